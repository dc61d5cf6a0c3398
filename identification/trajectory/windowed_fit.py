"""The normal equations of the windowed trajectory fit: forward-difference Jacobians
through the engine of the windows' initial states and the parameters, the damped
Schur-complement step (bundle-adjustment structure) inside the parameters' box, and
the standard errors.

The problem and its Levenberg-Marquardt loop are
:mod:`identification.trajectory.windowed_problem`; the windows themselves are
:mod:`identification.trajectory.windows`; the method and its cost are described in
:mod:`identification.trajectory.identifier`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np
import torch

from identification.linear.solve import Equilibrated
from identification.trajectory.forked import side_by_side, window_groups, window_jobs
from identification.trajectory.param_vector import DTYPE, ParamVector
from identification.trajectory.window_errors import window_sses
from identification.trajectory.windows import (
    Windows,
    end_caps,
    perturb,
    window_residual,
)
from tensegrity_env.engine import Engine, State
from tensegrity_env.io_utils import InputError


# ---------------------------------------------------------------------- stage 2
@dataclass(frozen=True)
class NormalEquations:
    """Gauss-Newton normal equations with per-window (local) and parameter (global) blocks.

    Attributes:
        H_ll: (B, n_l, n_l); H_lg: (B, n_l, n_g); g_l: (B, n_l);
        H_gg: (n_g, n_g); g_g: (n_g,); sse: sum of squared residuals [m^2]; m: residuals;
        g_gb: each window's share of ``g_g``, (B, n_g) (the sandwich's scores).
    """

    H_ll: torch.Tensor
    H_lg: torch.Tensor
    g_l: torch.Tensor
    H_gg: torch.Tensor
    g_g: torch.Tensor
    sse: float
    m: int
    g_gb: torch.Tensor


def linearize(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor, theta: torch.Tensor,
    chunk: int, step: float = 1e-7, exact_gradient: bool = False,
) -> NormalEquations:  # fmt: skip
    """Gauss-Newton normal equations of all windows at ``theta`` and the current states.

    ``J`` comes from forward differences of step ``step`` along every local coordinate
    and every free log-parameter (:func:`gauss_newton_fd`). Its ~1e-7 relative error
    barely moves the optimum (the shift is ~1e-7 of a standard error; none on clean
    data, where the residual vanishes). ``exact_gradient`` replaces ``Jᵀr`` by the
    exact gradient (reverse mode through the engine), about twice the cost. The windows
    are linearized in groups of at most ``chunk`` (:func:`window_groups`), in worker
    processes where :func:`~identification.trajectory.forked.window_workers` allows.
    """
    H_ll, H_lg, g_l, g_gb = [], [], [], []
    n_g = len(theta)
    H_gg = torch.zeros(n_g, n_g, dtype=DTYPE)
    g_g = torch.zeros(n_g, dtype=DTYPE)
    sse, m = 0.0, 0
    groups = [win.take(g) for g in window_groups(win.size, chunk)]
    tasks = [partial(group_equations, engine, vec, part, basis, theta, step, exact_gradient)
             for part in groups]  # fmt: skip
    # each window rolled out once and once per perturbed coordinate
    work = max(g.size for g in groups) * (basis.shape[0] + n_g + 1) * win.steps
    for part, (ll, lg, gg, gl, gb, gt, part_sse) in zip(
        groups, side_by_side(tasks, window_jobs(work)), strict=True
    ):
        H_ll.append(ll)
        H_lg.append(lg)
        g_l.append(gl)
        g_gb.append(gb)
        H_gg += gg
        g_g += gt
        sse += part_sse
        m += part.residuals
    return NormalEquations(
        torch.cat(H_ll), torch.cat(H_lg), torch.cat(g_l), H_gg, g_g, sse, m, torch.cat(g_gb)
    )


#: assemblies stepped at once by a forward-difference Jacobian (windows times perturbed
#: copies): the most windows a group of :func:`linearize` holds follows from it
FD_BATCH = 6000
#: a states-only fit on at least this many windows runs in at least two groups, so a
#: second core has a share of it (``bench_window_groups.py --states-only``: 48 floor
#: windows linearize in 0.51 of the time in two workers)
SPLIT_WINDOWS = 16


def group_size(basis: torch.Tensor, theta: torch.Tensor, windows: int) -> int:
    """The most windows in one group of a fit on ``windows`` windows: each is stepped
    with one perturbed copy per local coordinate (``basis`` (n_l, ...)) and per fitted
    coordinate (``theta`` (n_g,)), at most :data:`FD_BATCH` copies in a group. A fit of
    the windows' states only (``theta`` empty) takes at most half of them from
    :data:`SPLIT_WINDOWS` windows on: its windows are independent, each one's equations
    the same in any group. A joint fit's shared blocks sum over its groups, and the
    order of that sum moves a fit through round-off (enough to end a fit in another
    basin), so its grouping is left to the batch. Depends on the
    fit's sizes only (never on the workers), so the arithmetic is the same for any
    ``--jobs``."""
    most = max(1, FD_BATCH // (basis.shape[0] + len(theta) + 1))
    if windows >= SPLIT_WINDOWS and len(theta) == 0:
        most = min(most, -(-windows // 2))
    return most


def group_equations(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor, theta: torch.Tensor,
    step: float, exact_gradient: bool,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, float]:  # fmt: skip
    """One group of windows' share of :func:`linearize`: :func:`gauss_newton_fd`'s
    ``H_ll``, ``H_lg``, ``H_gg``, ``g_l`` and per-window ``g_g``, then the group's ``g_g``
    (exact where asked) and its ``rᵀr`` [m^2]."""
    ll, lg, gg, gl, gb, sse = gauss_newton_fd(engine, vec, win, basis, theta, step)
    gt = gb.sum(0)
    if exact_gradient:
        z = torch.zeros(win.size, basis.shape[0], dtype=DTYPE, requires_grad=True)
        th = theta.clone().requires_grad_(True)
        r = window_residual(engine, vec, win, basis)(z, th)
        gl, gt = torch.autograd.grad(0.5 * (r * r).sum(), (z, th))
    return ll, lg, gg, gl, gb, gt, sse


@torch.no_grad()
def gauss_newton_fd(
    engine: Engine,
    vec: ParamVector,
    win: Windows,
    basis: torch.Tensor,
    theta: torch.Tensor,
    step: float,
    block: int = 25,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, float]:
    """``JᵀJ`` and ``Jᵀr`` by forward differences, and the sum of squares ``rᵀr`` [m^2].

    Returns ``H_ll`` (B, n_l, n_l), ``H_lg`` (B, n_l, n_g), ``H_gg`` (n_g, n_g), ``g_l``
    (B, n_l), ``g_g`` per window (B, n_g) and ``rᵀr``. The windows and one perturbed copy per
    coordinate (``n_t = n_l + n_g``) are stepped as one batch of ``(n_t + 1) B`` (the
    parameters get a batch dimension); the products are accumulated every ``block``
    steps, so memory does not grow with the window length.
    """
    n_l, n_g, b = basis.shape[0], len(theta), win.size
    n_e = vec.n_effect
    n_t = n_l + n_g - n_e  # coordinates perturbed inside the one batch
    eye = step * torch.eye(n_t, dtype=DTYPE).repeat_interleave(b, dim=0)
    z = torch.cat([torch.zeros(b, n_l, dtype=DTYPE), eye[:, :n_l]])
    th_p = vec.split(theta)[0]
    th = torch.cat([th_p.expand(b, n_g - n_e), th_p + eye[:, n_l:]])
    state = State(*(x.repeat(n_t + 1, *([1] * (x.dim() - 1))) for x in win.state.tensors()))
    state = perturb(state, torch.einsum("bl,lrj->brj", z, basis))
    params = vec.params(vec.full(th))
    ctrl = None if win.control is None else win.control.repeat(n_t + 1, 1, 1, 1)
    cables = None if win.cables is None else win.cables.repeat(n_t + 1, 1, 1)
    eng = vec.engine(engine, theta)
    # effect coordinates: one more rollout of the windows each, with its own engine
    extra = []
    for k in range(n_e):
        e = torch.zeros(n_g, dtype=DTYPE)
        e[n_g - n_e + k] = step
        extra.append(vec.engine(engine, theta + e))
    p0 = vec.params(vec.full(theta))
    extra_state = [win.state] * n_e
    H_ll = torch.zeros(b, n_l, n_l, dtype=DTYPE)
    H_lg = torch.zeros(b, n_l, n_g, dtype=DTYPE)
    H_gg = torch.zeros(n_g, n_g, dtype=DTYPE)
    g_l = torch.zeros(b, n_l, dtype=DTYPE)
    g_g = torch.zeros(b, n_g, dtype=DTYPE)
    sse, t0 = 0.0, 0
    caps = [end_caps(engine, state.p, state.q)]
    caps_e = [[end_caps(engine, s.p, s.q)] for s in extra_state]
    for t in range(win.steps):
        u = None if ctrl is None else ctrl[:, t]
        uc = None if cables is None else cables[:, t]
        state = eng.step(state, params, u, uc)
        caps.append(end_caps(engine, state.p, state.q))
        for k in range(n_e):
            extra_state[k] = extra[k].step(extra_state[k], p0, None if u is None else u[:b],
                                           None if uc is None else uc[:b])  # fmt: skip
            caps_e[k].append(end_caps(engine, extra_state[k].p, extra_state[k].q))
        if len(caps) == block or t == win.steps - 1:
            x = torch.stack(caps, dim=1).reshape(n_t + 1, b, len(caps), -1)
            if n_e:
                xe = torch.stack([torch.stack(c, dim=1).reshape(b, len(caps), -1) for c in caps_e])
                x = torch.cat([x, xe])
            r = (x[0] - win.obs[:, t0 : t0 + len(caps)].flatten(2)).flatten(1)  # (b, m)
            J = (x[1:] - x[:1]).flatten(2) / step  # (n_l + n_g, b, m)
            w = win.weights(t0, t0 + len(caps))
            if w is not None:
                w = w.expand(-1, -1, win.obs.shape[2], win.obs.shape[3]).flatten(1)  # (b, m)
                r, J = r * w, J * w
            Jl, Jg = J[:n_l], J[n_l:]
            H_ll += torch.einsum("ibm,jbm->bij", Jl, Jl)
            H_lg += torch.einsum("ibm,jbm->bij", Jl, Jg)
            H_gg += torch.einsum("ibm,jbm->ij", Jg, Jg)
            g_l += torch.einsum("ibm,bm->bi", Jl, r)
            g_g += torch.einsum("ibm,bm->bi", Jg, r)
            sse += float((r * r).sum())
            t0, caps, caps_e = t0 + len(caps), [], [[] for _ in range(n_e)]
    return H_ll, H_lg, H_gg, g_l, g_g, sse


def _damped(H: torch.Tensor, lam: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``H + lam D + ε`` and the Marquardt scaling ``D = diag(H)``.

    ``ε = 1e-14 max(D)`` keeps directions the data does not see at all solvable.
    """
    d = torch.diagonal(H, dim1=-2, dim2=-1).clamp_min(0)
    if d.shape[-1] == 0:  # nothing global (only window states fitted)
        return H, d
    floor = 1e-14 * d.amax(-1, keepdim=True).clamp_min(1e-300)
    return H + torch.diag_embed(lam * d + floor), d


