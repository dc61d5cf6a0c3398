"""Identification from noisy measured end caps (motion capture).

Measured data holds end-cap positions only, ``nodes`` (N, T+1, 2R, 3) [m], with
Gaussian noise of ~1 mm. Finite differences of such positions destroy accelerations,
so identification runs in two stages:

1. **Smoothing + linear regression**
   (:func:`~identification.linear.smoothed.smoothed_regression`): a Savitzky-Golay
   filter gives end-cap positions, velocities and accelerations in continuous time;
   rod states and their rates follow from the rod geometry, and the paper's linear
   equations of motion (:func:`identification.linear.design.rod_blocks`) are solved exactly.
   Fast, but biased by the noise left after smoothing and by the smoothing itself.
2. **Multi-step trajectory fit** (:func:`~identification.trajectory.windowed_problem.fit`): the trajectories are cut into
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
identifiable; simulation uses the fitted mass times the robot file's axial moment per
unit mass (:attr:`tensegrity_env.topology.Rod.axial_gyration`; a solid rod's ``r^2 / 2``
where the file has none) and the per-window axial spin absorbs the rest. :attr:`TrajectoryIdentifier.notes_`
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
I_perp within 0.6 % (``tests/accuracy/test_noisy.py``, the slow test). The dataset generator's
livelier small preset (16 trajectories of 0.3 s, speeds up to 1 m/s and 3 rad/s) gives
every K, c, M, I_perp within 1.4 % from 4800 samples. The reported standard
errors (:attr:`TrajectoryIdentifier.stderr_`) are honest (z-scores of rms ~1) and
shrink as one over the square root of the data.

Modules: this one holds :class:`TrajectoryIdentifier`; the smoothing is
:func:`identification.data.end_caps.smooth_rod_states`, stage 1
:mod:`identification.linear.smoothed`, the parameter vector
:mod:`identification.trajectory.param_vector`, and the windows and the
Levenberg-Marquardt machinery :mod:`identification.trajectory.windowed_fit`.

Cost: every Levenberg-Marquardt iteration rolls out ``n_local + n_free + 1`` copies
(155 for the icosahedron) of all the data: ~1.2 s per 1000 samples on one core.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from identification.data.dataset import Dataset
from identification.data.end_caps import RodAxes, odd_window, smooth_rod_states
from identification.linear.smoothed import parse_anchors, smoothed_regression
from identification.trajectory.param_vector import (
    DTYPE,
    GROUPS,
    ParamVector,
    axial_per_mass,
    gain_sign,
    params_values,
)
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
from identification.trajectory.windows import STATE_KEYS, cut_windows, fill_grid, window_schedule
from tensegrity_env.engine import PHYSICS_DT, Engine, substeps_for
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology


class TrajectoryIdentifier:
    """Identification from (noisy) end caps: smoothing + regression, then trajectory fits.

    Stage 2 runs :func:`~identification.trajectory.windowed_problem.fit` on windows growing from ``first_window`` to
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
            the chi-square by less than this (earlier stages: 1); see :func:`~identification.trajectory.windowed_problem.fit`.
        exact_gradient: use the reverse-mode gradient (see :func:`linearize`).
        threads: torch intra-op threads during ``fit`` (restored after); the tensors are
            small, so extra threads mostly add overhead (and stall on a busy machine).
        physics_dt: the longest physics step [s]; the engine substeps between samples.
        start: the parameters to start from (a params file's, e.g. a robot's nominal
            model); None: the stage-1 regression on the smoothed end caps. Anchors keep
            their values either way.

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
        physics_dt: float = PHYSICS_DT,
        start: Params | None = None,
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
        self.physics_dt = float(physics_dt)
        self.start = start

    def fit(self, dataset: Dataset, split: str = "train") -> TrajectoryIdentifier:
        """Identify the parameters from the end caps (and control) of ``split``."""
        if dataset.topology.n_winches:  # the windows do not carry a winch state
            raise InputError(f"{dataset.path or 'dataset'}: the robot has winches; the "
                             "trajectory fit does not take them yet")  # fmt: skip
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
        sg = odd_window(self.smoothing / dataset.dt)
        smooth = smooth_rod_states(data.nodes, dataset.dt, axes, sg)
        cables = data.cable_control
        if self.start is not None:
            start = params_values(self.start, axes)
        else:
            start = smoothed_regression(topo, smooth, data.control, self.anchors, self.gravity,
                                        cables=cables)  # fmt: skip
        has_control = bool(np.any(data.control != 0))
        has_cables = cables is not None and bool(np.any(cables != 0))
        vec = self.start_vector(topo, axes, start, anchors, has_control, has_cables)
        engine = Engine(topo, dataset.dt, substeps=substeps_for(dataset.dt, self.physics_dt),
                        native=True)
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
            windows = cut_windows(data.nodes, data.control, grid, W, cables)
            if k == 0 and self.max_windows is not None and windows.size > self.max_windows:
                rng = np.random.default_rng(self.seed)
                windows = windows.take(np.sort(rng.choice(windows.size, self.max_windows, False)))

            def tick(mse: float, W: int = W) -> None:
                bar.update(1)
                bar.set_postfix(window=W, rms=f"{np.sqrt(mse):.3e} m")

            n_spin = windows.size * topo.n_rods if spin else 0
            gate = n_spin + 3 * np.sqrt(2 * n_spin) if spin else None  # chi2(n_spin) + 3 sd
            tol = self.tol if k >= len(schedule) - 1 else 1.0
            options = FitOptions(max_iter=self.max_iter, tol=tol, progress=tick,
                                 exact_gradient=self.exact_gradient, spin=spin, gate=gate)  # fmt: skip
            done = fit(WindowedProblem(engine, vec, windows, theta), options)
            if spin and gate is not None and done.score < gate:  # spins invisible: keep 0
                self.stages_.append(
                    {"window": windows.steps, "windows": windows.size, "spin": True,
                     "iterations": 0,
                     "skipped": f"score test: chi2 gain {done.score:.1f} < {gate:.1f} "
                     f"for {n_spin} axial spins, which stay 0"}
                )  # fmt: skip
                break
            self.spin_fitted_ = spin
            final, theta = done, done.theta
            fill_grid(engine, vec.params(vec.full(theta)), done.windows, grid)
            self.history_ += done.history if k == 0 else done.history[1:]
            self.stages_.append(
                {"window": windows.steps, "windows": windows.size, "spin": spin,
                 "iterations": len(done.history) - 1, "rms": float(np.sqrt(done.history[-1]))}
            )  # fmt: skip
        bar.total = bar.n
        bar.close()
        self.topology_, self.dt_ = topo, dataset.dt
        self.vector_ = vec
        self.params_ = vec.params(vec.full(theta).detach())
        self.initial_params_ = vec.params(vec.start)
        self.converged_ = bool(final.converged)
        self.windows_ = final.windows
        self.rms_ = float(np.sqrt(self.history_[-1]))
        names = vec.names()
        free = torch.nonzero(vec.free)[:, 0].tolist()
        self.stderr_ = {names[i]: float(s) for i, s in zip(free, final.stderr, strict=True)}
        self.notes_ = self.notes(topo, axes, has_control, has_cables)
        return self

    def start_vector(
        self, topo: Topology, axes: RodAxes, start: dict[str, np.ndarray],
        anchors: dict[tuple[str, int], float], has_control: bool, has_cables: bool = False,
    ) -> ParamVector:  # fmt: skip
        """The log-parameter vector the fit starts from: stage-1 values ``start`` (repaired
        where unusable, see :func:`~identification.linear.smoothed.smoothed_regression`), anchors
        fixed; sets ``mode_`` ("ratios" without a scale anchor, else "anchored"). Cable
        gains keep the sign stage 1 gives them; without cable commands they are held."""
        values, free = [], []
        cable_sign = gain_sign(start.get("cable_gain", np.zeros(topo.n_cables)))
        start = {**start, "cable_gain": np.abs(start.get("cable_gain", np.zeros(topo.n_cables)))}
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
            if (group == "control_gain" and not has_control) or (group == "cable_gain" and not has_cables):
                v[:], fixed[:] = 1.0, True
            values.append(v)
            free.append(~fixed)
        return ParamVector(
            topology=topo,
            rod_axes=axes,
            start=torch.as_tensor(np.log(np.concatenate(values)), dtype=DTYPE),
            free=torch.as_tensor(np.concatenate(free)),
            gravity=torch.tensor(self.gravity, dtype=DTYPE),
            cable_sign=cable_sign,
            axial=axial_per_mass(start, axes),
        )

    @staticmethod
    def notes(topo: Topology, axes: RodAxes, has_control: bool, has_cables: bool = False) -> dict[str, str]:
        notes = {
            f"inertia[{rod.name},{'xyz'[k]}]": (
                "axial inertia: spin about the axis through both end caps is invisible in "
                "end-cap data (value in params_: the fitted mass times the robot file's axial "
                + ("moment per unit mass" if rod.axial_gyration is not None else "solid-rod r^2/2")
                + ", for simulation only)"
            )
            for rod, k in zip(topo.rods, axes.axis, strict=True)
        }
        if not has_control:
            notes["control_gain"] = "no control in this data (assumed 1)"
        if topo.n_cables and not has_cables:
            for c in topo.cable_actuators:
                notes[f"cable_gain[{topo.springs[c].name}]"] = (
                    "no cable commands in this data (assumed 1)"
                )
        return notes

    @property
    def unidentifiable(self) -> list[str]:
        """Names of the parameters the data cannot identify (see ``notes_``)."""
        return list(self.notes_)
