"""Measured end caps (motion capture) to rod states, and datasets built from them.

Over 400 lines because the three ways from end caps to rod states share the rod
geometry (:class:`RodAxes`) and the handling of gaps; apart they would repeat both.

Motion capture sees points, not rigid-body states. Two end caps per rod fix the
rod's centre of mass and the direction of its axis, and nothing else:

* **spin about the rod axis is unobservable** from two end caps. The orientation
  returned here is the shortest-arc rotation taking the rod-frame axis (end cap 0
  to end cap 1) onto the measured axis, i.e. it has *no twist about the axis*, and
  the angular velocity returned is the component perpendicular to the axis only,
  ``ω_⊥ = a × ȧ``. For a thin rod (tiny axial inertia, springs attached on the axis)
  the axial spin carries no spring force, so the lost component does not matter
  for the springs; the true ``q`` equals the returned one up to a rotation about
  the axis.

Three ways from end caps to rod states (``method`` of :func:`measured_rod_states` and
:func:`with_measured_states`):

* ``"exact"`` (:func:`rod_states_from_nodes`): the caps as given; velocities are
  **central differences** in time (second-order one-sided at the two ends). For data
  from MuJoCo's semi-implicit Euler (``p_{t+1} = p_t + dt v_{t+1}``) the central
  difference of positions is ``(v_t + v_{t+1}) / 2``: half a step behind. With noisy
  caps the velocities are as noisy as the differences make them.
* ``"gaussian"`` (:func:`smooth_nodes`, then the same differences): the caps smoothed
  by a Gaussian kernel of std ``smoothing`` seconds. Its one-step transitions stand in
  for measured ones in the one-step regression and residuals; with 1 mm noise they
  carry the smoothing's bias, so small effects stay hidden.
* ``"savgol"`` (:func:`smooth_rod_states`): a cubic Savitzky-Golay filter of
  ``smoothing`` seconds gives positions, velocities *and* accelerations of the caps in
  continuous time, and the rods' states and rates follow from the geometry
  (:class:`RodAxes`). The first stage of end-cap identification
  (:mod:`identification.linear.smoothed`) regresses on these.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.signal import savgol_filter

from identification.data.dataset import SPLITS, Dataset, Split, check_dataset
from identification.data.quality import PLACEHOLDER_KINDS, placeholder_samples
from tensegrity_env.io_utils import InputError
from tensegrity_env.rotations import np_quat_to_matrix, shortest_arc, unit
from tensegrity_env.topology import Topology


# ---------------------------------------------------------------------- rod geometry
@dataclass(frozen=True)
class RodAxes:
    """End caps on a principal axis through the centre of mass, for every rod.

    Which end of a rod is end cap 0 is the file's choice: end cap 0 -> end cap 1 runs
    along the principal axis ``axis`` in either direction, ``sign``.

    Attributes:
        axis: index (0, 1, 2) of the principal axis holding rod r's end caps, (R,).
        frac: the COM as ``x_0 + frac * (x_1 - x_0)`` between the end caps, (R,).
        radius: each rod's radius [m], (R,), at least 1 mm: its end caps roll on it.
        sign: +1 where end cap 0 -> end cap 1 runs along the positive principal axis,
            -1 where along the negative one, (R,).
    """

    axis: np.ndarray
    frac: np.ndarray
    radius: np.ndarray
    sign: np.ndarray

    @property
    def direction(self) -> np.ndarray:
        """Unit vector from end cap 0 to end cap 1 in each rod's principal frame, (R, 3)."""
        return np.eye(3)[self.axis] * self.sign[:, None]

    @classmethod
    def of(cls, topology: Topology) -> RodAxes:
        """Raise :class:`InputError` if some rod's end caps are not on a principal axis."""
        ends = topology.end_offsets  # (R, 2, 3)
        axis, frac, sign = [], [], []
        for r, e in enumerate(ends):
            k = int(np.argmax(np.abs(e[1] - e[0])))
            off = np.delete(e, k, axis=1)
            scale = np.abs(e).max()
            if np.abs(off).max() > 1e-9 * scale or abs(e[1, k] - e[0, k]) < 1e-12:
                raise InputError(
                    f"rod '{topology.rods[r].name}': end caps are not on a principal axis through "
                    "the centre of mass; end-cap-only identification needs them there"
                )
            axis.append(k)
            frac.append(-e[0, k] / (e[1, k] - e[0, k]))
            sign.append(1.0 if e[1, k] > e[0, k] else -1.0)
        radius = np.array([max(rod.radius, 1e-3) for rod in topology.rods])
        return cls(np.array(axis), np.array(frac), radius, np.array(sign))


