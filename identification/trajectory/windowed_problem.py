"""One windowed fit: a model and its windows' initial states fitted to windows of
measured end caps (:class:`WindowedProblem`), solved by :func:`fit`.

Every fit through the engine is one of these problems: the declared parameters and
effect coordinates a :class:`~identification.trajectory.param_vector.ParamVector`
frees (its ``free`` mask, its effect coordinates and their box), some of them held
at their start (``hold``), on :class:`~identification.trajectory.windows.Windows`
whose samples lie at the data's own sample times, and each window's initial state
either fitted with the parameters (the default) or held at the data's
(``states_held``). :func:`fit` solves it by Levenberg-Marquardt:

* ``method="schur"`` (the default): the window states and the parameters jointly, the
  states eliminated by a Schur complement (bundle-adjustment structure;
  :mod:`identification.trajectory.windowed_fit` holds the normal equations);
* ``method="dense"``: the states held, a handful of effect coordinates and a dense
  Jacobian of forward differences (one batched rollout per coordinate): the one-step
  screens' fit of ground contact on many one-step windows from measured rod states.

The named uses of the first (the declared model's fit, a candidate's screen, the joint
fit with contact, the final refit) are built in
:mod:`identification.trajectory.presets` and
:mod:`identification.trajectory.floor_declared`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import torch

from identification.linear.solve import Equilibrated
from identification.trajectory.effect_coords import EffectCoords
from identification.trajectory.param_vector import DTYPE, ParamVector
from identification.trajectory.window_errors import jumped_windows
from identification.trajectory.windowed_fit import (
    WindowFit,
    bounded_step,
    group_size,
    linearize,
    trial_sse,
    window_stderr,
)
from identification.trajectory.windows import Windows, local_basis, perturb, rollout_caps
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import Engine
from tensegrity_env.params import Params


def _quiet(line: str) -> None:
    """A ``log`` that drops its line."""


@dataclass(frozen=True)
class WindowedProblem:
    """What a windowed fit fits, and to what.

    Attributes:
        engine: the engine the windows are rolled out by; the effects of ``vec``'s
            coordinates replace its own at every trial point (its time step is the
            data's sample interval, its substeps the physics step).
        vec: the fitted vector's layout: the free mask over the declared
            log-parameters, the effect coordinates appended to them, and their box
            (:meth:`~identification.trajectory.param_vector.ParamVector.bounds`).
        windows: the measured end caps (B, W+1, 2R, 3) [m] with their commands, the
            windows' initial rod states (B, R, ·), and where each window starts in its
            trajectory (sample times: :attr:`times`).
        theta: where the fit starts, (n_free + n_effect,); None: ``vec.theta0()``.
        hold: which coordinates of ``theta`` (n_free + n_effect,) bool stay at their
            start (None: none).
        states_held: the windows' initial states are data (measured rod states), not
            unknowns: only the coordinates are fitted (``method="dense"``).
        params: with ``states_held``, the declared parameters exactly as given (a
            regression's; None: ``vec``'s start).
    """

    engine: Engine
    vec: ParamVector
    windows: Windows
    theta: torch.Tensor | None = None
    hold: torch.Tensor | None = None
    states_held: bool = False
    params: Params | None = None

    @property
    def start(self) -> torch.Tensor:
        """Where the fit starts, (n_free + n_effect,)."""
        return self.vec.theta0() if self.theta is None else self.theta

    @property
    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Lower and upper bounds of the fitted coordinates, each (n_free + n_effect,)."""
        return self.vec.bounds()

    @property
    def times(self) -> np.ndarray:
        """Time of every sample of every window from its trajectory's first sample,
        (B, W+1) [s]."""
        steps = self.windows.start[:, None] + np.arange(self.windows.steps + 1)
        return steps * self.engine.dt

    @classmethod
    def states_only(
        cls, engine: Engine, vec: ParamVector, theta: torch.Tensor, windows: Windows
    ) -> WindowedProblem:
        """The windows' initial states alone, the model held at ``theta`` (``engine``
        with ``vec``'s effects at ``theta`` in it: :meth:`ParamVector.engine`)."""
        return cls(vec.engine(engine, theta), vec.held_at(theta), windows)


    @classmethod
    def effects_only(
        cls, engine: Engine, params: Params, effects: Sequence[PhysicalEffect],
        free: Sequence[tuple[int, str]], windows: Windows,
    ) -> WindowedProblem:  # fmt: skip
        """Parameters ``free`` ``(effect index, name)`` of ``effects`` (in the effects'
        order) fitted, each in its unconstrained coordinate
        (:func:`~identification.trajectory.effect_coords.to_free`), on ``windows`` from
        their own initial states (held), the declared ``params`` as given: the dense
        method's problem. ``engine``: without effects (``effects`` go in at every trial).
        """
        order = [i for i, _ in free]
        if order != sorted(order):
            raise ValueError("free parameters must be listed in the order of their effects")
        slots = tuple(tuple(k for i, k in free if i == j) for j in range(len(effects)))
        vec = replace(ParamVector.coordinates_only(engine.topology, params),
                      coords=EffectCoords(tuple(effects), slots))  # fmt: skip
        return cls(engine, vec, windows, states_held=True, params=params)

    def effects_at(self, result: WindowFit) -> list[PhysicalEffect]:
        """The effects at ``result``'s coordinates, their standard errors as each one's
        ``uncertainty`` (in the parameters' units: the delta method from log or logit
        coordinates)."""
        if self.vec.coords is None:
            return []
        n = self.vec.n_free
        return self.vec.coords.effects_at(result.theta[n:], result.stderr[n:])


@dataclass(frozen=True)
class FitOptions:
    """How :func:`fit` solves a :class:`WindowedProblem`.

    Attributes:
        method: ``"schur"`` (states and coordinates) or ``"dense"`` (states held).
        max_iter: most Levenberg-Marquardt iterations (one Jacobian each).
        tol: stopping rule: the chi-square the full Gauss-Newton step would still
            remove (schur; 0.1 leaves every parameter well within a fraction of its
            standard error), or the relative decrease of the sum of squares of an
            iteration (dense).
        spin, roll: which local coordinates of the window states are fitted (each
            rod's axial spin, its roll about its axis;
            :func:`~identification.trajectory.windows.local_basis`).
        line_search: a rejected step is tried shorter before more damping, and windows
            whose error jumps are left out (see :func:`fit`).
        gate: with it, nothing is done when the first step promises less chi-square.
        stall: with it (schur), the fit also stops once its last :data:`STALL_ITERS`
            iterations together lowered the chi-square by less than this (the error
            has stopped falling while the Newton decrement stays large: through
            impacts, the Gauss-Newton model promises decreases no step can reach).
        exact_gradient: ``Jᵀr`` by reverse mode through the engine
            (:func:`~identification.trajectory.windowed_fit.linearize`).
        fd_step: forward-difference step of the dense Jacobian (free coordinates).
        progress: called with the mean squared error [m^2] after each iteration.
        log: where the fit's remarks go (one line each).
    """

    method: Literal["schur", "dense"] = "schur"
    max_iter: int = 20
    tol: float = 0.1
    spin: bool = True
    roll: bool = False
    line_search: bool = False
    gate: float | None = None
    stall: float | None = None
    exact_gradient: bool = False
    fd_step: float = 1e-4
    progress: Callable[[float], None] | None = None
    log: Callable[[str], None] = _quiet

    @classmethod
    def dense(cls, max_iter: int = 25, tol: float = 1e-6) -> FitOptions:
        """The dense method's options (its stopping rule is a relative decrease)."""
        return cls(method="dense", max_iter=max_iter, tol=tol)

    @classmethod
    def states(cls, iters: int, spin: bool = False, roll: bool = False) -> FitOptions:
        """The options of a fit of the windows' states alone (a tighter stopping rule:
        the states are cheap, and a later joint fit starts from them)."""
        return cls(max_iter=iters, tol=0.01, spin=spin, roll=roll)


def fit(problem: WindowedProblem, options: FitOptions = FitOptions()) -> WindowFit:
    """Solve ``problem`` by ``options.method`` (see the module docstring).

    Schur: minimises the mean squared end-cap position error of all windows rolled out
    by the engine (Nielsen's damping update, faster when the model is good). Stops
    when the full Gauss-Newton step would lower the chi-square ``sse / σ̂²`` by less
    than ``tol`` (the Newton decrement), when the RMS error reaches round-off (clean
    data), with ``stall`` when the last :data:`STALL_ITERS` iterations together lowered
    the chi-square by less than ``stall``, or after ``max_iter`` iterations. With ``gate``, nothing is done when the
    first step promises less than ``gate`` (a score test: the new unknowns cannot be
    told from noise). ``line_search``: a rejected step is tried at
    :data:`LINE_FRACTIONS` of its length, the shortest error kept if lower, before
    more damping (where the error jumps, as on the floor where impacts cross physics
    steps, the damped steps turn towards the jumps while the Gauss-Newton direction
    still descends). With ``line_search``, a rejected step too short to matter
    (:data:`SHORT_STEP`) that still raised some windows' error by a jump
    (:func:`~identification.trajectory.window_errors.jumped_windows`) leaves those
    windows out and the fit goes on without them (up to :data:`MAX_JUMPED` of the
    windows; each such drop is ``log``-ged): an impact sitting on the edge of a
    physics step makes a window's error discontinuous at the current point, and every
    step then fails on it.

    Dense: see :func:`dense_fit`.
    """
    if options.method == "dense":
        if not problem.states_held:
            raise ValueError("the dense method fits coordinates alone: the problem's states must be held")
        return dense_fit(problem, options)
    if problem.states_held:
        raise ValueError("a problem with held states is solved by the dense method")
    return schur_fit(problem, options)


def schur_fit(problem: WindowedProblem, options: FitOptions) -> WindowFit:
    """:func:`fit`'s Schur-complement Levenberg-Marquardt (its docstring)."""
    engine, vec, windows, theta = problem.engine, problem.vec, problem.windows, problem.start
    hold, tol, gate, log = problem.hold, options.tol, options.gate, options.log
    line_search, exact_gradient = options.line_search, options.exact_gradient
    basis = local_basis(vec.axes, options.spin, options.roll)
    chunk = group_size(basis, theta, windows.size)
    lo, hi = problem.bounds
    hard = vec.hard_bounds()
    theta = theta.clamp(lo, hi)  # a start outside the physical domain (a screen's drag < 0)
    ne = linearize(engine, vec, windows, basis, theta, chunk, exact_gradient=exact_gradient)
    dof = max(ne.m - len(theta) - windows.size * basis.shape[0], 1)
    history = [ne.sse / ne.m]
    exact = (1e-12 * max(1.0, float(windows.obs.abs().max()))) ** 2  # round-off [m^2]
    _, _, newton, S = bounded_step(ne, 0.0, theta, lo, hi, hard, hold)
    score = newton / max(ne.sse / dof, 1e-300)
    done = bool(score < tol or history[-1] < exact or (gate is not None and score < gate))
    lam, nu, converged = 1e-7, 2.0, done

    def tried(
        d_z: torch.Tensor | None, d_theta: torch.Tensor | None
    ) -> tuple[Windows, np.ndarray, float]:
        """The windows moved by ``d_z``, each one's error at ``theta + d_theta`` (B,) and
        their sum [m^2]."""
        if d_z is None or d_theta is None:
            return windows, np.full(windows.size, np.inf), float("inf")
        trial = replace(
            windows, state=perturb(windows.state, torch.einsum("bl,lrj->brj", d_z, basis))
        )
        return trial, *trial_sse(engine, vec, trial, basis, theta + d_theta, chunk)

    now = None  # the current windows' errors (B,) [m^2], once a jump check wants them
    gains: list[float] = []  # each iteration's chi-square decrease (``stall``)
    jumps_left = int(MAX_JUMPED * windows.size)
    for _ in range(options.max_iter if not done else 0):
        while True:
            try:
                d_z, d_theta, pred, _ = bounded_step(ne, lam, theta, lo, hi, hard, hold)
                if not (bool(torch.isfinite(d_theta).all()) and bool(torch.isfinite(d_z).all())):
                    raise FloatingPointError("non-finite step")
            except (torch.linalg.LinAlgError, FloatingPointError):
                d_z, d_theta, pred = None, None, 0.0  # a singular system: more damping
            trial, per_window, sse = tried(d_z, d_theta)
            rho = (ne.sse - sse) / pred if pred > 0 and np.isfinite(sse) else -1.0
            if rho > 0:
                lam *= 0.1 if rho > 0.9 else max(1 / 3, 1 - (2 * rho - 1) ** 3)
                nu = 2.0
                break
            noise_var = ne.sse / dof
            if line_search and jumps_left and d_z is not None and pred < SHORT_STEP * noise_var:
                if now is None:
                    now = trial_sse(engine, vec, windows, basis, theta, chunk)[0]
                jumped = jumped_windows(now, per_window, noise_var)
                if 0 < jumped.sum() <= jumps_left:
                    jumps_left -= int(jumped.sum())
                    windows = windows.take(np.flatnonzero(~jumped))
                    log(f"    {int(jumped.sum())} windows left out of the fit: their error "
                        f"jumps at a step too short to matter (an impact on the edge of a "
                        f"physics step; {windows.size} left)")  # fmt: skip
                    ne = linearize(engine, vec, windows, basis, theta, chunk,
                                   exact_gradient=exact_gradient)  # fmt: skip
                    dof = max(ne.m - len(theta) - windows.size * basis.shape[0], 1)
                    lam, nu, now, gains = 1e-7, 2.0, None, []
                    continue
            if line_search and d_z is not None and d_theta is not None:
                shorter = [(t, *tried(t * d_z, t * d_theta)) for t in LINE_FRACTIONS]
                t, trial, _, sse = min(shorter, key=lambda x: x[3])
                if sse < ne.sse:
                    d_theta = t * d_theta
                    break
            lam, nu = lam * nu, nu * 2
            if lam > 1e10:
                break
        if lam > 1e10:
            converged = True  # no step lowers the error any more
            break
        assert d_theta is not None  # a step was taken: the loop above left with one
        windows, theta, now, before = trial, theta + d_theta, None, ne.sse
        ne = linearize(engine, vec, windows, basis, theta, chunk, exact_gradient=exact_gradient)
        _, _, newton, S = bounded_step(ne, 0.0, theta, lo, hi, hard, hold)
        history.append(ne.sse / ne.m)
        if options.progress is not None:
            options.progress(history[-1])
        gains.append((before - ne.sse) / max(ne.sse / dof, 1e-300))
        if newton < tol * ne.sse / dof or history[-1] < exact or stalled(gains, options.stall):
            converged = True
            break
    stderr = window_stderr(ne, S, ne.sse / dof)
    return WindowFit(theta, windows, history, stderr, score, converged, ne)


#: ``stall``: the iterations whose chi-square decreases are summed (:func:`stalled`)
STALL_ITERS = 3


def stalled(gains: Sequence[float], stall: float | None) -> bool:
    """Whether the last :data:`STALL_ITERS` of ``gains`` (each iteration's chi-square
    decrease, oldest first) sum to less than ``stall`` (never with ``stall`` None or
    fewer iterations)."""
    return stall is not None and len(gains) >= STALL_ITERS and sum(gains[-STALL_ITERS:]) < stall


#: fractions of a rejected step tried along its direction (``line_search``)
LINE_FRACTIONS = (0.5, 0.3, 0.1, 0.03)
#: with ``line_search``, a rejected step that promised less than this many units of
#: chi-square is too short to raise any window's error by itself (a window whose error
#: rose by :data:`~identification.trajectory.window_errors.JUMP` has a discontinuity)
SHORT_STEP = 10.0
#: at most this fraction of the windows is left out so (:func:`fit`)
MAX_JUMPED = 0.1
#: dense method: a coordinate beyond this magnitude (log or logit units) is a trial the
#: engine is not asked to take (an effect at e^50 of its unit)
DENSE_REACH = 50.0


def dense_fit(problem: WindowedProblem, options: FitOptions) -> WindowFit:
    """:func:`fit`'s dense method: Levenberg-Marquardt on the effect coordinates of
    ``problem.vec`` alone, every window rolled out from its own (held) initial state.

    The Jacobian is by forward differences of ``options.fd_step`` (one batched rollout
    per coordinate): effects have a handful of scalars, and the contact gate makes the
    error only piecewise smooth anyway. Damping starts at 1e-2, is divided by 3 after
    an accepted step and multiplied by 4 after a rejected one; the fit stops when an
    iteration lowers the sum of squares by less than ``options.tol`` of it, or finds no
    lower point. ``stderr`` (n,) is Gauss-Newton's on the equilibrated curvature
    (optimistic where window errors are correlated; inf along a direction the data
    does not see); ``score`` is NaN.
    """
    vec, windows = problem.vec, problem.windows
    params = vec.params(vec.start) if problem.params is None else problem.params
    n = len(problem.start)
    control = windows.control
    if control is None:  # no commands: zero ones
        control = torch.zeros(windows.size, windows.steps, vec.topology.n_rods, 3, dtype=DTYPE)

    def residual(theta: torch.Tensor) -> torch.Tensor:
        if not bool(torch.isfinite(theta).all()) or bool((theta.abs() > DENSE_REACH).any()):
            return torch.full((windows.obs.numel(),), float("inf"), dtype=DTYPE)
        eng = vec.engine(problem.engine, theta)
        with torch.no_grad():
            caps = rollout_caps(eng, params, windows.state, control, windows.cables)
        return (caps - windows.obs).reshape(-1)

    theta = problem.start
    r = residual(theta)
    sse = float((r**2).sum())
    history = [sse / r.numel()]
    lam, step_size, converged = 1e-2, options.fd_step, False
    J = torch.zeros(r.numel(), n, dtype=DTYPE)
    for _ in range(options.max_iter):
        for k in range(n):
            e = torch.zeros(n, dtype=DTYPE)
            e[k] = step_size
            J[:, k] = (residual(theta + e) - r) / step_size
        H, g = J.T @ J, J.T @ r
        D = torch.diag(torch.diagonal(H).clamp_min(1e-30))
        improved = False
        while lam < 1e8:
            step = -torch.linalg.solve(H + lam * D, g)
            r_new = residual(theta + step)
            sse_new = float((r_new**2).sum())
            if np.isfinite(sse_new) and sse_new < sse:
                theta, r, improved = theta + step, r_new, True
                rel = (sse - sse_new) / sse
                sse = sse_new
                lam = max(lam / 3, 1e-6)
                break
            lam *= 4
        history.append(sse / r.numel())
        if options.progress is not None:
            options.progress(history[-1])
        if not improved or rel < options.tol:
            converged = True
            break
    sigma2 = sse / max(r.numel() - n, 1)
    eq = Equilibrated.of(J.T @ J)
    se = torch.sqrt(sigma2 * torch.diagonal(eq.inverse()).clamp_min(0)).numpy()
    se[eq.unseen.numpy()] = np.inf  # a direction the data does not see
    return WindowFit(theta.detach(), windows, history, se, float("nan"), converged)
