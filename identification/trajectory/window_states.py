"""Initial rod states of trajectory windows, fitted on growing prefixes.

A state from smoothing is poor where an impact falls inside the filter's span, and on
a long window a fit started there may stop in another basin. So the states are fitted
on the first :data:`GROW` steps of each window, each stage from the last, then on the
whole window, from the prefixes' state or the one the fit started from, whichever fits
the whole window better: through an impact, a state fitted on a prefix can fly off
over the rest of the window (its error grows by orders of magnitude or to NaN, from
where no step brings it back). ``spin=True`` fits the rods' axial spins too (friction at
an end cap turns a rod about its axis), for clean data: under noise the fit may step
to spins whose explicit gyroscopic integration blows up on longer windows.

With the rods' **rolls** (an effect that sees them, such as box-form quadratic drag),
the rolls and spins are held on the prefixes: short prefixes cannot pin them, and rolls
fitted there stop in the wrong basin. The spins start from the structure's common
angular velocity (:func:`rigid_spins`; a window whose start fits better keeps that
start), the rolls are searched on the whole window
(:func:`search_rolls`) before the prefixes and again before the whole window's fit:
rolls fitted on the prefixes, or spins started at zero, leave the true model's states
well above the noise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import torch

from identification.data.end_caps import RodAxes
from identification.trajectory.param_vector import DTYPE, ParamVector
from identification.trajectory.window_errors import better_states
from identification.trajectory.windowed_fit import WindowFit
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
from identification.trajectory.windows import Windows, end_caps
from tensegrity_env.engine import Engine, State
from tensegrity_env.rotations import quat_mul, quat_to_matrix, shortest_arc

#: window prefixes [steps] the initial states are fitted on before the whole window
GROW = (10, 25, 50, 100, 200, 400)
#: roll offsets [rad] each rod is tried at (half a turn: box drag repeats there)
ROLL_GRID = tuple(np.pi * k / 8 for k in range(8))
#: axial spin offsets [rad/s] tried with each roll, about :func:`rigid_spins`
SPIN_GRID = (-1.0, 0.0, 1.0)
#: axial spins tried per rod by :func:`search_spins`, as fractions of its rolling spin
#: (its fastest end cap's speed over the cap radius: the spin of a cap rolling on the
#: floor without slipping), both ways; 0 keeps the spin as it was
SPIN_FRACTIONS = (0.0, 0.125, -0.125, 0.25, -0.25, 0.5, -0.5, 1.0, -1.0)
#: and judged on each window's first this many steps (the first of :data:`GROW`):
#: friction turns a wrong spin into a drift at once, while over the whole window the
#: error of the rest of a state from smoothing dominates (docs/decisions.md)
SPIN_STEPS = GROW[0]


def prefix(windows: Windows, steps: int) -> Windows:
    """The first ``steps`` steps of every window."""
    ctrl = None if windows.control is None else windows.control[:, :steps]
    valid = None if windows.valid is None else windows.valid[:, : steps + 1]
    return replace(windows, obs=windows.obs[:, : steps + 1], control=ctrl, valid=valid)


def fit_states(
    engine: Engine, vec: ParamVector, windows: Windows, iters: int, spin: bool = False,
    roll: bool = False, grow: bool = True,
) -> WindowFit:  # fmt: skip
    """Only the windows' initial states (``vec``: nothing free), on growing prefixes.

    ``spin``: the axial spins too (from the prefix of 25 steps on); ``roll``: the rods'
    roll about their axes (see :func:`~identification.trajectory.windows.local_basis`),
    searched and fitted on the whole window only, with the spins if ``spin`` (started
    from :func:`rigid_spins`, or from the start's own per window where that fits the
    window better: states fitted at a nearby model hold each rod's spin, and on the
    floor friction spins each rod on its own).
    ``grow=False``: no prefixes, for states already fitted at a nearby model. Returns
    the fit on the whole windows (its ``history[-1]``: mean squared end-cap error [m^2]).
    """
    empty = torch.zeros(0, dtype=torch.float64)
    if roll:
        start = windows
        if spin:
            windows = replace(windows, state=rigid_spins(windows.state, vec.axes.axis))
        windows = search_rolls(engine, vec, windows, spin)
        # (a start fitted at a nearby model holds each rod's own spin: kept where better)
        windows = better_states(engine, vec, empty, start, windows)[0]
    seed = windows
    stages = [g for g in GROW if grow and g < windows.steps]
    for n in stages:
        w = fit(WindowedProblem(engine, vec, prefix(windows, n), empty),
                FitOptions.states(iters, spin=spin and n >= 25 and not roll))
        windows = replace(windows, state=w.windows.state)
    if stages:  # a state fitted on a prefix can fly off over the rest of the window
        windows = better_states(engine, vec, empty, seed, windows)[0]
    if roll:
        windows = search_rolls(engine, vec, windows, spin)
    return fit(WindowedProblem(engine, vec, windows, empty), FitOptions.states(iters, spin, roll))


#: samples at each window's start the forward seed (:func:`forward_seeds`) fits a
#: quadratic to
FORWARD_SAMPLES = 3


def forward_seeds(windows: Windows, axes: RodAxes, dt: float) -> Windows:
    """``windows`` with initial states read from their own first samples only.

    A smoothing filter centred on a window's first sample mixes in the samples before
    it: across an impact there, or at a trajectory's first sample, where it
    extrapolates, it can put a rod metres per second off (a drop from rest read as
    9.5 m/s at 60 Hz). A quadratic through each end cap's first
    :data:`FORWARD_SAMPLES` seen samples of the window gives positions and velocities
    from the window alone; rod states from them as
    :func:`~identification.data.end_caps.smooth_rod_states` (shortest arc, no spin).
    Where a cap has too few seen samples there, or a rod's caps coincide, the window's
    own state stays. ``dt`` [s] between samples.
    """
    k = min(FORWARD_SAMPLES, windows.steps + 1)
    obs = windows.obs[:, :k].numpy()  # (B, k, 2R, 3)
    seen = windows.seen()[:, :k].numpy()  # (B, k, 2R)
    t = np.arange(k) * dt
    V = np.stack([np.ones(k), t, t**2], axis=1)[:, : min(3, k)]  # (k, order+1)
    W = seen[..., None].astype(float)  # weights (B, k, 2R, 1)
    A = np.einsum("ki,bkc,kj->bcij", V, W[..., 0], V)  # (B, 2R, o, o)
    rhs = np.einsum("ki,bkc,bkcd->bcid", V, W[..., 0], obs)  # (B, 2R, o, 3)
    ok = seen.sum(1) >= V.shape[1]  # (B, 2R)
    A = np.where(ok[..., None, None], A, np.eye(V.shape[1]))
    coef = np.linalg.solve(A, rhs)  # (B, 2R, o, 3)
    B, C = ok.shape
    x0, x1 = coef[:, :, 0].reshape(B, C // 2, 2, 3), coef[:, :, 1].reshape(B, C // 2, 2, 3)
    d, dd = x0[:, :, 1] - x0[:, :, 0], x1[:, :, 1] - x1[:, :, 0]
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    good = ok.reshape(B, C // 2, 2).all(-1) & (length[..., 0] > 0)  # (B, R)
    u = d / np.where(length > 0, length, 1.0)
    lam = axes.frac[:, None]
    fresh = State.from_numpy(x0[:, :, 0] + lam * d, x1[:, :, 0] + lam * dd,
                             shortest_arc(axes.direction, u),
                             np.cross(u, dd / np.where(length > 0, length, 1.0)))  # fmt: skip
    keep = torch.as_tensor(good)
    state = State(*(torch.where(keep.view(B, -1, *[1] * (a.dim() - 2)), a.to(b.dtype), b)
                    for a, b in zip(fresh.tensors(), windows.state.tensors(), strict=True)))  # fmt: skip
    return replace(windows, state=state)


def rigid_spins(state: State, axis: np.ndarray) -> State:
    """``state`` (B, R, ·) with each rod's axial spin that of the structure turning as one body.

    End caps show each rod's angular velocity across its axis, not along it. The
    structure's angular velocity ``W`` that best matches every rod's across its axis
    (least squares, ``Σ_r P_r W = Σ_r P_r ω_r`` with ``P_r`` the projection across rod
    r's axis) gives each rod's spin ``a_r · W``: a thrown tensegrity turns nearly as one
    body (its springs are stiff), so the rods' spins follow from each other's tumbling.
    Where the axes do not span space (parallel rods), the spins are kept.
    """
    a = torch.stack([quat_to_matrix(state.q)[:, r, :, int(k)] for r, k in enumerate(axis)], 1)
    proj = torch.eye(3, dtype=DTYPE) - a[..., :, None] * a[..., None, :]  # (B, R, 3, 3)
    lhs = proj.sum(1)
    rhs = torch.einsum("brij,brj->bi", proj, state.omega)
    ok = torch.linalg.cond(lhs) < 1e6
    w = torch.linalg.solve(torch.where(ok[:, None, None], lhs, torch.eye(3, dtype=DTYPE)), rhs)
    along = torch.einsum("bri,bri->br", a, state.omega)
    target = torch.einsum("bri,bi->br", a, w)
    d = torch.where(ok[:, None], target - along, torch.zeros_like(along))
    return State(state.p, state.v, state.q, state.omega + a * d[..., None])


def turned(state: State, rod: int, axis: int, angle: torch.Tensor, spin: torch.Tensor) -> State:
    """``state`` (B, R, ·) with rod ``rod`` rolled by ``angle`` [rad] and its axial spin
    raised by ``spin`` [rad/s] (B,), about its principal axis ``axis``."""
    half = torch.zeros(len(angle), 4, dtype=DTYPE)
    half[:, 0] = torch.cos(angle / 2)
    half[:, 1 + axis] = torch.sin(angle / 2)
    q, omega = state.q.clone(), state.omega.clone()
    q[:, rod] = quat_mul(state.q[:, rod], half)
    omega[:, rod] = state.omega[:, rod] + quat_to_matrix(state.q[:, rod])[..., axis] * spin[:, None]
    return State(state.p, state.v, q, omega)


@torch.no_grad()
def search_rolls(engine: Engine, vec: ParamVector, windows: Windows, spin: bool) -> Windows:
    """Each rod's roll (and axial spin if ``spin``) set to the best of a grid, per window.

    Rod by rod, the others held, every offset of :data:`ROLL_GRID` (times :data:`SPIN_GRID`)
    is rolled out on the whole window; the one with the smallest sum of squared
    end-cap errors is kept (no offset is among them: never worse). The roll's error
    landscape has a basin every quarter or half turn; a fit from the roll of
    smoothing and no spin may stop in the wrong one.
    """
    spins = SPIN_GRID if spin else (0.0,)
    grid = torch.tensor([(a, s) for a in ROLL_GRID for s in spins], dtype=DTYPE)
    B = windows.size
    eng = vec.engine(engine, torch.zeros(0, dtype=DTYPE))
    state = best_per_rod(eng, vec, windows, len(grid), lambda many, r, axis: turned(
        many, r, axis, grid[:, 0].repeat_interleave(B), grid[:, 1].repeat_interleave(B)))
    return replace(windows, state=state)


def best_per_rod(
    eng: Engine, vec: ParamVector, windows: Windows, G: int,
    turn: Callable[[State, int, int], State],
) -> State:  # fmt: skip
    """Rod by rod, the others held: ``turn(many, r, axis)`` gives G candidate states of
    rod ``r`` (about its end-cap ``axis``) for every window of ``windows`` (G * B
    states, candidate-major), each rolled out over the windows with ``eng`` at ``vec``'s
    start; each window keeps its candidate with the smallest sum of squared (weighted)
    end-cap errors. Returns the windows' states so chosen, (B,)."""
    B = windows.size
    params = vec.params(vec.start)
    obs = windows.obs.repeat(G, 1, 1, 1)
    ctrl = None if windows.control is None else windows.control.repeat(G, 1, 1, 1)
    cables = None if windows.cables is None else windows.cables.repeat(G, 1, 1)
    w = windows.weights()
    weights = None if w is None else w.repeat(G, 1, 1, 1)
    state = windows.state
    for r, axis in enumerate(vec.axes.axis):
        many = State(*(x.repeat(G, *([1] * (x.dim() - 1))) for x in state.tensors()))
        many = turn(many, r, int(axis))
        out = eng.rollout(many, params, windows.steps, ctrl, cables)
        err = end_caps(eng, out.p, out.q) - obs
        if weights is not None:
            err = err * weights
        sse = torch.nan_to_num(err.pow(2).sum(dim=(1, 2, 3)), nan=np.inf).reshape(G, B)
        pick = sse.argmin(0) * B + torch.arange(B)
        state = State(*(x[pick] for x in many.tensors()))
    return state


def rolling_spins(engine: Engine, state: State, radius: np.ndarray) -> torch.Tensor:
    """Each rod's rolling spin [rad/s], (B, R): the speed of its faster end cap
    (``v + ω × arm``) over the cap ``radius`` (R,) [m], the axial spin at which a cap
    rolls on the floor without slipping."""
    arms = torch.einsum("brij,rkj->brki", quat_to_matrix(state.q), engine.end_offsets)
    speed = (state.v[:, :, None] + torch.cross(state.omega[:, :, None].expand_as(arms), arms,
                                               dim=-1)).norm(dim=-1).amax(-1)  # fmt: skip
    return speed / torch.as_tensor(radius, dtype=DTYPE)


@torch.no_grad()
def search_spins(
    engine: Engine, vec: ParamVector, windows: Windows, steps: int = SPIN_STEPS
) -> Windows:
    """Each rod's axial spin set to the best of a grid, per window.

    A rod rolling on a floor on its end caps spins about its axis at up to its
    :func:`rolling_spins` (tens of rad/s on thin rods), far faster than it tumbles,
    and end caps do not show that spin: smoothing reads none. Through friction the
    spin decides where the rod goes, and a state fit started from no spin stops in
    another basin (on a drawn plant rolling on sphere caps, the true model's states
    fitted from smoothing end at 3.6 times the noise, and at 1.8 with only the true
    spins put in). Rod by rod, the others held, every fraction of
    :data:`SPIN_FRACTIONS` of the rod's rolling spin is added to its spin and rolled
    out over the window's first ``steps`` steps; the one with the smallest sum of
    squared end-cap errors there is kept (the spin as it was is among them). ``vec``:
    nothing free (the model held at its start)."""
    frac = torch.tensor(SPIN_FRACTIONS, dtype=DTYPE)
    full, windows = windows, prefix(windows, min(steps, windows.steps))
    G, B = len(frac), windows.size
    eng = vec.engine(engine, torch.zeros(0, dtype=DTYPE))
    scale = rolling_spins(eng, windows.state, vec.axes.radius)  # (B, R)
    zero = torch.zeros(G * B, dtype=DTYPE)
    state = best_per_rod(eng, vec, windows, G, lambda many, r, axis: turned(
        many, r, axis, zero, torch.nan_to_num(frac.repeat_interleave(B) * scale[:, r].repeat(G))))
    return replace(full, state=state)