# ---------------------------------------------------------------------- end caps -> rod states
def cap_names(topology: Topology) -> list[str]:
    """End-cap names in node order, ``<rod>.0`` and ``<rod>.1`` per rod, (2R,)."""
    return [f"{rod.name}.{k}" for rod in topology.rods for k in (0, 1)]


def check_caps_seen(nodes: np.ndarray, topology: Topology, where: str) -> None:
    """Refuse end caps ``nodes`` (N, T+1, 2R, 3) [m] in which an end cap is never seen
    (a rod's pose needs both of its end caps), or none is seen in four consecutive
    samples (the noise level, from third differences, cannot be estimated, nor any
    window fitted), or which holds placeholder samples for unseen end caps (exactly the
    origin, a position held exactly over frames, a duplicated sample:
    :func:`~identification.data.quality.placeholder_samples`)."""
    held = placeholder_samples(nodes).sum((0, 1))
    if held.any():
        worst = int(np.argmax(held))
        raise InputError(f"{where}: {int(held.sum())} end-cap samples are placeholders for an "
                         f"unseen end cap ({PLACEHOLDER_KINDS}; {cap_names(topology)[worst]}: "
                         f"{int(held[worst])}); "
                         "write them as NaN (import-mocap does)")  # fmt: skip
    valid = np.isfinite(nodes).all(-1)
    seen = valid.any((0, 1))
    if not seen.all():
        never = [name for name, s in zip(cap_names(topology), seen, strict=True) if not s]
        raise InputError(f"{where}: end cap{'s' if len(never) > 1 else ''} {', '.join(never)} "
                         "never seen (a rod's pose needs both of its end caps); check the "
                         "marker map")  # fmt: skip
    runs = valid[:, 3:] & valid[:, 2:-1] & valid[:, 1:-2] & valid[:, :-3]
    if not runs.any():
        raise InputError(f"{where}: no end cap is seen in four consecutive samples: the noise "
                         "level cannot be estimated nor a window fitted (are frames missing "
                         "at a regular interval?)")  # fmt: skip


def rod_states_from_nodes(
    nodes: np.ndarray, topology: Topology, dt: float
) -> dict[str, np.ndarray]:
    """Rod states from end-cap trajectories only (see the module docstring's caveats).

    Args:
        nodes: end-cap positions, (..., T+1, 2R, 3) [m], world frame; rod ``r`` owns
            nodes ``2r`` and ``2r + 1`` (the dataset's ``nodes``). Trailing world
            anchors, if included (``n_nodes`` points), are ignored.
        topology: the assembly; its end offsets say where the caps sit on each rod.
        dt: time between samples [s].

    Returns:
        ``p``, ``v``, ``omega`` (..., T+1, R, 3) and ``q`` (..., T+1, R, 4), as in
        the dataset schema: centre of mass [m] and its velocity [m/s]; principal-frame
        orientation (w, x, y, z) **with no twist about the rod axis** (shortest arc
        from the rod-frame axis); angular velocity [rad/s] **perpendicular to the
        axis only** (spin about the axis cannot be seen from two end caps).

    The centre of mass is placed from the end caps and the topology's end offsets:
    exact when it lies on the line through the end caps (every rod of the MJCF
    convention); an off-line centre of mass additionally depends on the unobservable
    twist and is placed using the no-twist orientation.
    """
    nodes = np.asarray(nodes, dtype=float)
    R = topology.n_rods
    if nodes.ndim < 3 or nodes.shape[-1] != 3 or nodes.shape[-2] not in (2 * R, topology.n_nodes):
        raise InputError(
            f"end caps have shape {nodes.shape}, expected (..., T+1, {2 * R}, 3) for {R} rods"
        )
    if nodes.shape[-3] < 2:
        raise InputError("end caps: need at least 2 samples in time")
    off_axis = topology.off_axis_points()
    if off_axis:
        raise InputError(
            f"end caps: springs attach at points off their rod's axis ({', '.join(off_axis[:3])}"
            f"{', ...' if len(off_axis) > 3 else ''}); placing them needs each rod's twist,"
            " which two tracked end caps do not give (record rod states)"
        )
    if not np.isfinite(dt) or dt <= 0:
        raise InputError(f"end caps: time step dt must be positive, got {dt}")
    x0, x1 = nodes[..., 0 : 2 * R : 2, :], nodes[..., 1 : 2 * R : 2, :]  # (..., T+1, R, 3)
    ends = topology.end_offsets  # (R, 2, 3), rod frame
    d_rod = ends[:, 1] - ends[:, 0]
    a_rod = unit(d_rod)
    d = x1 - x0
    a = unit(d)
    q = shortest_arc(a_rod, a)
    # COM = e0 + s (e1 - e0) + c_perp in the rod frame (origin = COM)
    s = -np.sum(ends[:, 0] * d_rod, axis=-1) / np.sum(d_rod * d_rod, axis=-1)  # (R,)
    c_perp = -(ends[:, 0] + s[:, None] * d_rod)  # (R, 3), zero for on-axis COM
    p = x0 + s[:, None] * d
    if np.any(np.abs(c_perp) > 1e-12):
        p = p + np.einsum(
            "...ij,...j->...i", np_quat_to_matrix(q), np.broadcast_to(c_perp, p.shape)
        )
    edge: Literal[1, 2] = 2 if nodes.shape[-3] >= 3 else 1
    v = np.gradient(p, dt, axis=-3, edge_order=edge)
    a_dot = np.gradient(a, dt, axis=-3, edge_order=edge)
    omega = np.cross(a, a_dot)  # ω_⊥ = a × ȧ for a unit vector turning as ȧ = ω × a
    return {"p": p, "v": v, "q": q, "omega": omega}


