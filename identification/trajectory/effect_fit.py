"""Fit the parameters of effects that are not linear in them (contact, ...) through the engine.

Short windows of the measured trajectories are rolled out by the differentiable
engine from their measured initial states; Levenberg-Marquardt adjusts a few
effect parameters (positive ones in log space) to minimise the mean squared
end-cap position error over every window. The Jacobian is by forward differences
(one extra batched rollout per parameter): effects have a handful of scalars, and
the contact gate makes the error only piecewise smooth anyway.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from identification.data.dataset import Split
from identification.linear.solve import Equilibrated
from tensegrity_env.effects.base import ParamSpec, PhysicalEffect
from tensegrity_env.engine import Engine, State
from tensegrity_env.params import Params
from tensegrity_env.rotations import quat_to_matrix
from tensegrity_env.topology import Topology

DTYPE = torch.float64


@dataclass(frozen=True)
class Windows:
    """Trajectory windows of ``L`` steps, batched over ``W``.

    Attributes:
        init: measured rod state at each window's first sample, (W, R, ·).
        caps: measured end caps over the window, (W, L+1, 2R, 3) [m].
        control: commands during each step, (W, L, R, 3).
        cables: cable actuators' commands during each step, (W, L, C); None without
            cable actuators.
    """

    init: State
    caps: torch.Tensor
    control: torch.Tensor
    cables: torch.Tensor | None = None

    @property
    def steps(self) -> int:
        return int(self.caps.shape[1]) - 1


def sample_windows(split: Split, length: int, count: int, seed: int = 0) -> Windows:
    """``count`` random windows of ``length`` steps (fewer if the split is short)."""
    if not split.has_states:
        raise ValueError("windows need rod states (derive them from the end caps first)")
    N, T = split.n_trajectories, split.n_transitions
    length = min(length, T)
    rng = np.random.default_rng(seed)
    traj = rng.integers(0, N, count)
    start = rng.integers(0, T - length + 1, count)
    t = start[:, None] + np.arange(length + 1)

    def pick(arr: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(arr[traj, start], dtype=DTYPE)

    init = State(*(pick(getattr(split, k)) for k in ("p", "v", "q", "omega")))
    caps = torch.as_tensor(split.nodes[traj[:, None], t], dtype=DTYPE)
    control = torch.as_tensor(split.control[traj[:, None], t[:, :-1]], dtype=DTYPE)
    cables = None
    if split.cable_control is not None:
        cables = torch.as_tensor(split.cable_control[traj[:, None], t[:, :-1]], dtype=DTYPE)
    return Windows(init, caps, control, cables)


def rollout_caps(
    engine: Engine,
    params: Params,
    init: State,
    control: torch.Tensor,
    cables: torch.Tensor | None = None,
) -> torch.Tensor:
    """End caps (W, L+1, 2R, 3) [m] of the engine rolled out from ``init`` under
    ``control`` (W, L, R, 3) and cable commands ``cables`` (W, L, C) if any."""
    R = init.p.shape[1]
    state, caps = init, []
    ends = engine.end_offsets
    for t in range(control.shape[1] + 1):
        if t:
            state = engine.step(
                state, params, control[:, t - 1], None if cables is None else cables[:, t - 1]
            )
        rot_arms = torch.einsum("wrij,rkj->wrki", quat_to_matrix(state.q), ends)
        caps.append((state.p.unsqueeze(2) + rot_arms).reshape(-1, 2 * R, 3))
    return torch.stack(caps, dim=1)


@dataclass(frozen=True)
class EffectFit:
    """Result of :func:`fit_effect_params`.

    Attributes:
        effects: the effects with fitted values.
        names: ``"effect.param"`` of each fitted parameter.
        values: fitted values, (n,).
        stderr: standard errors of the values (delta method from the Gauss-Newton
            covariance on the equilibrated curvature; optimistic where window errors are
            correlated; inf along a direction the data does not see), (n,).
        history: mean squared end-cap error [m^2], start and after each iteration.
    """

    effects: list[PhysicalEffect]
    names: list[str]
    values: np.ndarray
    stderr: np.ndarray
    history: list[float]


def _apply(
    effects: Sequence[PhysicalEffect], free: Sequence[tuple[int, str]], theta: torch.Tensor
) -> list[PhysicalEffect]:
    out = list(effects)
    for k, (i, key) in enumerate(free):
        out[i] = out[i].with_values(
            validate=False, **{key: from_free(out[i].PARAMS[key], theta[k])}
        )
    return out


def to_free(spec: ParamSpec, value: float) -> float:
    """A parameter value in the unconstrained coordinates of the fit (log, logit or as is)."""
    if spec.unit_interval:
        return float(np.log(value / (1.0 - value)))
    if spec.positive:
        return float(np.log(max(value, 1e-12)))
    return float(value)


def from_free(spec: ParamSpec, x: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`to_free`."""
    if spec.unit_interval:
        return torch.sigmoid(x)
    if spec.positive:
        return torch.exp(x)
    return x


