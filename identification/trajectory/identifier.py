"""Identification from noisy measured end caps (motion capture).

Measured data holds end-cap positions only, ``nodes`` (N, T+1, 2R, 3) [m], with
Gaussian noise of ~1 mm. Finite differences of such positions destroy accelerations,
so identification runs in two stages:

1. **Smoothing + linear regression** (:func:`smoothed_regression`): a Savitzky-Golay
   filter gives end-cap positions, velocities and accelerations in continuous time;
   rod states and their rates follow from the rod geometry, and the paper's linear
   equations of motion (:func:`identification.linear.design.rod_blocks`) are solved exactly.
   Fast, but biased by the noise left after smoothing and by the smoothing itself.
2. **Multi-step trajectory fit** (:func:`fit_windows`): the trajectories are cut into
   windows; each window's initial rod state and the physical parameters (log K, c,
   l0, M, I_perp, h; anchors fixed) are free, the differentiable engine rolls every
   window out (batched, float64) and Levenberg-Marquardt minimises the mean squared
   end-cap position error. That is maximum likelihood under Gaussian position noise.
   The window states are local unknowns, so each iteration solves the normal
   equations by a Schur complement on the parameters (bundle-adjustment structure).
   Jacobians come from forward differences through the engine, all directions
   rolled out as one batch (three times cheaper than forward-mode AD here); the
   reverse-mode gradient is available as a check. Windows grow from short (which
   forgive a rough start) to long (which carry far more information per sample).

What end caps cannot show: a rod whose end caps lie on one of its principal axes
can spin about that axis unseen. Its axial moment of inertia enters the motion only
through the (unknown) axial angular momentum ``I_axial * omega_axial``, so it is not
identifiable; simulation uses the solid-cylinder value ``M r^2 / 2`` of the fitted
mass and the per-window axial spin absorbs the rest. :attr:`TrajectoryIdentifier.notes_`
says so; the two perpendicular inertias are one parameter ``I_perp`` per rod. The
axial spins themselves barely show (and make Gauss-Newton converge slowly), so they
are freed only in a last stage, and only when a score test says the data can see
them (clean data, long windows); otherwise they stay 0.

Data needed (icosahedron, 1 kHz, 1 mm noise, initial speeds ~0.5 m/s and ~1.5 rad/s,
no control; the damping c is always the weakest group). Long windows matter far more
than the number of samples: at the truth, one 4 s trajectory gives a largest relative
standard error of c of 2.1 % with 0.5 s windows but 1.1 % with 2 s windows, and 1.2 s
of data cut into 0.1 s windows gives 23 %. Two 0.6 s trajectories give K, M, I_perp
within 1 % and c within ~4 %; four 2 s trajectories (8000 samples) give every K, c, M,
I_perp within 0.6 % (``tests/test_noisy.py``, the slow test). The dataset generator's
livelier small preset (16 trajectories of 0.3 s, speeds up to 1 m/s and 3 rad/s) gives
every K, c, M, I_perp within 1.4 % from 4800 samples. The reported standard
errors (:attr:`TrajectoryIdentifier.stderr_`) are honest (z-scores of rms ~1) and
shrink as one over the square root of the data.

Modules: this one holds the smoothing, stage 1 and :class:`TrajectoryIdentifier`;
the parameter vector is in :mod:`identification.trajectory.param_vector` and the windows and the
Levenberg-Marquardt machinery in :mod:`identification.trajectory.windowed_fit` (their names are
re-exported here).

Cost: every Levenberg-Marquardt iteration rolls out ``n_local + n_free + 1`` copies
(155 for the icosahedron) of all the data: ~1.2 s per 1000 samples on one core.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.signal import savgol_filter
from tqdm.auto import tqdm

from identification.data.dataset import Dataset, Split
from identification.linear.design import (
    ParameterLayout,
    accumulate_normal,
    hinge_blocks,
    rod_blocks,
    rod_slots,
    with_hinges,
)
from identification.linear.features import TransitionFeatures
from identification.linear.solve import solve_constrained
from identification.trajectory.param_vector import (  # noqa: F401  (re-exported)
    DTYPE,
    GROUPS,
    LOG_BOX,
    ParamVector,
    RodAxes,
    parse_anchors,
)
from identification.trajectory.windowed_fit import (  # noqa: F401  (re-exported)
    STATE_KEYS,
    NormalEquations,
    WindowFit,
    Windows,
    _damped,
    _stderr,
    cut_windows,
    end_caps,
    fill_grid,
    fit_windows,
    gauss_newton_fd,
    linearize,
    local_basis,
    perturb,
    schur_step,
    window_residual,
    window_schedule,
    window_sse,
)
from tensegrity_env.engine import Engine
from tensegrity_env.engine.forces import spring_frames
from tensegrity_env.engine.kinematics import AttachmentPoints, Kinematics
from tensegrity_env.io_utils import InputError
from tensegrity_env.rotations import quat_to_matrix, shortest_arc
from tensegrity_env.topology import Topology


# ---------------------------------------------------------------------- measured data
def add_measurement_noise(dataset: Dataset, std: float = 1e-3, seed: int = 0) -> Dataset:
    """A copy with i.i.d. Gaussian noise of ``std`` [m] on every end-cap coordinate.

    Only ``nodes`` (noisy) and ``control`` are kept: rod states are dropped, as motion
    capture would not give them. Each split draws from its own seeded stream.
    """
    splits = {}
    for k, (name, split) in enumerate(sorted(dataset.splits.items())):
        rng = np.random.default_rng([seed, k])
        noisy = split.nodes + std * rng.standard_normal(split.nodes.shape)
        splits[name] = Split(nodes=noisy, control=split.control.copy())
    attrs = {**dataset.attrs, "measurement_noise_std": float(std)}
    return Dataset(dataset.topology, dataset.dt, splits, attrs=attrs, path=None)


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

    @property
    def margin(self) -> int:
        """Samples at each end where the filter extrapolates."""
        return min(self.window // 2, (self.p.shape[1] - 1) // 2)


def smooth_rod_states(
    nodes: np.ndarray, dt: float, axes: RodAxes, window: int, polyorder: int = 3
) -> SmoothedStates:
    """Savitzky-Golay smoothing of end caps ``nodes`` (N, T+1, 2R, 3) and the rod states.

    ``window`` is the filter length in samples (odd; clipped to the trajectory). The
    perpendicular angular velocity and acceleration are ``u × u̇`` and ``u × ü`` of
    the rod direction ``u``.
    """
    T1 = nodes.shape[1]
    window = min(window, T1 if T1 % 2 else T1 - 1)
    window = max(window, polyorder + 2 + (polyorder % 2 == 0))
    kw = {"window_length": window, "polyorder": polyorder, "axis": 1, "delta": dt}
    x, xd, xdd = (savgol_filter(nodes, deriv=d, **kw) for d in range(3))
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
        q=shortest_arc(np.eye(3)[axes.axis], u),  # the roll about u is not seen by end caps
        omega=omega, alpha=alpha, window=window,
    )  # fmt: skip


# ---------------------------------------------------------------------- stage 1
def smoothed_features(
    topology: Topology, s: SmoothedStates, control: np.ndarray, keep: np.ndarray | None = None
) -> TransitionFeatures:
    """:class:`TransitionFeatures` at every sample ``t < T`` away from the ends (``s.margin``).

    Continuous-time accelerations from the smoothing replace the transition's finite
    differences; ``control`` is (N, T, R, 3); ``keep`` (N, T) selects samples (None: all).
    """
    T = control.shape[1]
    t = slice(s.margin, max(s.margin + 1, min(T, s.p.shape[1] - s.margin)))

    def pick(arr: np.ndarray) -> torch.Tensor:
        part = arr[:, t]
        flat = part.reshape(-1, *arr.shape[2:]) if keep is None else part[keep[:, t]]
        return torch.as_tensor(flat, dtype=DTYPE)

    p, q, omega, alpha, accel = map(pick, (s.p, s.q, s.omega, s.alpha, s.a))
    x_end, xd_end, u = map(pick, (s.x, s.xd, control))
    n, R = p.shape[:2]
    rot = quat_to_matrix(q)
    anchors = torch.as_tensor(topology.anchor_positions, dtype=DTYPE).expand(n, -1, -1)
    x_all, xd_all = [x_end, anchors], [xd_end, torch.zeros_like(anchors)]
    points, point_arms = AttachmentPoints.of(topology), None
    if points is not None:  # on the rod axes (refused otherwise), placed by the smoothing
        v = pick(s.v)
        point_arms = torch.einsum("npij,pj->npi", rot[:, points.rod], points.offset)
        x_all.append(p[:, points.rod] + point_arms)
        xd_all.append(v[:, points.rod] + torch.cross(omega[:, points.rod], point_arms, dim=-1))
    kin = Kinematics(
        rot=rot,
        arms=x_end.reshape(n, R, 2, 3) - p.unsqueeze(2),
        x=torch.cat(x_all, dim=1),
        xd=torch.cat(xd_all, dim=1),
        points=points,
        point_arms=point_arms,
    )
    nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long)
    arm_u = torch.einsum("nrij,rj->nri", rot, torch.as_tensor(topology.control_arms, dtype=DTYPE))
    return TransitionFeatures(
        accel=accel,
        alpha_local=torch.einsum("nrji,nrj->nri", rot, alpha),
        omega_local=torch.einsum("nrji,nrj->nri", rot, omega),
        rot=rot,
        arms=kin.node_arms,
        springs=spring_frames(kin, nodes[:, 0], nodes[:, 1]),
        control=u,
        control_arm=arm_u,
    )


def smoothed_regression(
    topology: Topology,
    smooth: SmoothedStates,
    control: np.ndarray,
    anchors: Mapping[str, float] | None = None,
    gravity: Sequence[float] = (0.0, 0.0, -9.81),
    keep: np.ndarray | None = None,
    knots: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Stage 1: linear regression on smoothed end caps (see :func:`smooth_rod_states`).

    ``keep`` (N, T): the samples used (None: all), e.g. those away from a floor.
    ``knots`` (S,) [m]: also fit each spring's stiffness change ``ΔK`` below its knot
    (:func:`~identification.linear.design.hinge_blocks`), returned as ``compression_stiffness``
    with its standard error ``compression_stiffness_se`` (S,) [N/m].
    Returns natural-unit values: ``stiffness``, ``damping``, ``rest_length`` (S,),
    ``mass``, ``inertia_perp`` (R,) and ``control_gain`` (1,); NaN where the regression
    cannot tell. Samples near the ends, where the filter extrapolates, are not used.
    Anchors (see :func:`parse_anchors`) fix the scale; without one it is ``mass`` of the
    first rod = 1.
    """
    topo = topology
    axes = RodAxes.of(topo)
    layout = ParameterLayout.build(topo)
    slots = rod_slots(layout)
    feat = smoothed_features(topo, smooth, control, keep)
    P = layout.n_params
    S = topo.n_springs if knots is not None else 0
    blocks = rod_blocks(feat, slots, torch.tensor(gravity, dtype=DTYPE))
    if knots is not None:
        blocks = torch.cat([blocks, hinge_blocks(feat, slots, torch.as_tensor(knots))], dim=-1)
        slots = with_hinges(slots, P, S)
    normal = torch.zeros(P + S + 1, P + S + 1, dtype=DTYPE)
    accumulate_normal(blocks, slots, P + S, normal)
    fixed = {}
    rods, springs = [r.name for r in topo.rods], [s.name for s in topo.springs]
    for (group, i), value in parse_anchors(topo, anchors or {}).items():
        names = {
            "mass": [f"mass[{rods[i]}]"],
            "stiffness": [f"stiffness[{springs[i]}]"],
            "damping": [f"damping[{springs[i]}]"],
            "control_gain": ["control_gain"],
            "inertia_perp": [
                f"inertia[{rods[i]},{'xyz'[k]}]" for k in range(3) if k != axes.axis[i]
            ],
        }.get(group, [])  # rest lengths do not set the scale
        for name in names:
            fixed[layout.lookup(name)] = float(value)
    if not any(v != 0 for v in fixed.values()):
        fixed = {layout.index("mass", 0): 1.0}
    sol = solve_constrained(normal[:-1, :-1], fixed, feat.n * topo.n_rods * 6)
    th = {
        g: [] for g in ("mass", "inertia", "stiffness", "stiffness_rest", "damping", "control_gain")
    }
    for value, group in zip(sol.theta[:P], layout.groups, strict=True):
        th[group].append(value)
    hinge = {"compression_stiffness": sol.theta[P:], "compression_stiffness_se": sol.stderr[P:]}
    inertia = np.array(th["inertia"]).reshape(-1, 3)
    perp = np.isfinite(inertia) & (np.eye(3)[axes.axis] == 0)  # the two perpendicular axes
    count = perp.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return {
            "stiffness": np.array(th["stiffness"]),
            "damping": np.array(th["damping"]),
            "rest_length": np.array(th["stiffness_rest"]) / np.array(th["stiffness"]),
            "mass": np.array(th["mass"]),
            "inertia_perp": np.where(count > 0, np.where(perp, inertia, 0).sum(1) / count, np.nan),
            "control_gain": np.array(th["control_gain"]),
        } | (hinge if S else {})


