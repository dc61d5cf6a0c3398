"""Physical parameters of a spring-rod assembly and the header of the ``params.json`` file.

:class:`tensegrity_env.model.Model` reads and writes the whole document.

:class:`Params` is a frozen dataclass of torch tensors so it can be differentiated
through the engine (make any field ``requires_grad``) and moved between devices and
dtypes. Shapes use ``S = n_springs``, ``R = n_rods``, ``C`` cable actuators and ``W``
winches.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tensegrity_env.io_utils import InputError
from tensegrity_env.topology import Topology

PARAMS_FORMAT = "tensegrity-sr/params"
PARAMS_VERSION = 1

#: Units of every field of :class:`Params`, as written into ``params.json``.
UNITS: dict[str, str] = {
    "stiffness": "N/m",
    "damping": "N*s/m",
    "rest_length": "m",
    "mass": "kg",
    "inertia": "kg*m^2 (principal, rod frame x y z)",
    "control_gain": "N per command unit",
    "gravity": "m/s^2",
    "cable_gain": "N per command unit",
    "winch_speed": "m/s at command 1",
    "winch_min": "m",
    "winch_max": "m",
    "winch_lag": "s",
}

FIELDS: tuple[str, ...] = tuple(UNITS)
#: fields sized by the topology's actuators, absent from ``params.json`` when empty
OPTIONAL_FIELDS: tuple[str, ...] = ("cable_gain", "winch_speed", "winch_min", "winch_max",
                                    "winch_lag")  # fmt: skip
#: the winch fields, each (W,)
WINCH_FIELDS: tuple[str, ...] = ("winch_speed", "winch_min", "winch_max", "winch_lag")


def _empty() -> torch.Tensor:
    return torch.zeros(0, dtype=torch.float64)


@dataclass(frozen=True)
class Params:
    """Physical parameters.

    Attributes:
        stiffness: spring stiffness K, (S,) [N/m].
        damping: spring damping c, (S,) [N*s/m].
        rest_length: spring rest length l0, (S,) [m].
        mass: rod mass M, (R,) [kg].
        inertia: rod principal inertia I = (Ixx, Iyy, Izz) in the rod frame, (R, 3) [kg*m^2].
        control_gain: the scalar h mapping a control command f_u to force h*f_u, () [N/unit].
        gravity: gravitational acceleration, (3,) [m/s^2].
        cable_gain: the gain h_c of each cable actuator, (C,) [N/unit]: a command u
            changes the driven spring's tension by ``-h_c u`` (empty without cable
            actuators; see :class:`tensegrity_env.topology.Topology`).
        winch_speed: each winch's ``v_max``, the rate of its spring's rest length at
            command 1 (the winch radius inside), (W,) [m/s].
        winch_min, winch_max: the range of each wound spring's rest length, (W,) [m].
        winch_lag: each winch motor's first-order lag on its winding speed, (W,) [s]; 0
            for none. The wound springs' ``rest_length`` is their rest length at the
            start (see :mod:`tensegrity_env.engine.winch`).
    """

    stiffness: torch.Tensor
    damping: torch.Tensor
    rest_length: torch.Tensor
    mass: torch.Tensor
    inertia: torch.Tensor
    control_gain: torch.Tensor
    gravity: torch.Tensor
    cable_gain: torch.Tensor = field(default_factory=_empty)
    winch_speed: torch.Tensor = field(default_factory=_empty)
    winch_min: torch.Tensor = field(default_factory=_empty)
    winch_max: torch.Tensor = field(default_factory=_empty)
    winch_lag: torch.Tensor = field(default_factory=_empty)

    # ------------------------------------------------------------------ construction
    @classmethod
    def create(
        cls,
        stiffness: Any,
        damping: Any,
        rest_length: Any,
        mass: Any,
        inertia: Any,
        control_gain: Any = 1.0,
        gravity: Any = (0.0, 0.0, -9.81),
        cable_gain: Any = (),
        winch_speed: Any = (),
        winch_min: Any = (),
        winch_max: Any = (),
        winch_lag: Any = (),
        dtype: torch.dtype = torch.float64,
        device: str | torch.device = "cpu",
    ) -> Params:
        """Build from array-likes (numpy, lists, tensors); values are copied."""

        def t(x: Any) -> torch.Tensor:
            return torch.as_tensor(np.asarray(x, dtype=float), dtype=dtype, device=device).clone()

        return cls(
            stiffness=t(stiffness),
            damping=t(damping),
            rest_length=t(rest_length),
            mass=t(mass),
            inertia=t(inertia).reshape(-1, 3),
            control_gain=t(control_gain).reshape(()),
            gravity=t(gravity).reshape(3),
            cable_gain=t(cable_gain).reshape(-1),
            winch_speed=t(winch_speed).reshape(-1),
            winch_min=t(winch_min).reshape(-1),
            winch_max=t(winch_max).reshape(-1),
            winch_lag=t(winch_lag).reshape(-1),
        )

    def replace(self, **changes: Any) -> Params:
        return dataclasses.replace(self, **changes)

    def to(
        self, dtype: torch.dtype | None = None, device: str | torch.device | None = None
    ) -> Params:
        return Params(**{f: getattr(self, f).to(dtype=dtype, device=device) for f in FIELDS})

    def detach(self) -> Params:
        return Params(**{f: getattr(self, f).detach().clone() for f in FIELDS})

    def numpy(self) -> dict[str, np.ndarray]:
        """Every field as a float64 numpy array."""
        return {f: getattr(self, f).detach().cpu().double().numpy().copy() for f in FIELDS}

    @property
    def n_springs(self) -> int:
        return int(self.stiffness.shape[0])

    @property
    def n_rods(self) -> int:
        return int(self.mass.shape[0])

    # ------------------------------------------------------------------ checks
    def validate(self, topology: Topology, source: str = "params") -> Params:
        """Check shapes against ``topology`` and the physical domain (finite; M, I, K > 0;
        c, l0 >= 0; principal inertias obey the triangle inequality). Raises
        :class:`InputError` naming the field and the spring or rod."""
        S, R = topology.n_springs, topology.n_rods
        shapes = {
            "stiffness": (S,),
            "damping": (S,),
            "rest_length": (S,),
            "mass": (R,),
            "inertia": (R, 3),
            "control_gain": (),
            "gravity": (3,),
            "cable_gain": (topology.n_cables,),
            **{f: (topology.n_winches,) for f in WINCH_FIELDS},
        }
        springs = [sp.name for sp in topology.springs]
        rods = [r.name for r in topology.rods]
        owners = {"stiffness": springs, "damping": springs, "rest_length": springs,
                  "mass": rods, "inertia": rods}  # fmt: skip

        def where(f: str, bad: torch.Tensor) -> str:
            """The elements of field ``f`` where ``bad`` holds, by name, with their values."""
            rows = bad.reshape(bad.shape[0], -1).any(-1) if bad.ndim else bad.reshape(1)
            names = owners.get(f) or [f"{f}[{i}]" for i in range(rows.numel())]
            values = getattr(self, f).reshape(rows.numel(), -1).tolist()
            hits = [f"{names[i]} = {v[0] if len(v) == 1 else v}"
                    for i, v in enumerate(values) if bool(rows[i])]  # fmt: skip
            return ", ".join(hits[:4]) + (f" (and {len(hits) - 4} more)" if len(hits) > 4 else "")

        for f, shape in shapes.items():
            v = getattr(self, f)
            if tuple(v.shape) != shape:
                raise InputError(f"{source}: '{f}' has shape {tuple(v.shape)}, expected {shape}")
            if not torch.isfinite(v).all():
                raise InputError(f"{source}: '{f}' contains NaN or inf ({where(f, ~torch.isfinite(v))})")
        if (self.mass <= 0).any():
            raise InputError(f"{source}: masses must be positive: {where('mass', self.mass <= 0)}")
        if (self.inertia <= 0).any():
            raise InputError(f"{source}: inertias must be positive: "
                             f"{where('inertia', self.inertia <= 0)}")  # fmt: skip
        total = self.inertia.sum(-1, keepdim=True)
        if (2 * self.inertia > total * (1 + 1e-9)).any():
            bad = [i for i, row in enumerate((2 * self.inertia > total * (1 + 1e-9)).tolist())
                   if any(row)]  # fmt: skip
            raise InputError(f"{source}: principal inertias of rod(s) {bad} violate the triangle "
                             "inequality (each must be <= the sum of the other two)")  # fmt: skip
        if (self.stiffness <= 0).any():
            raise InputError(f"{source}: spring stiffness must be positive: "
                             f"{where('stiffness', self.stiffness <= 0)}")  # fmt: skip
        if (self.damping < 0).any():
            raise InputError(f"{source}: spring damping must be >= 0: "
                             f"{where('damping', self.damping < 0)}")  # fmt: skip
        if (self.rest_length < 0).any():
            raise InputError(f"{source}: rest lengths must be >= 0: "
                             f"{where('rest_length', self.rest_length < 0)}")  # fmt: skip
        self._validate_winches(topology, source)
        return self

    def _validate_winches(self, topology: Topology, source: str) -> None:
        """Winch speeds > 0, ranges ``0 <= l_min <= l_max``, lags >= 0, named by spring."""
        names = [topology.springs[s].name for s in topology.winches]
        checks = (
            ("winch_speed", self.winch_speed <= 0, "must be > 0 m/s"),
            ("winch_min", self.winch_min < 0, "must be >= 0 m"),
            ("winch_max", self.winch_max < self.winch_min, "must be >= winch_min"),
            ("winch_lag", self.winch_lag < 0, "must be >= 0 s"),
        )
        for f, bad, what in checks:
            for w in torch.nonzero(bad).flatten().tolist():
                value = float(getattr(self, f)[w])
                raise InputError(f"{source}: '{f}' of winch on spring '{names[w]}' is {value}: {what}")


    def relative_error(self, truth: Params) -> dict[str, np.ndarray]:
        """Element-wise |self - truth| / |truth| for every field (0/0 counts as 0);
        the actuator fields only where there are such actuators."""
        a, b = self.numpy(), truth.numpy()
        out = {}
        for f in FIELDS:
            if f in OPTIONAL_FIELDS and b[f].size == 0:
                continue
            den = np.abs(b[f])
            out[f] = np.where(den > 0, np.abs(a[f] - b[f]) / np.where(den > 0, den, 1.0), 0.0)
        return out


# ---------------------------------------------------------------------- params.json
def params_to_dict(params: Params) -> dict[str, Any]:
    """The ``params`` section: field -> nested lists (units in :data:`UNITS`); the
    actuator fields (:data:`OPTIONAL_FIELDS`) only where there are such actuators."""
    return {
        f: v.tolist() for f, v in params.numpy().items() if f not in OPTIONAL_FIELDS or v.size
    }


def check_numbers(value: Any, where: str, source: str) -> None:
    """Raise :class:`InputError` if a leaf of ``value`` (nested lists) is text, a boolean or
    a mapping: ``"1.5"`` would otherwise be read as a number. ``None`` (JSON null) reads as NaN and
    is refused by :meth:`Params.validate`."""
    if isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            check_numbers(v, f"{where}[{i}]", source)
    elif isinstance(value, (str, bool, dict)):
        raise InputError(f"{source}: {where} is {json.dumps(value)}: not numeric (write "
                         "numbers without quotes)")  # fmt: skip


def params_from_dict(d: Mapping[str, Any], source: str = "params") -> Params:
    """:class:`Params` from a ``params`` section; raises :class:`InputError` naming ``source``.

    The actuator fields (:data:`OPTIONAL_FIELDS`) may be absent (no such actuators)."""
    if not isinstance(d, Mapping):
        raise InputError(f"{source}: 'params' must be a mapping of field to values")
    d = {**{f: [] for f in OPTIONAL_FIELDS}, **d}
    missing = [f for f in FIELDS if f not in d]
    if missing:
        raise InputError(f"{source}: missing parameter(s) {missing}")
    for f in FIELDS:
        check_numbers(d[f], f"'{f}'", source)
    try:
        return Params.create(**{f: d[f] for f in FIELDS})
    except (ValueError, TypeError, RuntimeError) as e:  # torch reshapes raise RuntimeError
        raise InputError(f"{source}: malformed parameter values ({str(e).splitlines()[0]})") from None


def load_params_document(path: str | Path) -> dict[str, Any]:
    """Read and check the header of a params file; returns the whole JSON document."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such params file")
    try:
        doc = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: not valid JSON ({e.msg if hasattr(e, 'msg') else e})") from None
    if not isinstance(doc, dict) or doc.get("format") != PARAMS_FORMAT:
        raise InputError(f"{p}: not a tensegrity-sr params file (format != {PARAMS_FORMAT!r})")
    if doc.get("version") != PARAMS_VERSION:
        raise InputError(f"{p}: params version {doc.get('version')} is not supported")
    return doc

