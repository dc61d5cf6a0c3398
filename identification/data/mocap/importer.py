"""Recordings to end caps of a robot, and end caps to the public dataset format."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from identification.data.dataset import Dataset, Split
from identification.data.end_caps import cap_names
from identification.data.mocap.labelling import LENGTH_TOL, initial_caps_from_shape, label_clouds
from identification.data.mocap.marker_map import MarkerMap, default_map
from identification.data.mocap.placement import Placement
from identification.data.mocap.recording import MarkerRecording
from identification.data.mocap.stretches import Stretch, assign_splits, pieces
from identification.data.mocap.vertical import AXIS_ANGLE, find_vertical
from identification.data.quality import longest_run, placeholder_samples, third_difference_noise
from identification.data.sample_grid import check_span, grid_index
from tensegrity_env.assemblies import node_positions
from tensegrity_env.io_utils import InputError
from tensegrity_env.rotations import TO_Z_UP, np_quat_mul, np_quat_to_matrix
from tensegrity_env.topology import Topology

#: a labelled take's rods may differ from the robot's lengths by at most this fraction
#: (median over frames; marker offsets a few millimetres off stay far inside)
ROD_LENGTH_TOL = 0.1
#: recordings of one dataset may differ in nominal rate by at most this fraction
RATE_TOL = 0.01
#: a labelled frame's rod may differ from its usual length by this fraction at most; beyond,
#: both its end caps are read as unseen in that frame (a marker swapped with another
#: rod's, or mislabelled for a few frames)
ROD_FRAME_TOL = 0.05
#: a rod's marker distance may stray from its usual value by this many times the
#: take's marker noise (a rigid rod: only noise moves it) ...
NOISE_TO_LENGTH_TOL = 20.0
#: ... within this range [m] (2 mm: the precision a model of the rods can use; 1 cm:
#: the tracker's gate for noisy data)
LENGTH_TOL_RANGE = (0.002, LENGTH_TOL)
#: the span [s] over which a rod's usual marker distance is the median
ROD_LENGTH_WINDOW = 1.0
#: rounds of that check, each on the medians of what the one before kept
ROD_LENGTH_ROUNDS = 5


@dataclass(frozen=True)
class Robot:
    """What the importer needs of a robot file: its graph and (MJCF only) its rest end caps."""

    topology: Topology
    rest_caps: np.ndarray | None  # (2R, 3) [m]
    source: Path


def read_robot(
    path: str | Path, ignore: tuple[str, ...] = (), end_caps: tuple[str, ...] = ()
) -> Robot:
    """A robot from an MJCF file (graph + rest pose; ``end_caps``: its end-cap sites,
    two per rod, where the convention does not find them), an NTRT YAML model (graph +
    rest pose, :func:`~tensegrity_env.ntrt.from_ntrt`) or a params.json (graph only)."""
    p = Path(path)
    if p.suffix.lower() == ".json":
        from tensegrity_env.model import Model

        return Robot(Model.load(p).topology, None, p)
    if p.suffix.lower() in (".yaml", ".yml"):
        from tensegrity_env.ntrt import from_ntrt

        ntrt = from_ntrt(p)
        return Robot(ntrt.topology, ntrt.rest_caps, p)
    if p.suffix.lower() != ".xml":
        raise InputError(f"{p}: robot file must be an MJCF .xml, an NTRT .yaml or a params .json")
    from tensegrity_env.mjcf import from_mjcf

    asm = from_mjcf(p, ignore=ignore, end_caps=end_caps)
    m = asm.model
    pos = np.stack([m.qpos0[a : a + 3] for a in asm.rod_qpos])
    quat = np.stack([m.qpos0[a + 3 : a + 7] for a in asm.rod_qpos])
    com = pos + np.einsum("rij,rj->ri", np_quat_to_matrix(quat), asm.body_ipos)
    q = np_quat_mul(quat, asm.body_iquat)
    caps = node_positions(asm.topology, com, q)[: 2 * asm.topology.n_rods]
    return Robot(asm.topology, caps, p)


@dataclass(frozen=True)
class ImportedTake:
    """End caps of one take. ``caps`` (F, 2R, 3) [m], NaN unseen; ``time`` (F,) [s];
    ``track_of_cap`` (F, 2R): the file column each cap came from (-1 unseen);
    ``commands`` (F, C + W): each cable actuator's, then each winch motor's command in
    force from each frame on
    [command units] (None: not logged, zero); ``rejected``: labelled samples read as
    unseen (:func:`checked_labels`, :func:`rods_off_their_length`); ``reacquired``
    (2R,): times each cap was found again after being lost (unlabelled takes);
    ``ids`` (F, M): the recording's marker ids (:attr:`MarkerRecording.ids`);
    ``stretches``: the take's stretches of which a fit uses those at rest, free or named
    (:mod:`~identification.data.mocap.stretches`; None: the whole take is used);
    ``placement``: how its markers were placed on the robot's end caps and floor
    (:mod:`~identification.data.mocap.placement`; None: as recorded)."""

    source: Path
    time: np.ndarray
    caps: np.ndarray
    rate: float
    relabelled_frames: int
    ghosts: int
    track_of_cap: np.ndarray
    commands: np.ndarray | None = None
    rejected: int = 0
    reacquired: np.ndarray | None = None
    ids: np.ndarray | None = None
    stretches: tuple[Stretch, ...] | None = None
    placement: Placement | None = None

    def piece(self, a: int = 0, b: int | None = None, n_commands: int = 0) -> Piece:
        """Frames ``a:b`` as (time, caps, commands (zero where not logged))."""
        cmd = self.commands if self.commands is not None else np.zeros((len(self.time), n_commands))
        return self.time[a:b], self.caps[a:b], cmd[a:b]


#: one take's stretch for a split: time (F,), caps (F, 2R, 3), commands (F, C + W)
Piece = tuple[np.ndarray, np.ndarray, np.ndarray]


def _apply_map(rec: MarkerRecording, mmap: MarkerMap, n_caps: int) -> np.ndarray:
    caps = np.full((rec.n_frames, n_caps, 3), np.nan)
    offsets = np.zeros(n_caps)
    for name, (cap, off) in mmap.caps.items():
        caps[:, cap] = rec.points[:, rec.names.index(name)]
        offsets[cap] = off
    if np.any(offsets != 0):
        u = caps[:, 1::2] - caps[:, 0::2]
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        caps[:, 0::2] += offsets[0::2, None] * u  # marker beyond end 0 along -u
        caps[:, 1::2] -= offsets[1::2, None] * u
    return caps


def check_take(rec: MarkerRecording, robot: Robot, mmap: MarkerMap | None) -> MarkerMap | None:
    """What :func:`take_end_caps` needs, checked before any work: the map to use
    (labelled takes), or for unlabelled takes without a map a frame that shows every end
    cap (tracking starts at the first such frame). One-line errors; a take whose frame
    times leave most of its grid empty (a timestamp glitch, a long pause) is refused
    here, as ``identify`` would (:func:`~identification.data.sample_grid.check_span`)."""
    finite = np.isfinite(rec.time)
    if finite.any():
        dt = 1.0 / rec.rate
        k, _ = grid_index(np.where(finite, rec.time, rec.time[finite][0]), dt)
        check_span(rec.time, k, finite, dt, str(rec.source))
    n_caps = 2 * robot.topology.n_rods
    if not rec.unlabelled:
        mmap = mmap or default_map(rec.names, robot.topology)
        if mmap is None:
            raise InputError(
                f"{rec.source}: {len(rec.names)} markers, robot {robot.source} has {n_caps} end "
                "caps; pass --map (markers named <rod>_<0|1|end0|end1> map themselves)"
            )
        mmap.check_names(rec.names, rec.source)
        if len({c for c, _ in mmap.caps.values()}) != n_caps:
            raise InputError(
                f"{mmap.source}: maps {len(mmap.caps)} markers, robot {robot.source} has {n_caps} end caps"
            )
        check_rod_lengths(_apply_map(rec, mmap, n_caps), robot, rec.source)
        return mmap
    if mmap is not None:
        mmap.check_names(rec.names, rec.source)
        return mmap
    if robot.rest_caps is None:
        raise InputError(
            f"{rec.source}: unlabelled markers need --map (the first frame's track ids) "
            "or an MJCF robot file (its rest pose starts the tracking)"
        )
    if first_full_frame(rec, n_caps) is None:
        most = int(np.isfinite(rec.points).all(-1).sum(-1).max())
        raise InputError(
            f"{rec.source}: no frame shows all {n_caps} end caps (at most {most} points); "
            "pass --map naming the first frame's tracks"
        )
    return None


def first_full_frame(rec: MarkerRecording, n_caps: int) -> int | None:
    """The first frame of an unlabelled take with at least ``n_caps`` points (where
    tracking starts from the robot's shape), None if there is none."""
    full = np.flatnonzero(np.isfinite(rec.points).all(-1).sum(-1) >= n_caps)
    return int(full[0]) if full.size else None


def upright(take: ImportedTake, up: str | None) -> tuple[ImportedTake, str]:
    """``take`` (end caps in the file's coordinates) turned z-up, and a line saying how
    its vertical was found (:func:`~identification.data.mocap.vertical.find_vertical`).
    ``up``: the axis the user named (``--up``), refused in one line when the data says
    otherwise; None: the data's (z when it shows neither free flight nor a floor)."""
    found = find_vertical(take.caps, take.time)
    src = take.source
    if found is not None and found.angle > AXIS_ANGLE:
        raise InputError(f"{src}: {found.evidence}, {found.angle:.0f} deg from the file's nearest "
                         f"axis {found.axis}: a tilted vertical is not read")  # fmt: skip
    if up is not None:
        if found is not None and found.axis.lstrip("-") != up:
            raise InputError(f"{src}: --up {up} contradicts the data: {found.evidence}; the file is "
                             f"{found.axis}-up")  # fmt: skip
        axis, how = up, "given by --up" + (f", and {found.evidence}" if found else "")
    elif found is None:
        axis, how = "z", "taken as z: no free flight and no floor found in the take (--up names it)"
    else:
        axis, how = found.axis, found.evidence
    return replace(take, caps=take.caps @ TO_Z_UP[axis].T), f"{src}: up is {axis} ({how})"


def tracking_report(take: ImportedTake, topology: Topology) -> str:
    """Per end cap of an unlabelled take: the share of frames it was seen, its longest
    gap, how often it was found again after being lost, and how many marker ids it
    was seen under."""
    seen = np.isfinite(take.caps).all(-1)
    dt = 1.0 / take.rate
    lines = [f"{take.source}: tracking per end cap (labelled up to the robot's symmetry)",
             "  end cap          seen   longest gap  found again  marker ids"]  # fmt: skip
    for i, name in enumerate(cap_names(topology)):
        cols = take.track_of_cap[:, i]
        rows = np.flatnonzero(cols >= 0)
        ids = take.ids[rows, cols[rows]] if take.ids is not None else cols[rows]
        again = int(take.reacquired[i]) if take.reacquired is not None else 0
        lines.append(f"  {name:<12} {100 * seen[:, i].mean():6.2f} %  {longest_run(~seen[:, i]) * dt:8.3f} s"
                     f"  {again:11d}  {len(np.unique(ids)):10d}")  # fmt: skip
    return "\n".join(lines)


def cap_distances(robot: Robot) -> np.ndarray:
    """(R,) [m]: the distance between each rod's two end caps."""
    return np.array([float(np.linalg.norm(np.subtract(*rod.ends()))) for rod in robot.topology.rods])


def check_rod_lengths(caps: np.ndarray, robot: Robot, source: Path) -> None:
    """Refuse labelled end caps ``caps`` (F, 2R, 3) [m] whose rods are not the robot's
    length: the median distance of each rod's two end caps over the frames that see both
    must be within :data:`ROD_LENGTH_TOL` of the rod's length (mislabelled markers, a
    wrong map or a wrong length unit are far outside)."""
    for r, (rod, length) in enumerate(zip(robot.topology.rods, cap_distances(robot), strict=True)):
        a, b = caps[:, 2 * r], caps[:, 2 * r + 1]
        both = np.isfinite(a).all(-1) & np.isfinite(b).all(-1)
        if not both.any():
            continue
        apart = float(np.median(np.linalg.norm(a[both] - b[both], axis=-1)))
        if abs(apart - length) > ROD_LENGTH_TOL * length:
            raise InputError(
                f"{source}: the end caps of {rod.name} are {apart:.4g} m apart (median over "
                f"{int(both.sum())} frames), the robot's are {length:.4g} m apart: "
                "mislabelled markers, a wrong --map, or the wrong length unit (--units)"
            )


def take_end_caps(rec: MarkerRecording, robot: Robot, mmap: MarkerMap | None) -> ImportedTake:
    """The robot's end caps in every frame of ``rec`` (labelled or a point cloud; an
    unlabelled take without a map from :func:`first_full_frame` on)."""
    return label_take(rec, robot, check_take(rec, robot, mmap))


def label_take(rec: MarkerRecording, robot: Robot, mmap: MarkerMap | None) -> ImportedTake:
    """:func:`take_end_caps` of a take already checked: ``mmap`` as :func:`check_take`
    returned it."""
    n_caps = 2 * robot.topology.n_rods
    if not rec.unlabelled:
        assert mmap is not None
        column = np.full(n_caps, -1)
        for name, (cap, _) in mmap.caps.items():
            column[cap] = rec.names.index(name)
        caps, swapped, rejected = checked_labels(_apply_map(rec, mmap, n_caps), cap_distances(robot))
        track = np.where(np.isfinite(caps).all(-1), column, -1)
        for f, r in swapped:
            track[f, 2 * r : 2 * r + 2] = track[f, 2 * r : 2 * r + 2][::-1]
        relabelled = len({f for f, _ in swapped})
        return ImportedTake(rec.source, rec.time, caps, rec.rate, relabelled, 0, track, rejected=rejected)
    lengths = cap_distances(robot)
    if mmap is not None:
        first = np.full((n_caps, 3), np.nan)
        for name, (cap, off) in mmap.caps.items():
            first[cap] = rec.points[0, rec.names.index(name)]
            lengths[cap // 2] += off  # the markers' distance, offsets included
    else:
        assert robot.rest_caps is not None
        start = first_full_frame(rec, n_caps)
        assert start is not None, "check_take refuses a take without a full frame"
        rec = rec.from_frame(start)
        seen = np.isfinite(rec.points[0]).all(-1)
        first = initial_caps_from_shape(robot.rest_caps, rec.points[0, seen])
    # two passes: the rods' marker distances as tracked with the robot's lengths and a
    # loose gate, then tracked again with those
    built = robot.rest_caps  # labelled by cap index, as the tracking is
    lab = label_clouds(rec.points, rec.time, first, marker_distances(first, lengths), ids=rec.ids, built=built)
    apart = np.linalg.norm(lab.caps[:, 0::2] - lab.caps[:, 1::2], axis=-1)
    usual = np.array([np.median(a[np.isfinite(a)]) if np.isfinite(a).any() else np.nan for a in apart.T])
    lengths = np.where(np.isfinite(usual), usual, lengths)
    lab = label_clouds(rec.points, rec.time, first, lengths, ids=rec.ids, built=built)
    caps, rejected = rods_off_their_length(lab.caps, rec.time, length_tolerance(rec))
    caps, held = without_placeholders(caps)
    rejected += held
    return ImportedTake(
        rec.source, rec.time, caps, rec.rate, lab.relabelled_frames, lab.ghosts, lab.track_of_cap,
        rejected=rejected, reacquired=lab.reacquired, ids=rec.ids,
    )  # fmt: skip


def without_placeholders(caps: np.ndarray) -> tuple[np.ndarray, int]:
    """End caps ``caps`` (F, 2R, 3) [m] with the samples that read as placeholders
    (:func:`~identification.data.quality.placeholder_samples`: every seen cap repeating
    the frame before within a micrometre, where a ghost point that did not repeat kept
    the cloud's frame from reading as repeated) read as unseen, and how many."""
    mask = placeholder_samples(caps) & np.isfinite(caps).all(-1)
    out = caps.copy()
    out[mask] = np.nan
    return out, int(mask.sum())


def marker_distances(first: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """(R,) [m]: each rod's marker distance as the first frame's end caps ``first``
    (2R, 3) show it (markers sit on the caps' surfaces, millimetres beyond the robot
    file's end caps), where both are seen and within :data:`ROD_LENGTH_TOL` of the
    robot's ``lengths`` (R,) [m] (offsets included); else that length."""
    apart = np.linalg.norm(first[0::2] - first[1::2], axis=-1)
    ok = np.isfinite(apart) & (np.abs(apart - lengths) <= ROD_LENGTH_TOL * lengths)
    return np.where(ok, apart, lengths)


def length_tolerance(rec: MarkerRecording) -> float:
    """How far [m] a labelled rod's marker distance may stray from its usual value:
    :data:`NOISE_TO_LENGTH_TOL` times the take's marker noise (the median over its
    tracks), within :data:`LENGTH_TOL_RANGE`."""
    d3 = np.diff(rec.points, n=3, axis=0)
    noise = third_difference_noise(d3, least=10)
    lo, hi = LENGTH_TOL_RANGE
    return float(np.clip(NOISE_TO_LENGTH_TOL * noise, lo, hi)) if np.isfinite(noise) else hi


def rods_off_their_length(caps: np.ndarray, time: np.ndarray, tol: float) -> tuple[np.ndarray, int]:
    """End caps ``caps`` (F, 2R, 3) [m] at ``time`` (F,) [s] with a rod's cap read as
    unseen in the frames where the rod's marker distance is more than ``tol`` [m] from
    its median over the :data:`ROD_LENGTH_WINDOW` around the frame (a marker mistaken
    for another, or a reconstruction that jumps; a marker that moves on its cap over a
    take, as an impact can make it, shifts the median with it). The cap read as unseen
    is the one farther from the line through its positions in the frames before and
    after (the one that jumped); both where neither is seen in both. Repeated on the
    medians of what is kept (:data:`ROD_LENGTH_ROUNDS`) until every kept rod is within
    ``tol`` of its median. Returns the caps and the number of samples so read."""
    lo = np.searchsorted(time, time - ROD_LENGTH_WINDOW / 2)
    hi = np.searchsorted(time, time + ROD_LENGTH_WINDOW / 2, side="right")
    out = caps.copy()
    for _ in range(ROD_LENGTH_ROUNDS):  # the medians of what is kept, until they hold
        apart = np.linalg.norm(out[:, 0::2] - out[:, 1::2], axis=-1)  # (F, R)
        usual = np.full_like(apart, np.nan)
        for f in np.flatnonzero(np.isfinite(apart).any(-1)):
            window = apart[lo[f] : hi[f]]
            has = np.isfinite(window).any(0)
            usual[f, has] = np.nanmedian(window[:, has], axis=0)
        off = np.isfinite(apart) & (np.abs(apart - usual) > tol)
        if not off.any():
            break
        bend = np.full(out.shape[:2], np.inf)  # (F, 2R): how far each cap leaves the line
        bend[1:-1] = np.linalg.norm(out[:-2] - 2.0 * out[1:-1] + out[2:], axis=-1)  # of its neighbours
        bend[~np.isfinite(bend)] = np.inf
        for f, r in zip(*np.nonzero(off), strict=True):
            a, b = bend[f, 2 * r], bend[f, 2 * r + 1]
            if np.isfinite(a) or np.isfinite(b):  # the cap that jumped, seen by its neighbours
                out[f, 2 * r + int(b > a)] = np.nan
            else:
                out[f, 2 * r : 2 * r + 2] = np.nan
    else:  # what is left after the last round is checked once more, both caps dropped
        apart = np.linalg.norm(out[:, 0::2] - out[:, 1::2], axis=-1)
        usual = np.array([[np.nanmedian(apart[lo[f] : hi[f], r]) if np.isfinite(apart[lo[f] : hi[f], r]).any()
                           else np.nan for r in range(apart.shape[1])] for f in range(len(apart))])  # fmt: skip
        off = np.isfinite(apart) & (np.abs(apart - usual) > tol)
        out[np.repeat(off, 2, axis=1)] = np.nan
    return out, int(np.isnan(out).any(-1).sum() - np.isnan(caps).any(-1).sum())


def checked_labels(caps: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, list[tuple[int, int]], int]:
    """Labelled end caps ``caps`` (F, 2R, 3) [m] checked frame by frame against the rods'
    ``lengths`` (R,) [m].

    A rod whose two end caps jump, from one frame to the next, each to about where the
    other was (its two markers' labels swapped: no rod turns half a turn in one frame)
    gets them swapped back. Then a rod whose end caps are not their usual distance
    apart (the take's median, which a constant marker offset moves), within
    :data:`ROD_FRAME_TOL` of its length, loses both in that frame (a marker swapped with
    another rod's, or mislabelled). Returns the caps, the (frame, rod) pairs swapped back, and
    the number of samples read as unseen.
    """
    caps = caps.copy()
    R = len(lengths)
    swapped: list[tuple[int, int]] = []
    both = np.isfinite(caps).all(-1).reshape(len(caps), R, 2).all(-1)  # (F, R)
    for r in range(R):
        for f in np.flatnonzero(both[1:, r] & both[:-1, r]) + 1:
            a, b = caps[f, 2 * r], caps[f, 2 * r + 1]
            pa, pb = caps[f - 1, 2 * r], caps[f - 1, 2 * r + 1]
            stay = np.linalg.norm(a - pa) + np.linalg.norm(b - pb)
            cross = np.linalg.norm(a - pb) + np.linalg.norm(b - pa)
            if cross < stay and stay > lengths[r]:
                caps[f, 2 * r : 2 * r + 2] = caps[f, 2 * r : 2 * r + 2][::-1].copy()
                swapped.append((int(f), r))
    apart = np.linalg.norm(caps[:, 0::2] - caps[:, 1::2], axis=-1)  # (F, R)
    seen = np.isfinite(apart)
    usual = np.array([np.median(apart[seen[:, r], r]) if seen[:, r].any() else lengths[r]
                      for r in range(R)])  # fmt: skip
    off = seen & (np.abs(apart - usual) > ROD_FRAME_TOL * lengths)
    caps[np.repeat(off, 2, axis=1)] = np.nan
    return caps, swapped, int(2 * off.sum())


def parse_fractions(text: str) -> tuple[float, float, float]:
    """``"0.7,0.15,0.15"`` -> train, val, test fractions (sum 1)."""
    try:
        parts = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"--split: {text!r} is not three fractions like 0.7,0.15,0.15") from None
    if len(parts) != 3 or min(parts) < 0 or abs(sum(parts) - 1) > 1e-6 or parts[0] <= 0:
        raise InputError(f"--split: {text!r} must be train,val,test fractions summing to 1")
    return parts


def _stack(pieces: list[Piece], n_rods: int, n_cables: int) -> Split:
    """Takes of one split as trajectories of equal length: the shortest take's; longer
    takes are cut into as many whole pieces of that length as they hold (the rest of a
    take, shorter than one piece, is left out). Each sample keeps its own time (from the
    piece's first). Cable and winch commands (the first ``n_cables`` columns, then the
    winches') are those in force over each sample interval."""
    T1 = min(len(t) for t, _, _ in pieces)
    chunks = [(t[a : a + T1], c[a : a + T1], u[a : a + T1 - 1]) for t, c, u in pieces
              for a in range(0, len(t) - T1 + 1, T1)]  # fmt: skip
    nodes = np.stack([c for _, c, _ in chunks])
    time = np.stack([t - t[0] for t, _, _ in chunks])
    commands = np.stack([u for _, _, u in chunks])
    cables, winches = commands[..., :n_cables], commands[..., n_cables:]
    return Split(nodes=nodes, control=np.zeros((len(chunks), T1 - 1, n_rods, 3)), time=time,
                 cable_control=cables if cables.shape[-1] else None,
                 winch_control=winches if winches.shape[-1] else None)  # fmt: skip


def build_dataset(
    takes: list[ImportedTake], robot: Robot, fractions: tuple[float, float, float],
    assign: dict[str, str] | None = None, piece: float = 2.0,
) -> Dataset:  # fmt: skip
    """Takes to splits: ``assign`` (file name -> split) where given, else ``fractions``
    of the takes (or, with fewer takes than splits, of each take's pieces, or of its
    duration when it has no stretches). A take with stretches gives only pieces of
    ``piece`` [s] cut from the stretches a fit uses (:func:`~identification.data.mocap.
    stretches.pieces`), each whole in one split; the attrs record the stretches and
    each split's pieces (file, time of its first and last sample [s])."""
    rates = np.array([t.rate for t in takes])
    if np.ptp(rates) > RATE_TOL * rates.min():
        raise InputError(f"takes have different frame rates ({sorted(set(rates.round(3)))} Hz); import them separately")
    groups: dict[str, list[Piece]] = {"train": [], "val": [], "test": []}
    where: dict[str, list[list[object]]] = {"train": [], "val": [], "test": []}
    C = robot.topology.n_cables + robot.topology.n_winches

    def add(t: ImportedTake, split: str, a: int = 0, b: int | None = None) -> None:
        groups[split].append(t.piece(a, b, C))
        end = len(t.time) if b is None else b
        where[split].append([t.source.name, round(float(t.time[a]), 4), round(float(t.time[end - 1]), 4)])

    def cut(t: ImportedTake) -> list[tuple[int, int | None]]:
        ranges: list[tuple[int, int | None]] = (
            [*pieces(list(t.stretches), t.time, piece)] if t.stretches is not None else [(0, None)]
        )
        if not ranges:
            raise InputError(f"{t.source}: no stretch a fit can use lasts {piece:g} s "
                             f"({', '.join(map(str, t.stretches or ()))})")  # fmt: skip
        return ranges

    if assign or len(takes) >= 3:
        if assign:
            names = [assign.get(t.source.name, "train") for t in takes]
        else:
            n = len(takes)
            n_val = round(fractions[1] * n) if fractions[1] > 0 else 0
            n_test = round(fractions[2] * n) if fractions[2] > 0 else 0
            n_val, n_test = max(n_val, fractions[1] > 0), max(n_test, fractions[2] > 0)
            names = ["train"] * (n - n_val - n_test) + ["val"] * n_val + ["test"] * n_test
        for t, s in zip(takes, names, strict=True):
            for a, b in cut(t):
                add(t, s, a, b)
    else:
        for t in takes:
            if t.stretches is None:  # fractions of the take's duration
                edges = np.round(np.cumsum((0.0, *fractions)) * len(t.time)).astype(int)
                for s, a, b in zip(("train", "val", "test"), edges[:-1], edges[1:], strict=True):
                    if b - a >= 2:
                        add(t, s, int(a), int(b))
                continue
            ranges = cut(t)
            for (a, b), s in zip(ranges, assign_splits(len(ranges), fractions), strict=True):
                add(t, s, a, b)
    if not groups["train"]:
        raise InputError("no take left for the training split")
    splits = {s: _stack(p, robot.topology.n_rods, robot.topology.n_cables) for s, p in groups.items() if p}
    attrs: dict[str, object] = {
        "source": "import-mocap",
        "files": [str(t.source) for t in takes],
        "relabelled_frames": int(sum(t.relabelled_frames for t in takes)),
        "ghost_points": int(sum(t.ghosts for t in takes)),
        "rejected_samples": int(sum(t.rejected for t in takes)),
    }
    if any(t.placement is not None for t in takes):
        attrs["placement"] = {t.source.name: t.placement.to_dict() for t in takes if t.placement is not None}
    if any(t.stretches is not None for t in takes):
        attrs["stretches"] = {t.source.name: [x.to_dict() for x in t.stretches or ()] for t in takes}
    attrs["pieces"] = {s: w for s, w in where.items() if w}
    return Dataset(topology=robot.topology, dt=float(1.0 / np.median(rates)), splits=splits, attrs=attrs)
