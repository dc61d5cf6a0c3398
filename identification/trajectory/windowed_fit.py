"""Windowed trajectory fits through the engine: windows of measured end caps, their
initial states and the parameters fitted by Levenberg-Marquardt with a Schur complement
(bundle-adjustment structure) and forward-difference Jacobians.

Split from :mod:`identification.trajectory.identifier`; see there for the method and its cost.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import torch

from identification.data.end_caps import RodAxes
from identification.trajectory.param_vector import DTYPE, ParamVector
from tensegrity_env.engine import Engine, State
from tensegrity_env.params import Params
from tensegrity_env.rotations import quat_mul, quat_to_matrix

# ---------------------------------------------------------------------- windows
STATE_KEYS = ("p", "v", "q", "omega")


@dataclass(frozen=True)
class Windows:
    """Trajectory windows of ``W`` steps, batched over ``B``.

    Attributes:
        obs: measured end caps, (B, W+1, 2R, 3) [m].
        control: commands during each step, (B, W, R, 3), or None (no control).
        state: current estimate of each window's initial rod state, (B, R, ·).
        traj, start: trajectory index and first sample of each window, (B,).
        valid: which samples count, (B, W+1) bool, or None (all): windows of
            different lengths share one batch, each ending where its valid samples do.
    """

    obs: torch.Tensor
    control: torch.Tensor | None
    state: State
    traj: np.ndarray
    start: np.ndarray
    valid: torch.Tensor | None = None

    @property
    def size(self) -> int:
        return int(self.obs.shape[0])

    @property
    def steps(self) -> int:
        return int(self.obs.shape[1]) - 1

    @property
    def residuals(self) -> int:
        """Number of end-cap coordinates that count (see ``valid``)."""
        if self.valid is None:
            return int(self.obs.numel())
        return int(self.valid.sum()) * int(self.obs[0, 0].numel())

    def weights(self, t0: int = 0, t1: int | None = None) -> torch.Tensor | None:
        """``valid`` of samples ``t0:t1`` as 0/1 weights, (B, t1-t0, 1, 1), or None."""
        if self.valid is None:
            return None
        return self.valid[:, t0:t1, None, None].to(self.obs.dtype)

    def take(self, idx: slice | np.ndarray) -> Windows:
        i = np.atleast_1d(np.arange(self.size)[idx])
        t = torch.as_tensor(i)
        ctrl = None if self.control is None else self.control[t]
        valid = None if self.valid is None else self.valid[t]
        return Windows(self.obs[t], ctrl, self.state.index(t), self.traj[i], self.start[i], valid)


def cut_windows(
    nodes: np.ndarray, control: np.ndarray, grid: dict[str, np.ndarray], window: int
) -> Windows:
    """Non-overlapping windows of about ``window`` steps over every trajectory.

    ``nodes`` (N, T+1, 2R, 3), ``control`` (N, T, R, 3); initial states are read from
    ``grid``, rod states at every sample (N, T+1, R, ·) (the smoothing, or a previous
    fit). The length is adjusted so that ``T // window`` windows tile each trajectory
    (fewer than that many steps are left over at its end).
    """
    N, T1 = nodes.shape[:2]
    W = (T1 - 1) // max(1, (T1 - 1) // window)
    starts = np.arange(0, T1 - W, W)
    traj, start = np.repeat(np.arange(N), len(starts)), np.tile(starts, N)
    span = start[:, None] + np.arange(W + 1)
    obs = torch.as_tensor(nodes[traj[:, None], span], dtype=DTYPE)
    ctrl = control[traj[:, None], span[:, :-1]]
    state = State.from_numpy(*(grid[k][traj, start] for k in STATE_KEYS))
    ctrl_t = torch.as_tensor(ctrl, dtype=DTYPE) if np.any(ctrl != 0) else None
    return Windows(obs, ctrl_t, state, traj, start)


@torch.no_grad()
def fill_grid(
    engine: Engine, params: Params, windows: Windows, grid: dict[str, np.ndarray]
) -> None:
    """Write the rollout of every fitted window into ``grid`` (N, T+1, R, ·), in place."""
    roll = engine.rollout(windows.state, params, windows.steps, windows.control)
    span = windows.start[:, None] + np.arange(windows.steps + 1)
    for k, arr in roll.numpy().items():
        grid[k][windows.traj[:, None], span] = arr


def local_basis(axes: RodAxes, spin: bool = True, roll: bool = False) -> torch.Tensor:
    """Tangents of each window's initial state, (n_local, R, 12).

    Per rod: ``δp, δv`` (world), ``δθ`` (rotation vector), ``δω`` (both in the rod frame).
    The rotation about the axis holding the end caps is left out unless ``roll``: it
    moves nothing but an effect that sees it (``sees_roll``, e.g. box-form quadratic
    drag). ``spin=False`` also leaves out the angular velocity about that axis (rod
    frame): it acts only through the tiny gyroscopic term ``I_axial ω_axial``, so
    short windows cannot tell it from noise.
    """
    R = len(axes.axis)
    rows = []
    for r in range(R):
        for j in range(12):
            if 6 <= j < 9 and j - 6 == axes.axis[r] and not roll:
                continue
            if j - 9 == axes.axis[r] and not spin:
                continue
            e = torch.zeros(R, 12, dtype=DTYPE)
            e[r, j] = 1.0
            rows.append(e)
    return torch.stack(rows)


def sees_roll(engine: Engine) -> bool:
    """Whether one of ``engine``'s effects depends on the rods' roll about their axes."""
    return any(getattr(e, "sees_roll", False) for e in engine.effects)


def perturb(state: State, d: torch.Tensor) -> State:
    """``state ⊕ d`` for per-rod perturbations ``d`` (B, R, 12) (see :func:`local_basis`)."""
    dq = torch.cat([torch.ones_like(d[..., :1]), 0.5 * d[..., 6:9]], dim=-1)
    q = quat_mul(state.q, dq)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    d_omega = torch.einsum("brij,brj->bri", quat_to_matrix(state.q), d[..., 9:12])
    return State(state.p + d[..., 0:3], state.v + d[..., 3:6], q, state.omega + d_omega)


def end_caps(engine: Engine, p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """End-cap positions of rod poses ``p`` (..., R, 3), ``q`` (..., R, 4) -> (..., 2R, 3)."""
    arms = torch.einsum("...rij,rkj->...rki", quat_to_matrix(q), engine.end_offsets)
    return (p.unsqueeze(-2) + arms).flatten(-3, -2)


def window_residual(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor
) -> Callable[[torch.Tensor, torch.Tensor], torch.Tensor]:
    """``f(z, theta)``: engine end caps minus measured, (B, W+1, 2R, 3) [m] (0 where
    not ``win.valid``).

    ``z`` (B, n_local) perturbs each window's initial state along ``basis``;
    ``theta`` (n_free,) are the free log-parameters.
    """

    def f(z: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
        state = perturb(win.state, torch.einsum("bl,lrj->brj", z, basis))
        eng = vec.engine(engine, theta)
        roll = eng.rollout(state, vec.params(vec.full(theta)), win.steps, win.control)
        r = end_caps(eng, roll.p, roll.q) - win.obs
        w = win.weights()
        return r if w is None else r * w

    return f


# ---------------------------------------------------------------------- stage 2
@dataclass(frozen=True)
class NormalEquations:
    """Gauss-Newton normal equations with per-window (local) and parameter (global) blocks.

    Attributes:
        H_ll: (B, n_l, n_l); H_lg: (B, n_l, n_g); g_l: (B, n_l);
        H_gg: (n_g, n_g); g_g: (n_g,); sse: sum of squared residuals [m^2]; m: residuals.
    """

    H_ll: torch.Tensor
    H_lg: torch.Tensor
    g_l: torch.Tensor
    H_gg: torch.Tensor
    g_g: torch.Tensor
    sse: float
    m: int


def linearize(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor, theta: torch.Tensor,
    chunk: int, step: float = 1e-7, exact_gradient: bool = False,
) -> NormalEquations:  # fmt: skip
    """Gauss-Newton normal equations of all windows at ``theta`` and the current states.

    ``J`` comes from forward differences of step ``step`` along every local coordinate
    and every free log-parameter (:func:`gauss_newton_fd`). Its ~1e-7 relative error
    barely moves the optimum (the shift is ~1e-7 of a standard error; none on clean
    data, where the residual vanishes). ``exact_gradient`` replaces ``Jᵀr`` by the
    exact gradient (reverse mode through the engine), about twice the cost.
    """
    H_ll, H_lg, g_l = [], [], []
    n_g = len(theta)
    H_gg = torch.zeros(n_g, n_g, dtype=DTYPE)
    g_g = torch.zeros(n_g, dtype=DTYPE)
    sse, m = 0.0, 0
    for start in range(0, win.size, chunk):
        part = win.take(slice(start, start + chunk))
        ll, lg, gg, gl, gt, part_sse = gauss_newton_fd(engine, vec, part, basis, theta, step)
        if exact_gradient:
            z = torch.zeros(part.size, basis.shape[0], dtype=DTYPE, requires_grad=True)
            th = theta.clone().requires_grad_(True)
            r = window_residual(engine, vec, part, basis)(z, th)
            gl, gt = torch.autograd.grad(0.5 * (r * r).sum(), (z, th))
        H_ll.append(ll)
        H_lg.append(lg)
        g_l.append(gl)
        H_gg += gg
        g_g += gt
        sse += part_sse
        m += part.residuals
    return NormalEquations(torch.cat(H_ll), torch.cat(H_lg), torch.cat(g_l), H_gg, g_g, sse, m)


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
    (B, n_l), ``g_g`` (n_g,) and ``rᵀr``. The windows and one perturbed copy per
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
    g_g = torch.zeros(n_g, dtype=DTYPE)
    sse, t0 = 0.0, 0
    caps = [end_caps(engine, state.p, state.q)]
    caps_e = [[end_caps(engine, s.p, s.q)] for s in extra_state]
    for t in range(win.steps):
        u = None if ctrl is None else ctrl[:, t]
        state = eng.step(state, params, u)
        caps.append(end_caps(engine, state.p, state.q))
        for k in range(n_e):
            extra_state[k] = extra[k].step(extra_state[k], p0, None if u is None else u[:b])
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
                w = w.expand(-1, -1, x.shape[-1], 1).flatten(1)  # (b, m)
                r, J = r * w, J * w
            Jl, Jg = J[:n_l], J[n_l:]
            H_ll += torch.einsum("ibm,jbm->bij", Jl, Jl)
            H_lg += torch.einsum("ibm,jbm->bij", Jl, Jg)
            H_gg += torch.einsum("ibm,jbm->ij", Jg, Jg)
            g_l += torch.einsum("ibm,bm->bi", Jl, r)
            g_g += torch.einsum("ibm,bm->i", Jg, r)
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
    ne: NormalEquations, lam: float
) -> tuple[torch.Tensor, torch.Tensor, float, torch.Tensor]:
    """Solve ``(H + lam D) δ = -g`` by eliminating the window states.

    Returns δz (B, n_l), δθ (n_g,), the predicted decrease of the sum of squares
    ``δᵀ(lam D δ - g)`` [m^2] and the reduced matrix ``S = A_gg - Σ H_gl A_ll⁻¹ H_lg``.
    """
    n_g = ne.H_gg.shape[0]
    A_ll, D_l = _damped(ne.H_ll, lam)
    A_gg, D_g = _damped(ne.H_gg, lam)
    Y = torch.linalg.solve(A_ll, torch.cat([ne.H_lg, ne.g_l.unsqueeze(-1)], dim=-1))
    S = A_gg - torch.einsum("bli,blj->ij", ne.H_lg, Y[..., :n_g])
    b = -ne.g_g + torch.einsum("bli,bl->i", ne.H_lg, Y[..., n_g])
    S = 0.5 * (S + S.T)
    d_theta = torch.linalg.solve(S, b)
    d_z = -(Y[..., n_g] + torch.einsum("blj,j->bl", Y[..., :n_g], d_theta))
    pred = lam * ((D_l * d_z**2).sum() + (D_g * d_theta**2).sum())
    pred -= (ne.g_l * d_z).sum() + (ne.g_g * d_theta).sum()
    return d_z, d_theta, float(pred), S


@torch.no_grad()
def window_sse(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor, theta: torch.Tensor,
    chunk: int,
) -> float:  # fmt: skip
    """Sum of squared end-cap errors of all windows [m^2]."""
    total = 0.0
    for start in range(0, win.size, chunk):
        part = win.take(slice(start, start + chunk))
        z0 = torch.zeros(part.size, basis.shape[0], dtype=DTYPE)
        total += float((window_residual(engine, vec, part, basis)(z0, theta) ** 2).sum())
    return total


@dataclass(frozen=True)
class WindowFit:
    """Result of :func:`fit_windows`.

    Attributes:
        theta: fitted free log-parameters, (n_free,).
        windows: the windows with fitted initial states.
        history: mean squared end-cap error [m^2] at the start and after each iteration.
        stderr: standard error of each free log-parameter (= relative standard error of
            the parameter) from the Gauss-Newton covariance ``σ² S⁻¹``, (n_free,).
        score: the chi-square decrease the first Gauss-Newton step promised.
        converged: the stopping rule was met (not just ``max_iter``).
    """

    theta: torch.Tensor
    windows: Windows
    history: list[float]
    stderr: np.ndarray
    score: float
    converged: bool


def fit_windows(
    engine: Engine,
    vec: ParamVector,
    windows: Windows,
    theta: torch.Tensor,
    max_iter: int = 20,
    tol: float = 0.1,
    progress: Callable[[float], None] | None = None,
    exact_gradient: bool = False,
    spin: bool = True,
    gate: float | None = None,
    roll: bool = False,
) -> WindowFit:
    """Stage 2: Levenberg-Marquardt on window initial states and free log-parameters.

    Minimises the mean squared end-cap position error of all windows rolled out by
    ``engine`` (Nielsen's damping update, faster when the model is good). Stops when
    the full Gauss-Newton step would lower the chi-square ``sse / σ̂²`` by less than
    ``tol`` (the Newton decrement: 0.1 leaves every parameter well within a fraction
    of its standard error), when the RMS error reaches round-off (clean data), or
    after ``max_iter`` iterations (one Jacobian each). With ``gate``, nothing is done
    when the first step promises less than ``gate`` (a score test: the new unknowns
    cannot be told from noise). ``progress`` is called with the mean squared error
    after each iteration; ``exact_gradient``: see :func:`linearize`; ``spin`` and
    ``roll``: see :func:`local_basis`.
    """
    basis = local_basis(vec.axes, spin, roll)
    chunk = max(1, 6000 // (basis.shape[0] + len(theta) + 1))  # batch of the FD Jacobian
    ne = linearize(engine, vec, windows, basis, theta, chunk, exact_gradient=exact_gradient)
    dof = max(ne.m - len(theta) - windows.size * basis.shape[0], 1)
    history = [ne.sse / ne.m]
    exact = (1e-12 * max(1.0, float(windows.obs.abs().max()))) ** 2  # round-off [m^2]
    _, _, newton, S = schur_step(ne, 0.0)
    score = newton / max(ne.sse / dof, 1e-300)
    lo, hi = vec.bounds()
    done = score < tol or history[-1] < exact or (gate is not None and score < gate)
    lam, nu, converged = 1e-7, 2.0, done
    for _ in range(max_iter if not done else 0):
        while True:
            d_z, d_theta, pred, _ = schur_step(ne, lam)
            d_theta = (theta + d_theta).clamp(lo, hi) - theta
            d_state = torch.einsum("bl,lrj->brj", d_z, basis)
            trial = replace(windows, state=perturb(windows.state, d_state))
            try:
                sse = window_sse(engine, vec, trial, basis, theta + d_theta, chunk)
            except torch.linalg.LinAlgError:  # e.g. a contact solve at extreme trial values
                sse = float("inf")
            rho = (ne.sse - sse) / pred if pred > 0 and np.isfinite(sse) else -1.0
            if rho > 0:
                lam *= 0.1 if rho > 0.9 else max(1 / 3, 1 - (2 * rho - 1) ** 3)
                nu = 2.0
                break
            lam, nu = lam * nu, nu * 2
            if lam > 1e10:
                break
        if lam > 1e10:
            converged = True  # no step lowers the error any more
            break
        windows, theta = trial, theta + d_theta
        ne = linearize(engine, vec, windows, basis, theta, chunk, exact_gradient=exact_gradient)
        _, _, newton, S = schur_step(ne, 0.0)
        history.append(ne.sse / ne.m)
        if progress is not None:
            progress(history[-1])
        if newton < tol * ne.sse / dof or history[-1] < exact:
            converged = True
            break
    stderr = _stderr(S, ne.sse / dof).numpy()
    return WindowFit(theta, windows, history, stderr, score, converged)


def _stderr(S: torch.Tensor, sigma2: float) -> torch.Tensor:
    """Standard errors ``sqrt(diag(σ² S⁻¹))`` of the parameters, (n_g,)."""
    return torch.sqrt(torch.diagonal(sigma2 * torch.linalg.pinv(S, hermitian=True)).clamp_min(0))


def window_schedule(first: int, last: int, factor: float = 4.0) -> list[int]:
    """Window lengths growing geometrically, by at most ``factor``, from ``first`` to ``last``."""
    if first >= last:
        return [last]
    n = int(np.ceil(np.log(last / first) / np.log(factor) - 1e-9))
    return [round(first * (last / first) ** (k / n)) for k in range(n + 1)]