def _odd(x: float) -> int:
    n = max(round(x), 5)
    return n if n % 2 else n + 1


# ---------------------------------------------------------------------- the estimator
class TrajectoryIdentifier:
    """Identification from (noisy) end caps: smoothing + regression, then trajectory fits.

    Stage 2 runs :func:`fit_windows` on windows growing from ``first_window`` to
    ``window`` steps (:func:`window_schedule`); each stage starts from the previous
    stage's parameters and, for its windows' initial states, from the previous
    stage's fitted trajectories. Short windows forgive a rough start; long windows
    carry far more information per sample (see the module notes).

    Args:
        anchors: known values fixing the common scale of M, I, K, c, h, e.g.
            ``{"mass[rod0]": 1.95}`` (see :func:`parse_anchors`). Without one, results
            are ratios to ``mass`` of the first rod (``mode_ == "ratios"``).
        window: steps per window in the final stage (capped at the trajectory length).
        smoothing: Savitzky-Golay window of stage 1 [s] (cubic).
        max_iter: Levenberg-Marquardt iterations per stage (one Jacobian each).
        seed: seed of the random window subset of the first stage.
        progress: show a progress bar over the iterations.
        first_window: steps per window in the first stage.
        max_windows: at most this many (random) windows in the first stage; None: all.
        gravity: known gravitational acceleration, (3,) [m/s^2].
        tol: the final windows' stages stop when the full Gauss-Newton step would lower
            the chi-square by less than this (earlier stages: 1); see :func:`fit_windows`.
        exact_gradient: use the reverse-mode gradient (see :func:`linearize`).
        threads: torch intra-op threads during ``fit`` (restored after); the tensors are
            small, so extra threads mostly add overhead (and stall on a busy machine).

    After ``fit``: ``params_`` (:class:`Params`), ``initial_params_`` (stage 1),
    ``history_`` (mean squared end-cap error [m^2] before the first and after each
    iteration, all stages), ``stages_`` (window length, windows, whether the axial
    spins were free, iterations and RMS error [m] per stage; the spin stage is skipped
    when a score test finds the spins invisible, and ``spin_fitted_`` says which),
    ``stderr_`` (relative standard error of each fitted
    parameter), ``notes_`` (parameter name -> why the data cannot identify it; its value
    in ``params_`` is assumed, for simulation only), ``rms_`` (final end-cap RMS error
    [m], an estimate of the measurement noise), ``mode_``, ``converged_``.
    """

    def __init__(
        self,
        anchors: Mapping[str, float] | None = None,
        window: int = 1000,
        smoothing: float = 0.1,
        max_iter: int = 20,
        seed: int = 0,
        progress: bool = False,
        first_window: int = 100,
        max_windows: int | None = 64,
        gravity: Sequence[float] = (0.0, 0.0, -9.81),
        tol: float = 0.1,
        exact_gradient: bool = False,
        threads: int | None = 1,
    ) -> None:
        if min(window, first_window) < 1 or max_iter < 0 or not smoothing > 0:
            raise InputError("windows >= 1 step, max_iter >= 0 and smoothing > 0 are required")
        self.anchors = dict(anchors or {})
        self.window = int(window)
        self.smoothing = float(smoothing)
        self.max_iter = int(max_iter)
        self.seed = seed
        self.progress = progress
        self.first_window = int(first_window)
        self.max_windows = max_windows
        self.gravity = tuple(float(g) for g in gravity)
        self.tol = tol
        self.exact_gradient = exact_gradient
        self.threads = threads

    def fit(self, dataset: Dataset, split: str = "train") -> TrajectoryIdentifier:
        """Identify the parameters from the end caps (and control) of ``split``."""
        threads = torch.get_num_threads()
        try:
            if self.threads is not None:
                torch.set_num_threads(self.threads)
            return self._fit(dataset, split)
        finally:
            torch.set_num_threads(threads)

    def _fit(self, dataset: Dataset, split: str) -> TrajectoryIdentifier:
        topo, data = dataset.topology, dataset.split(split)
        off_axis = topo.off_axis_points()
        if off_axis:
            raise InputError(
                f"springs attach at points off their rod's axis ({', '.join(off_axis[:3])}); "
                "placing them needs each rod's twist, which smoothed end caps do not give"
            )
        axes = RodAxes.of(topo)
        anchors = parse_anchors(topo, self.anchors)
        sg = _odd(self.smoothing / dataset.dt)
        smooth = smooth_rod_states(data.nodes, dataset.dt, axes, sg)
        start = smoothed_regression(topo, smooth, data.control, self.anchors, self.gravity)
        has_control = bool(np.any(data.control != 0))
        vec = self._vector(topo, axes, start, anchors, has_control)
        engine = Engine(topo, dataset.dt)
        grid = {k: getattr(smooth, k).copy() for k in STATE_KEYS}
        theta = vec.start[vec.free]
        schedule = window_schedule(self.first_window, min(self.window, data.n_transitions))
        self.history_, self.stages_ = [], []
        bar = tqdm(
            total=self.max_iter * (len(schedule) + 1), desc="trajectory fit", unit="it",
            disable=not self.progress,
        )  # fmt: skip
        # the axial spins are fitted last, on the final windows, if the data can see them
        plan = [(W, False) for W in schedule] + [(schedule[-1], True)]
        self.spin_fitted_ = False
        for k, (W, spin) in enumerate(plan):
            windows = cut_windows(data.nodes, data.control, grid, W)
            if k == 0 and self.max_windows is not None and windows.size > self.max_windows:
                rng = np.random.default_rng(self.seed)
                windows = windows.take(np.sort(rng.choice(windows.size, self.max_windows, False)))

            def tick(mse: float, W: int = W) -> None:
                bar.update(1)
                bar.set_postfix(window=W, rms=f"{np.sqrt(mse):.3e} m")

            n_spin = windows.size * topo.n_rods if spin else 0
            gate = n_spin + 3 * np.sqrt(2 * n_spin) if spin else None  # chi2(n_spin) + 3 sd
            tol = self.tol if k >= len(schedule) - 1 else 1.0
            fit = fit_windows(
                engine, vec, windows, theta, self.max_iter, tol, tick, self.exact_gradient,
                spin=spin, gate=gate,
            )  # fmt: skip
            if spin and gate is not None and fit.score < gate:  # spins invisible: keep 0
                self.stages_.append(
                    {"window": windows.steps, "windows": windows.size, "spin": True,
                     "iterations": 0,
                     "skipped": f"score test: chi2 gain {fit.score:.1f} < {gate:.1f} "
                     f"for {n_spin} axial spins, which stay 0"}
                )  # fmt: skip
                break
            self.spin_fitted_ = spin
            final, theta = fit, fit.theta
            fill_grid(engine, vec.params(vec.full(theta)), fit.windows, grid)
            self.history_ += fit.history if k == 0 else fit.history[1:]
            self.stages_.append(
                {"window": windows.steps, "windows": windows.size, "spin": spin,
                 "iterations": len(fit.history) - 1, "rms": float(np.sqrt(fit.history[-1]))}
            )  # fmt: skip
        bar.total = bar.n
        bar.close()
        self.topology_, self.dt_ = topo, dataset.dt
        self.vector_ = vec
        self.params_ = vec.params(vec.full(theta).detach())
        self.initial_params_ = vec.params(vec.start)
        self.converged_ = final.converged
        self.windows_ = final.windows
        self.rms_ = float(np.sqrt(self.history_[-1]))
        names = vec.names()
        free = torch.nonzero(vec.free)[:, 0].tolist()
        self.stderr_ = {names[i]: float(s) for i, s in zip(free, final.stderr, strict=True)}
        self.notes_ = self._notes(topo, axes, has_control)
        return self

    def _vector(
        self, topo: Topology, axes: RodAxes, start: dict[str, np.ndarray],
        anchors: dict[tuple[str, int], float], has_control: bool,
    ) -> ParamVector:  # fmt: skip
        """Log-parameter vector: stage-1 values (repaired where unusable), anchors fixed."""
        values, free = [], []
        self.mode_ = "anchored"
        if not any(g != "rest_length" for g, _ in anchors):
            anchors = {**anchors, ("mass", 0): 1.0}
            self.mode_ = "ratios"
        for group in GROUPS:
            v = np.array(start[group], dtype=float)
            good = np.isfinite(v) & (v > 0)
            v[~good] = np.median(v[good]) if good.any() else 1.0
            fixed = np.zeros(len(v), dtype=bool)
            for (g, i), value in anchors.items():
                if g == group:
                    v[i], fixed[i] = value, True
            if group == "control_gain" and not has_control:
                v[:], fixed[:] = 1.0, True
            values.append(v)
            free.append(~fixed)
        return ParamVector(
            topology=topo,
            axes=axes,
            start=torch.as_tensor(np.log(np.concatenate(values)), dtype=DTYPE),
            free=torch.as_tensor(np.concatenate(free)),
            gravity=torch.tensor(self.gravity, dtype=DTYPE),
        )

    @staticmethod
    def _notes(topo: Topology, axes: RodAxes, has_control: bool) -> dict[str, str]:
        notes = {
            f"inertia[{rod.name},{'xyz'[k]}]": (
                "axial inertia: spin about the axis through both end caps is invisible in "
                "end-cap data; not identifiable (value in params_ is the assumed solid "
                "cylinder M r^2/2, for simulation only)"
            )
            for rod, k in zip(topo.rods, axes.axis, strict=True)
        }
        if not has_control:
            notes["control_gain"] = "no control in this data; not identifiable (assumed 1)"
        return notes

    @property
    def unidentifiable(self) -> list[str]:
        """Names of the parameters the data cannot identify (see ``notes_``)."""
        return list(self.notes_)