def schur_step(
    ne: NormalEquations, lam: float, held: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor, float, torch.Tensor]:
    """Solve ``(H + lam D) δ = -g`` by eliminating the window states.

    ``held`` (n_g,) bool: global coordinates that do not move (``δθ = 0`` there; the
    others and the states solve the system without them).

    Returns δz (B, n_l), δθ (n_g,), the predicted decrease of the sum of squares
    ``δᵀ(lam D δ - g)`` [m^2] and the reduced matrix ``S = A_gg - Σ H_gl A_ll⁻¹ H_lg``
    (of every coordinate, held ones included).
    """
    n_g = ne.H_gg.shape[0]
    A_ll, D_l = _damped(ne.H_ll, lam)
    A_gg, D_g = _damped(ne.H_gg, lam)
    Y = torch.linalg.solve(A_ll, torch.cat([ne.H_lg, ne.g_l.unsqueeze(-1)], dim=-1))
    S = A_gg - torch.einsum("bli,blj->ij", ne.H_lg, Y[..., :n_g])
    b = -ne.g_g + torch.einsum("bli,bl->i", ne.H_lg, Y[..., n_g])
    S = 0.5 * (S + S.T)
    if held is not None and bool(held.any()):
        idx = held.nonzero().squeeze(-1)
        S_free, b = S.clone(), b.clone()
        S_free[idx, :], S_free[:, idx], b[idx] = 0.0, 0.0, 0.0
        S_free[idx, idx] = 1.0
        d_theta = torch.linalg.solve(S_free, b)
    else:
        d_theta = torch.linalg.solve(S, b)
    d_z = -(Y[..., n_g] + torch.einsum("blj,j->bl", Y[..., :n_g], d_theta))
    pred = lam * ((D_l * d_z**2).sum() + (D_g * d_theta**2).sum())
    pred -= (ne.g_l * d_z).sum() + (ne.g_g * d_theta).sum()
    return d_z, d_theta, float(pred), S