def fit_effect_params(
    topology: Topology,
    dt: float,
    params: Params,
    effects: Sequence[PhysicalEffect],
    free: Sequence[tuple[int, str]],
    windows: Windows,
    max_iter: int = 25,
    tol: float = 1e-6,
    fd_step: float = 1e-4,
) -> EffectFit:
    """Levenberg-Marquardt on the ``free`` parameters ``(effect index, name)``.

    Every parameter is a scalar; positive ones (see ``ParamSpec.positive``) are
    fitted as ``log`` values. The others stay as given.
    """

    def theta_of(effs: Sequence[PhysicalEffect]) -> torch.Tensor:
        vals = [
            to_free(effs[i].PARAMS[key], float(effs[i].values[key].detach().reshape(-1)[0]))
            for i, key in free
        ]
        return torch.tensor(vals, dtype=DTYPE)

    def residual(theta: torch.Tensor) -> torch.Tensor:
        if not bool(torch.isfinite(theta).all()) or bool((theta.abs() > 50).any()):
            return torch.full((windows.caps.numel(),), float("inf"), dtype=DTYPE)
        eng = Engine(topology, dt, effects=_apply(effects, free, theta))
        with torch.no_grad():
            caps = rollout_caps(eng, params, windows.init, windows.control, windows.cables)
        return (caps - windows.caps).reshape(-1)

    theta = theta_of(effects)
    r = residual(theta)
    sse = float((r**2).sum())
    history = [sse / r.numel()]
    lam = 1e-2
    J = torch.zeros(r.numel(), len(free), dtype=DTYPE)
    for _ in range(max_iter):
        for k in range(len(free)):
            e = torch.zeros(len(free), dtype=DTYPE)
            e[k] = fd_step
            J[:, k] = (residual(theta + e) - r) / fd_step
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
        if not improved or rel < tol:
            break
    sigma2 = sse / max(r.numel() - len(free), 1)
    eq = Equilibrated.of(J.T @ J)
    se_theta = torch.sqrt(sigma2 * torch.diagonal(eq.inverse()).clamp_min(0)).numpy()
    se_theta[eq.unseen.numpy()] = np.inf  # a direction the data does not see
    fitted = _apply(effects, free, theta.detach())
    values, stderr = [], []
    for k, (i, key) in enumerate(free):
        spec = fitted[i].PARAMS[key]
        v = float(fitted[i].values[key].reshape(-1)[0])
        values.append(v)
        # delta method: d value / d free coordinate
        slope = v * (1 - v) if spec.unit_interval else (abs(v) if spec.positive else 1.0)
        stderr.append(slope * se_theta[k])
    names = [f"{effects[i].name}.{key}" for i, key in free]
    return EffectFit(fitted, names, np.array(values), np.array(stderr), history)
