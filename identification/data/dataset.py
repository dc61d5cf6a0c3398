"""Trajectory datasets: the public HDF5 format, its reader and its writer.

Schema (``format = "tensegrity-sr/trajectories"``, ``version = 2``; version 1 files, which
have no ``time`` and no gaps, are still read); ``R`` rods,
``N`` trajectories per split, ``T`` transitions per trajectory (``T + 1`` samples):

====================================  ===================  =====================================
path                                  shape                meaning
====================================  ===================  =====================================
``/`` attrs                                                ``format``, ``version``, ``dt`` [s],
                                                           ``assembly``, ``created``, ``source``
``/topology`` attr ``json``                                the topology graph (rods, end-cap
                                                           offsets, anchors, springs)
``/splits/<split>/p``                 (N, T+1, R, 3)       rod COM position [m], world frame
``/splits/<split>/v``                 (N, T+1, R, 3)       rod COM velocity [m/s], world frame
``/splits/<split>/q``                 (N, T+1, R, 4)       principal-frame orientation,
                                                           unit quaternion (w, x, y, z),
                                                           ``x_world = R(q) x_rod``
``/splits/<split>/omega``             (N, T+1, R, 3)       angular velocity [rad/s], world frame
``/splits/<split>/nodes``             (N, T+1, 2R, 3)      end-cap positions [m]; rod r owns
                                                           nodes 2r and 2r+1
``/splits/<split>/control``           (N, T, R, 3)         command f_u applied during step t
                                                           [command units], world frame
``/splits/<split>/cable_control``     (N, T, C)            optional: command of each cable
                                                           actuator during step t (zero if
                                                           absent)
``/splits/<split>/winch_control``     (N, T, W)            optional: command of each winch
                                                           motor during step t, in [-1, 1]
                                                           (zero if absent); each trajectory
                                                           starts with the winches at rest at
                                                           their declared rest lengths
``/splits/<split>/time``              (N, T+1)             optional: time of each sample [s]
                                                           from the trajectory's start; may be
                                                           non-uniform; NaN after a shorter
                                                           trajectory's end (its nodes NaN too)
``/ground_truth`` attrs                                    ``params`` (JSON), ``sim`` (JSON),
                                                           ``mjcf`` (XML text), ``effects``
====================================  ===================  =====================================

``dt`` is the nominal sample interval (1 / the nominal rate). Splits are ``train``,
``val`` and ``test``. Measured data (motion capture) may carry only ``nodes`` (and
``control``), and its ``nodes`` may hold NaN where a marker was not seen (a gap): the
per-marker validity is ``Split.valid``. Rod states are then derived from the end caps by
:func:`identification.data.end_caps.rod_states_from_nodes`. The ground truth lives in its own
group and is only read by :func:`read_ground_truth`, so an identifier never sees it
by accident.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from tensegrity_env.io_utils import InputError, atomic_path
from tensegrity_env.params import Params, params_from_dict, params_to_dict
from tensegrity_env.topology import Topology, TopologyError

DATASET_FORMAT = "tensegrity-sr/trajectories"
DATASET_VERSION = 2
#: versions the reader accepts
READABLE_VERSIONS = (1, 2)
SPLITS = ("train", "val", "test")
STATE_KEYS = ("p", "v", "q", "omega")
STATE_WIDTH = {"p": 3, "v": 3, "q": 4, "omega": 3}


@dataclass
class Split:
    """One split of trajectories (arrays as in the module schema; states may be None)."""

    nodes: np.ndarray
    control: np.ndarray
    p: np.ndarray | None = None
    v: np.ndarray | None = None
    q: np.ndarray | None = None
    omega: np.ndarray | None = None
    time: np.ndarray | None = None
    cable_control: np.ndarray | None = None
    winch_control: np.ndarray | None = None

    @property
    def n_trajectories(self) -> int:
        return int(self.nodes.shape[0])

    @property
    def n_transitions(self) -> int:
        """Transitions per trajectory, T."""
        return int(self.nodes.shape[1]) - 1

    @property
    def has_cable_commands(self) -> bool:
        """Whether this split drives cable actuators (non-zero ``cable_control``)."""
        return self.cable_control is not None and bool(np.any(self.cable_control != 0))

    @property
    def has_winch_commands(self) -> bool:
        """Whether this split drives winch motors (non-zero ``winch_control``)."""
        return self.winch_control is not None and bool(np.any(self.winch_control != 0))

    @property
    def has_states(self) -> bool:
        return all(getattr(self, k) is not None for k in STATE_KEYS)

    @property
    def valid(self) -> np.ndarray:
        """(N, T+1, 2R) bool: the end cap was seen in that sample (False in a gap)."""
        return np.isfinite(self.nodes).all(axis=-1)

    @property
    def has_gaps(self) -> bool:
        """Whether any end cap is missing in any sample."""
        return not bool(self.valid.all())

    def times(self, dt: float) -> np.ndarray:
        """(N, T+1) sample times [s]: the stored ``time``, else uniform at ``dt``."""
        if self.time is not None:
            return self.time
        t = np.arange(self.nodes.shape[1]) * dt
        return np.broadcast_to(t, self.nodes.shape[:2]).copy()

    def subset(self, idx: np.ndarray | slice) -> Split:
        """The trajectories ``idx`` of this split."""
        pick = {
            k: (None if getattr(self, k) is None else getattr(self, k)[idx])
            for k in (*STATE_KEYS, "time", "cable_control", "winch_control")
        }
        return Split(nodes=self.nodes[idx], control=self.control[idx], **pick)


@dataclass
class GroundTruth:
    """What the simulator used; never given to an identifier.

    Attributes:
        params: the true parameters (including the control gain h).
        sim: simulation options (JSON-able dict).
        mjcf: the MJCF text of the ground-truth model.
        effects: undeclared effects planted in the data, with their parameters.
    """

    params: Params
    sim: dict[str, Any] = field(default_factory=dict)
    mjcf: str = ""
    effects: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class Dataset:
    """A trajectory dataset in memory.

    Attributes:
        topology: the assembly graph.
        dt: time between samples [s].
        splits: split name -> :class:`Split`.
        attrs: free-form provenance (assembly, source, created, preset, seed, ...).
        path: the file it was read from, if any.
    """

    topology: Topology
    dt: float
    splits: dict[str, Split]
    attrs: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    def split(self, name: str) -> Split:
        if name not in self.splits:
            where = self.path or "dataset"
            raise InputError(f"{where}: has no '{name}' split (has {sorted(self.splits)})")
        return self.splits[name]

    @property
    def n_steps(self) -> int:
        """Total transitions over all splits."""
        return sum(s.n_trajectories * s.n_transitions for s in self.splits.values())


# ---------------------------------------------------------------------- writing
def write_dataset(
    path: str | Path, dataset: Dataset, ground_truth: GroundTruth | None = None
) -> Path:
    """Write ``dataset`` (and optionally its ground truth) atomically to ``path``."""
    check_dataset(dataset, str(path))
    with atomic_path(path, suffix=".h5") as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = DATASET_FORMAT
            f.attrs["version"] = DATASET_VERSION
            f.attrs["dt"] = float(dataset.dt)
            f.attrs["created"] = datetime.now(UTC).isoformat(timespec="seconds")
            for k, v in dataset.attrs.items():
                f.attrs[k] = v if isinstance(v, (int, float, str, bool)) else json.dumps(v)
            f.create_group("topology").attrs["json"] = dataset.topology.to_json()
            for name, split in dataset.splits.items():
                g = f.create_group(f"splits/{name}")
                for k in ("nodes", "control", *STATE_KEYS, "time", "cable_control", "winch_control"):
                    arr = getattr(split, k)
                    if arr is not None:
                        g.create_dataset(k, data=np.asarray(arr, dtype=np.float64), chunks=True)
            if ground_truth is not None:
                gt = f.create_group("ground_truth")
                gt.attrs["params"] = json.dumps(params_to_dict(ground_truth.params))
                gt.attrs["sim"] = json.dumps(ground_truth.sim)
                gt.attrs["mjcf"] = ground_truth.mjcf
                gt.attrs["effects"] = json.dumps(ground_truth.effects)
    return Path(path)


# ---------------------------------------------------------------------- reading
def _open(path: str | Path) -> h5py.File:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such dataset file")
    try:
        f = h5py.File(p, "r")
    except OSError as e:
        raise InputError(f"{p}: not a readable HDF5 file (truncated or corrupt: {e})") from None
    fmt = _decode(f.attrs.get("format"))
    version = _decode(f.attrs.get("version", -1))
    if fmt != DATASET_FORMAT:
        f.close()
        raise InputError(f"{p}: not a tensegrity-sr dataset (format attribute missing or wrong)")
    if not isinstance(version, (int, np.integer)) or int(version) not in READABLE_VERSIONS:
        f.close()
        raise InputError(f"{p}: dataset version {version!r} is not supported")
    return f


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


def _decode(v: Any) -> Any:
    if isinstance(v, bytes):
        v = v.decode()
    if isinstance(v, np.generic):
        return v.item()
    return v


def read_dataset(path: str | Path, splits: tuple[str, ...] | None = None) -> Dataset:
    """Read a dataset (without its ground truth). Raises :class:`InputError` on bad input."""
    p = Path(path)
    with _open(p) as f:
        try:
            topology = Topology.from_json(_decode(f["topology"].attrs["json"]))
            dt = float(f.attrs["dt"])
            attrs = {k: _decode(v) for k, v in f.attrs.items() if k not in ("format", "version")}
            names = [s for s in f["splits"] if splits is None or s in splits]
            out = {}
            for name in names:
                g = f[f"splits/{name}"]
                arrays: dict[str, Any] = {
                    k: (g[k][()] if k in g else None)
                    for k in ("nodes", "control", *STATE_KEYS, "time", "cable_control", "winch_control")
                }
                if arrays["nodes"] is None:
                    raise InputError(f"{p}: split '{name}' has no 'nodes'")
                if arrays["control"] is None:
                    n, t1 = arrays["nodes"].shape[:2]
                    arrays["control"] = np.zeros((n, t1 - 1, topology.n_rods, 3))
                if arrays["cable_control"] is None and topology.n_cables:
                    n, t1 = arrays["nodes"].shape[:2]
                    arrays["cable_control"] = np.zeros((n, t1 - 1, topology.n_cables))
                if arrays["winch_control"] is None and topology.n_winches:
                    n, t1 = arrays["nodes"].shape[:2]
                    arrays["winch_control"] = np.zeros((n, t1 - 1, topology.n_winches))
                out[name] = Split(**arrays)
        except InputError:
            raise
        except (KeyError, OSError, ValueError, TypeError, TopologyError) as e:
            raise InputError(f"{p}: malformed dataset ({_first_line(e)})") from None
    ds = Dataset(topology=topology, dt=dt, splits=out, attrs=attrs, path=p)
    check_dataset(ds, str(p))
    return ds


def read_ground_truth(path: str | Path) -> GroundTruth | None:
    """The ground truth stored with a simulated dataset, or None for measured data."""
    with _open(path) as f:
        if "ground_truth" not in f:
            return None
        try:
            a = f["ground_truth"].attrs
            return GroundTruth(
                params=params_from_dict(
                    json.loads(_decode(a["params"])), source=f"{path}:ground_truth"
                ),
                sim=json.loads(_decode(a.get("sim", "{}"))),
                mjcf=str(_decode(a.get("mjcf", ""))),
                effects=json.loads(_decode(a.get("effects", "[]"))),
            )
        except (KeyError, OSError, ValueError, TypeError) as e:
            raise InputError(f"{path}: malformed ground truth ({_first_line(e)})") from None


def check_dataset(ds: Dataset, where: str) -> None:
    """Shapes, finiteness and dt; one :class:`InputError` naming the problem."""
    R = ds.topology.n_rods
    if not np.isfinite(ds.dt) or ds.dt <= 0:
        raise InputError(f"{where}: time step dt must be positive, got {ds.dt}")
    if not ds.splits:
        raise InputError(f"{where}: dataset has no splits")
    for name, s in ds.splits.items():
        if s.nodes.ndim != 4 or s.nodes.shape[2:] != (2 * R, 3):
            raise InputError(
                f"{where}: split '{name}' nodes have shape {s.nodes.shape}, "
                f"expected (N, T+1, {2 * R}, 3)"
            )
        N, T1 = s.nodes.shape[:2]
        if T1 < 2:
            raise InputError(f"{where}: split '{name}' trajectories need at least 2 samples")
        if s.control.shape != (N, T1 - 1, R, 3):
            raise InputError(
                f"{where}: split '{name}' control has shape {s.control.shape}, "
                f"expected {(N, T1 - 1, R, 3)}"
            )
        for k, n in (("cable_control", ds.topology.n_cables), ("winch_control", ds.topology.n_winches)):
            arr = getattr(s, k)
            if arr is not None and arr.shape != (N, T1 - 1, n):
                raise InputError(
                    f"{where}: split '{name}' {k} has shape {arr.shape}, expected {(N, T1 - 1, n)}"
                )
        for k in ("control", "cable_control", "winch_control", *STATE_KEYS):
            arr = getattr(s, k)
            if arr is None:
                continue
            if k in STATE_KEYS and arr.shape != (N, T1, R, STATE_WIDTH[k]):
                raise InputError(
                    f"{where}: split '{name}' '{k}' has shape {arr.shape}, "
                    f"expected {(N, T1, R, STATE_WIDTH[k])}"
                )
            if not np.all(np.isfinite(arr)):
                raise InputError(f"{where}: split '{name}' '{k}' contains NaN or inf")
        _check_nodes_and_time(s, name, where)


def _check_nodes_and_time(s: Split, name: str, where: str) -> None:
    """End caps: finite or NaN (a gap), never inf, every trajectory seen somewhere; time:
    finite and increasing where stored, NaN only after a trajectory's last sample."""
    if np.isinf(s.nodes).any():
        raise InputError(f"{where}: split '{name}' 'nodes' contains inf")
    partial = np.isnan(s.nodes).any(axis=-1) & ~np.isnan(s.nodes).all(axis=-1)
    if partial.any():
        raise InputError(
            f"{where}: split '{name}' 'nodes' has an end cap with some coordinates NaN "
            "and others not (a gap is NaN in x, y and z)"
        )
    unseen = ~np.isfinite(s.nodes).all(axis=-1)
    if unseen.all(axis=(1, 2)).any():
        raise InputError(f"{where}: split '{name}' 'nodes' has a trajectory that is NaN throughout")
    if s.time is None:
        if s.has_states and not np.isfinite(s.nodes).all():
            raise InputError(f"{where}: split '{name}' has rod states but NaN end caps")
        return
    if s.time.shape != s.nodes.shape[:2]:
        raise InputError(
            f"{where}: split '{name}' 'time' has shape {s.time.shape}, expected {s.nodes.shape[:2]}"
        )
    finite = np.isfinite(s.time)
    if np.isinf(s.time).any() or (np.diff(finite.astype(int), axis=1) > 0).any():
        raise InputError(f"{where}: split '{name}' 'time' is inf or NaN before a trajectory's end")
    steps = np.diff(s.time, axis=1)
    if (steps[np.isfinite(steps)] <= 0).any():
        raise InputError(f"{where}: split '{name}' 'time' does not increase in every trajectory")
    if not finite[:, :2].all():
        raise InputError(f"{where}: split '{name}' has a trajectory shorter than 2 samples")
    if np.isfinite(s.nodes[~finite]).any():
        raise InputError(f"{where}: split '{name}' has end caps after a trajectory's last time")