def bounded_step(
    ne: NormalEquations,
    lam: float,
    theta: torch.Tensor,
    lo: torch.Tensor,
    hi: torch.Tensor,
    hard: torch.Tensor | None = None,
    hold: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, float, torch.Tensor]:
    """:func:`schur_step` inside the box ``lo <= θ <= hi`` (n_g,).

    ``hard`` (n_g,) bool: coordinates whose bound is physical (a drag coefficient's 0;
    default all). One of those on its bound whose step would leave the box is held
    there and the step solved again without it (an active set); the others (search
    ranges) take the free step. Any coordinate that would cross a bound is stopped on it.
    ``hold`` (n_g,) bool: coordinates held where they are whatever the step.
    """
    held = torch.zeros_like(theta, dtype=torch.bool) if hold is None else hold.clone()
    hard = torch.ones_like(held) if hard is None else hard
    for _ in range(theta.numel() + 1):
        d_z, d_theta, pred, S = schur_step(ne, lam, held)
        out = hard & (((theta <= lo) & (d_theta < 0)) | ((theta >= hi) & (d_theta > 0)))
        if not bool((out & ~held).any()):
            break
        held = held | out
    return d_z, (theta + d_theta).clamp(lo, hi) - theta, pred, S


@dataclass(frozen=True)
class WindowFit:
    """Result of :func:`~identification.trajectory.windowed_problem.fit`.

    Attributes:
        theta: fitted coordinates: free log-parameters and effect coordinates,
            (n_free + n_effect,).
        windows: the windows with fitted initial states (as given where they are held;
            without any the fit left out).
        history: mean squared end-cap error [m^2] at the start and after each iteration.
        stderr: standard error of each free log-parameter (= relative standard error of
            the parameter; an effect coordinate's in its own unit), (n_free + n_effect,):
            the larger of the Gauss-Newton ``σ̂² S⁻¹`` and the window-clustered sandwich
            (:func:`window_stderr`; the dense method: Gauss-Newton's); inf where the data
            cannot see the coordinate.
        score: the chi-square decrease the first Gauss-Newton step promised (NaN: the
            dense method).
        converged: the stopping rule was met (not just ``max_iter``).
        normal: the Gauss-Newton normal equations at ``theta`` and the fitted states.
    """

    theta: torch.Tensor
    windows: Windows
    history: list[float]
    stderr: np.ndarray
    score: float
    converged: bool
    normal: NormalEquations | None = None