def smooth_nodes(nodes: np.ndarray, dt: float, smoothing: float) -> np.ndarray:
    """End caps (N, T+1, 2R, 3) smoothed along time: Gaussian of std ``smoothing`` [s].

    The ``"gaussian"`` method: the one-step transitions of these caps are double
    differences, which amplify whatever the filter passes by 1/dt², and a Gaussian
    kernel has no side lobes to pass high-frequency noise (``"savgol"`` instead
    differentiates its fitted polynomials, :func:`smooth_rod_states`). The ends are
    extended by a cubic fit (``mode="nearest"`` would bend them). ``smoothing`` below
    half a sample returns ``nodes`` unchanged. Gaps (NaN) are bridged by a normalized
    convolution over the seen samples; where a gap is too long for the kernel (less
    than 5 % of its weight on seen samples) the result stays NaN, and callers leave
    those samples out.
    """
    sigma = smoothing / dt
    if sigma < 0.5:
        return nodes
    if not np.isfinite(nodes).all():  # gaps: normalized convolution over the seen samples
        seen = np.isfinite(nodes).all(-1, keepdims=True).astype(float)
        num = gaussian_filter1d(np.where(seen > 0, nodes, 0.0), sigma, axis=1, mode="constant")
        den = gaussian_filter1d(seen, sigma, axis=1, mode="constant")
        with np.errstate(invalid="ignore", divide="ignore"):
            out = num / den
        out[np.broadcast_to(den < 0.05, out.shape)] = np.nan  # too far from any sample
        return out
    pad = min(int(4 * sigma), nodes.shape[1] - 1)
    w = min(nodes.shape[1] if nodes.shape[1] % 2 else nodes.shape[1] - 1, 2 * pad + 1)
    ext = savgol_filter(nodes, window_length=max(w, 5), polyorder=3, axis=1, mode="interp")
    head = 2 * ext[:, :1] - nodes[:, pad:0:-1]  # point reflection about the smoothed ends
    tail = 2 * ext[:, -1:] - nodes[:, -2 : -pad - 2 : -1]
    padded = np.concatenate([head, nodes, tail], axis=1)
    return gaussian_filter1d(padded, sigma, axis=1, mode="nearest")[:, pad : pad + nodes.shape[1]]