def trial_sse(
    engine: Engine,
    vec: ParamVector,
    windows: Windows,
    basis: torch.Tensor,
    theta: torch.Tensor,
    chunk: int,
) -> tuple[np.ndarray, float]:
    """:func:`window_sses` of a trial point, (B,) and their sum [m^2], ``inf`` where the
    engine cannot take it.

    A trial the engine cannot take (a contact solve or an effect at extreme or
    non-finite values, a singular system) is a rejected step, not an error.
    """
    try:
        each, sse = window_sses(engine, vec, windows, basis, theta, chunk)
    except (torch.linalg.LinAlgError, FloatingPointError, InputError):
        return np.full(windows.size, np.inf), float("inf")
    each = np.where(np.isfinite(each), each, np.inf)
    return each, (sse if np.isfinite(sse) else float("inf"))


def state_response(ne: NormalEquations, direction: torch.Tensor) -> torch.Tensor:
    """How the windows' fitted states follow a step of the global coordinates, (B, n_l).

    The Gauss-Newton change of each window's local coordinates (its initial state,
    see :func:`local_basis`) per unit step along ``direction`` (n_g,) with the states
    refitted: ``-H_ll⁻¹ H_lg direction`` (the Schur complement's elimination).
    """
    A_ll, _ = _damped(ne.H_ll, 0.0)
    rhs = torch.einsum("blg,g->bl", ne.H_lg, direction.to(DTYPE)).unsqueeze(-1)
    return -torch.linalg.solve(A_ll, rhs).squeeze(-1)


#: eigenvalues of the equilibrated ``S`` below this fraction of its largest are
#: directions the data does not see: a parameter with a share in them has an infinite
#: standard error
UNSEEN = 1e-13


def window_stderr(ne: NormalEquations, S: torch.Tensor, sigma2: float) -> np.ndarray:
    """Standard errors of the global coordinates, (n_g,), never exactly 0.

    The larger of the Gauss-Newton ``σ̂² diag(S⁻¹)`` (independent residuals) and the
    sandwich ``S⁻¹ (Σ_b s_b s_bᵀ) S⁻¹ · B/(B-1)`` clustered by window, with ``s_b`` the
    window's profiled score ``g_g,b - H_lg,bᵀ H_ll,b⁻¹ g_l,b`` (its initial state
    eliminated), centred: the end-cap errors along one window are far from independent
    (a model error or a poor initial state shifts them together), which the
    Gauss-Newton value ignores. The same form as the contact search's standard errors,
    clustered per touchdown (:mod:`identification.trajectory.touchdown`). ``S`` is
    equilibrated first (:class:`~identification.linear.solve.Equilibrated`: the
    coordinates' curvatures span ten orders of magnitude, a log-stiffness against an
    effect coefficient in its own units); a coordinate with a share in a direction the
    data does not see (eigenvalue of the equilibrated ``S`` below :data:`UNSEEN` of the
    largest) gets inf.
    """
    n_g = S.shape[0]
    if n_g == 0:
        return np.zeros(0)
    eq = Equilibrated.of(S, UNSEEN)  # (symmetrised there)
    inv = eq.inverse()
    gauss = sigma2 * torch.diagonal(inv)
    var = gauss
    B = ne.g_gb.shape[0]
    if B > 1:
        A_ll, _ = _damped(ne.H_ll, 0.0)
        y = torch.linalg.solve(A_ll, ne.g_l.unsqueeze(-1)).squeeze(-1)  # (B, n_l)
        scores = ne.g_gb - torch.einsum("bli,bl->bi", ne.H_lg, y)
        scores = scores - scores.mean(0)
        sandwich = inv @ (scores.T @ scores) @ inv * (B / (B - 1))
        var = torch.maximum(gauss, torch.diagonal(sandwich))
    se = torch.sqrt(var.clamp_min(0)).numpy().copy()
    se[eq.unseen.numpy() | ~(se > 0)] = np.inf
    return se