@dataclass(frozen=True)
class SmoothedStates:
    """Rod kinematics from smoothed end caps, all (N, T+1, R, ·), world frame.

    Attributes:
        x, xd: end-cap positions [m] and velocities [m/s], (N, T+1, 2R, 3).
        p, v, a: COM position [m], velocity [m/s], acceleration [m/s^2].
        q: orientation (w, x, y, z) with the shortest-arc axial phase, (..., 4).
        omega, alpha: angular velocity [rad/s] and acceleration [rad/s^2] perpendicular
            to the rod (the axial part is unobservable and set to 0).
        window: the filter length used [samples].
        whole: (N, T+1) bool, every end cap seen at every sample of the filter's window
            around that sample (all True without gaps). Accelerations where a gap falls
            inside the window come from a polynomial fitted across it: the regression
            uses only ``whole`` samples.
    """

    x: np.ndarray
    xd: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    q: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    window: int
    whole: np.ndarray

    @property
    def finite(self) -> np.ndarray:
        """(N, T+1) bool: every rod's state and rates are defined at that sample (False
        where a gap was too long for the filter to bridge)."""
        fields = (self.x, self.xd, self.p, self.v, self.a, self.q, self.omega, self.alpha)
        return np.logical_and.reduce([np.isfinite(f).all(axis=(2, 3)) for f in fields])

    @property
    def margin(self) -> int:
        """Samples at each end where the filter extrapolates."""
        return min(self.window // 2, (self.p.shape[1] - 1) // 2)


def smooth_rod_states(
    nodes: np.ndarray, dt: float, axes: RodAxes, window: int, polyorder: int = 3
) -> SmoothedStates:
    """The ``"savgol"`` method: rod states and rates from a cubic Savitzky-Golay fit.

    ``nodes``: end caps (N, T+1, 2R, 3) [m]; ``dt`` [s]; ``window``: the filter length in
    samples (odd, see :func:`odd_window`; clipped to the trajectory). Positions,
    velocities and accelerations are the fitted polynomials and their derivatives (no
    finite differences); the perpendicular angular velocity and acceleration are
    ``u × u̇`` and ``u × ü`` of the rod direction ``u``, and the orientation the
    shortest arc from the rod's own end cap 0 -> end cap 1 direction
    (:attr:`RodAxes.direction`, either sign) onto ``u`` (no twist, as
    :func:`rod_states_from_nodes`). Gaps (NaN)
    are fitted through by :func:`masked_savgol`; a rod's states are NaN where a gap of
    either end cap is too long to bridge (:attr:`SmoothedStates.finite` is False there).
    """
    T1 = nodes.shape[1]
    window = min(window, T1 if T1 % 2 else T1 - 1)
    window = max(window, polyorder + 2 + (polyorder % 2 == 0))
    if np.isfinite(nodes).all():
        kw = {"window_length": window, "polyorder": polyorder, "axis": 1, "delta": dt}
        x, xd, xdd = (savgol_filter(nodes, deriv=d, **kw) for d in range(3))
    else:
        x, xd, xdd = masked_savgol(nodes, dt, window, polyorder)
    N, _, n2, _ = nodes.shape
    shape = (N, T1, n2 // 2, 2, 3)
    x, xd, xdd = (y.reshape(shape) for y in (x, xd, xdd))
    lam = axes.frac[:, None]
    d, dd, ddd = (y[..., 1, :] - y[..., 0, :] for y in (x, xd, xdd))
    p, v, a = (y[..., 0, :] + lam * dy for y, dy in ((x, d), (xd, dd), (xdd, ddd)))
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    u = d / length
    omega = np.cross(u, dd / length)
    alpha = np.cross(u, ddd / length)
    return SmoothedStates(
        x=x.reshape(nodes.shape), xd=xd.reshape(nodes.shape), p=p, v=v, a=a,
        q=shortest_arc(axes.direction, u),  # the roll about u is not seen by end caps
        omega=omega, alpha=alpha, window=window, whole=whole_windows(nodes, window),
    )  # fmt: skip


def whole_windows(nodes: np.ndarray, window: int) -> np.ndarray:
    """(N, T+1) bool: every end cap of ``nodes`` (N, T+1, 2R, 3) is seen throughout the
    ``window``-sample filter window used at each sample (one-sided at the ends, as
    :func:`masked_savgol`)."""
    T1 = nodes.shape[1]
    h = window // 2
    missing = (~np.isfinite(nodes).all(axis=(-1, -2))).astype(int)  # (N, T+1)
    count = np.concatenate([np.zeros((len(nodes), 1), int), np.cumsum(missing, axis=1)], axis=1)
    centre = np.clip(np.arange(T1), h, max(h, T1 - 1 - h))
    lo, hi = np.clip(centre - h, 0, T1), np.clip(centre + h + 1, 0, T1)
    return (count[:, hi] - count[:, lo]) == 0


def masked_savgol(
    nodes: np.ndarray, dt: float, window: int, polyorder: int = 3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Savitzky-Golay through gaps: at every sample a polynomial of ``polyorder`` is
    fitted by least squares to the end cap's *seen* samples within ``window`` (NaN in
    ``nodes`` (N, T+1, 2R, 3) is a gap; near the ends the window is one-sided, as
    ``savgol_filter``'s ``mode="interp"``). Returns positions [m], velocities [m/s] and
    accelerations [m/s²] of the fit, each like ``nodes``. Where a window holds fewer
    than ``polyorder + 2`` seen samples (a gap too long to bridge) the result is NaN,
    never a filled-in value.
    """
    N, T1, C, _ = nodes.shape
    h = window // 2
    n_c = T1 - 2 * h  # window centres h .. T1-1-h; the ends use the nearest whole window
    seen = np.isfinite(nodes).all(-1)
    y = np.where(seen[..., None], nodes, 0.0)
    w = seen.astype(float)
    k = np.arange(-h, h + 1, dtype=float)
    P = polyorder + 1
    basis = k[:, None] ** np.arange(P)  # (window, P)
    gram = np.zeros((N, n_c, C, P, P))
    rhs = np.zeros((N, n_c, C, P, 3))
    count = np.zeros((N, n_c, C))
    for j in range(2 * h + 1):
        wj, yj = w[:, j : j + n_c], y[:, j : j + n_c]
        gram += wj[..., None, None] * np.outer(basis[j], basis[j])
        rhs += wj[..., None, None] * basis[j][:, None] * yj[..., None, :]
        count += wj
    ok = count >= polyorder + 2
    gram[~ok] = np.eye(P)
    coef = np.linalg.solve(gram, rhs)  # (N, n_c, C, P, 3) in powers of the sample offset
    coef[~ok] = np.nan
    t = np.arange(T1)
    centre = np.clip(t, h, T1 - 1 - h)
    u = (t - centre).astype(float)  # offset of each sample from its window's centre
    c = coef[:, centre - h]  # (N, T1, C, P, 3)
    powers = np.arange(P)
    dpow = [u[:, None] ** powers, powers * u[:, None] ** np.clip(powers - 1, 0, None),
            powers * (powers - 1) * u[:, None] ** np.clip(powers - 2, 0, None)]  # fmt: skip
    x, xd, xdd = (np.einsum("tp,ntcpk->ntck", d, c) / dt**i for i, d in enumerate(dpow))
    return x, xd, xdd


def odd_window(x: float) -> int:
    """A Savitzky-Golay window of about ``x`` samples: odd, at least 5."""
    n = max(round(x), 5)
    return n if n % 2 else n + 1


#: ways from end caps to rod states (see the module docstring)
Method = Literal["exact", "gaussian", "savgol"]
METHODS: tuple[str, ...] = ("exact", "gaussian", "savgol")


def measured_rod_states(
    nodes: np.ndarray, topology: Topology, dt: float, method: Method, smoothing: float = 0.0
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Rod states from end caps by ``method`` (see the module docstring).

    Args:
        nodes: end caps (N, T+1, 2R, 3) [m], world frame.
        topology: the assembly.
        dt: time between samples [s].
        method: ``"exact"``, ``"gaussian"`` or ``"savgol"``.
        smoothing: the filter's std (``"gaussian"``) or length (``"savgol"``) [s];
            not used by ``"exact"``.

    Returns:
        the end caps the states belong to (smoothed, or ``nodes`` itself for
        ``"exact"``) and ``p``, ``v``, ``q``, ``omega`` as :func:`rod_states_from_nodes`.
        With gaps (NaN end caps) the states are NaN at every sample whose differences
        (or filter window, ``"savgol"``) reach a sample where some end cap was not
        seen, so that a fit on them leaves those samples out rather than using values
        made up across the gap.
    """
    if method == "exact":
        out, st = nodes, rod_states_from_nodes(nodes, topology, dt)
        whole = seen_around(nodes)
    elif method == "gaussian":
        out = smooth_nodes(nodes, dt, smoothing)
        st, whole = rod_states_from_nodes(out, topology, dt), seen_around(nodes)
    elif method == "savgol":
        s = smooth_rod_states(nodes, dt, RodAxes.of(topology), odd_window(smoothing / dt))
        out, st, whole = s.x, {"p": s.p, "v": s.v, "q": s.q, "omega": s.omega}, s.whole
    else:
        raise InputError(f"unknown smoothing method '{method}' (use {', '.join(METHODS)})")
    if not whole.all():
        st = {k: np.where(whole[..., None, None], v, np.nan) for k, v in st.items()}
    return out, st


def seen_around(nodes: np.ndarray) -> np.ndarray:
    """(N, T+1) bool: every end cap of ``nodes`` (N, T+1, 2R, 3) seen at the sample and
    its two neighbours (what a central difference there uses)."""
    return whole_windows(nodes, 3)


def with_measured_states(
    dataset: Dataset, smoothing: float = 0.01, method: Method = "gaussian"
) -> Dataset:
    """The dataset with rod states in every split (from its end caps where it had none).

    ``method`` and ``smoothing`` [s] as in :func:`measured_rod_states`; the splits
    derived keep the end caps their states belong to.
    """
    if all(s.has_states for s in dataset.splits.values()):
        return dataset
    splits = {}
    for name, s in dataset.splits.items():
        if s.has_states:
            splits[name] = s
            continue
        nodes, st = measured_rod_states(s.nodes, dataset.topology, dataset.dt, method, smoothing)
        splits[name] = Split(nodes=nodes, control=s.control, **st)
    how = {"exact": "unsmoothed", "gaussian": f"Gaussian smoothing {smoothing:g} s",
           "savgol": f"Savitzky-Golay smoothing {smoothing:g} s"}[method]  # fmt: skip
    attrs = {**dataset.attrs, "states": f"from end caps, {how}"}
    return Dataset(dataset.topology, dataset.dt, splits, attrs=attrs, path=dataset.path)


# ---------------------------------------------------------------------- datasets
def dataset_from_end_caps(
    topology: Topology,
    dt: float,
    nodes: Mapping[str, np.ndarray],
    control: Mapping[str, np.ndarray] | None = None,
    attrs: Mapping[str, Any] | None = None,
) -> Dataset:
    """A dataset from end-cap trajectories only, e.g. motion capture.

    Args:
        topology: the assembly (rods with their end offsets, springs, anchors).
        dt: time between samples [s].
        nodes: split name (``train``, ``val``, ``test``) -> end caps (N, T+1, 2R, 3)
            [m] world frame, or a single trajectory (T+1, 2R, 3). Rod ``r`` owns
            nodes ``2r`` (its end cap 0) and ``2r + 1`` (end cap 1).
        control: split name -> commands f_u (N, T, R, 3) applied during each step,
            world frame; None (or a missing split) means no control.
        attrs: provenance stored in the file (e.g. ``{"source": "vicon, 200 Hz"}``).

    Returns:
        a :class:`~identification.data.dataset.Dataset` without rod states (they are
        derived by :func:`rod_states_from_nodes` when needed); write it with
        :func:`identification.data.dataset.write_dataset`. Raises :class:`InputError` on
        bad shapes or non-finite values.
    """
    if "train" not in nodes:
        raise InputError(f"end-cap data: needs a 'train' split (got {sorted(nodes)})")
    splits: dict[str, Split] = {}
    R = topology.n_rods
    for name, arr in nodes.items():
        if name not in SPLITS:
            raise InputError(f"end-cap data: unknown split '{name}' (use {', '.join(SPLITS)})")
        x = np.asarray(arr, dtype=float)
        if x.ndim == 3:
            x = x[None]
        if x.ndim != 4 or x.shape[2:] != (2 * R, 3):
            raise InputError(
                f"end-cap data: split '{name}' has shape {np.shape(arr)}, expected "
                f"(N, T+1, {2 * R}, 3) or (T+1, {2 * R}, 3)"
            )
        ctrl = None if control is None else control.get(name)
        if ctrl is None:
            ctrl = np.zeros((x.shape[0], max(x.shape[1] - 1, 0), R, 3))
        else:
            ctrl = np.asarray(ctrl, dtype=float)
            if ctrl.ndim == 3 and x.shape[0] == 1:
                ctrl = ctrl[None]
        splits[name] = Split(nodes=x, control=ctrl)
    ds = Dataset(
        topology=topology,
        dt=float(dt),
        splits=splits,
        attrs={"assembly": topology.name, "source": "end caps", **dict(attrs or {})},
    )
    check_dataset(ds, "end-cap data")
    return ds
