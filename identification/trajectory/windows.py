"""Windows of measured end caps for the trajectory fit: cutting, their initial states'
local coordinates, the engine rollout of a window and its residual, the window schedule.

The fit over windows is :mod:`identification.trajectory.windowed_fit`; the method is
described in :mod:`identification.trajectory.identifier`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from identification.data.dataset import Split
from identification.data.end_caps import RodAxes
from identification.trajectory.param_vector import DTYPE, ParamVector
from tensegrity_env.engine import Engine, State
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params
from tensegrity_env.rotations import quat_mul, quat_to_matrix

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
        cables: the cable actuators' commands during each step, (B, W, C), or None
            (no cable actuators, or no commands).
    """

    obs: torch.Tensor
    control: torch.Tensor | None
    state: State
    traj: np.ndarray
    start: np.ndarray
    valid: torch.Tensor | None = None
    cables: torch.Tensor | None = None

    @property
    def size(self) -> int:
        return int(self.obs.shape[0])

    @property
    def steps(self) -> int:
        return int(self.obs.shape[1]) - 1

    @property
    def residuals(self) -> int:
        """Number of end-cap coordinates that count (see ``valid``)."""
        return int(self.window_residuals().sum())

    def window_residuals(self) -> np.ndarray:
        """Number of end-cap coordinates that count in each window (see ``valid``), (B,)."""
        if self.valid is None:
            return np.full(self.size, int(self.obs[0].numel()))
        per = self.valid.reshape(self.size, -1).sum(dim=1).numpy()
        coords = int(self.obs.shape[-1]) if self.valid.ndim == 3 else int(self.obs[0, 0].numel())
        return per * coords

    def seen(self) -> torch.Tensor:
        """Which end caps count at each sample, (B, W+1, 2R) bool (see ``valid``)."""
        shape = self.obs.shape[:-1]
        if self.valid is None:
            return torch.ones(shape, dtype=torch.bool)
        return (self.valid if self.valid.ndim == 3 else self.valid[..., None]).expand(shape)

    def weights(self, t0: int = 0, t1: int | None = None) -> torch.Tensor | None:
        """``valid`` of samples ``t0:t1`` as 0/1 weights, (B, t1-t0, 1 or 2R, 1), or None.

        ``valid`` is per sample (B, W+1) (e.g. airborne selection) or per end cap
        (B, W+1, 2R) (markers not seen: their observation is stored as 0 and weighs 0).
        """
        if self.valid is None:
            return None
        v = self.valid[:, t0:t1]
        return (v[..., None] if v.ndim == 3 else v[..., None, None]).to(self.obs.dtype)

    def take(self, idx: slice | np.ndarray) -> Windows:
        i = np.atleast_1d(np.arange(self.size)[idx])
        t = torch.as_tensor(i)
        ctrl = None if self.control is None else self.control[t]
        valid = None if self.valid is None else self.valid[t]
        cables = None if self.cables is None else self.cables[t]
        return Windows(self.obs[t], ctrl, self.state.index(t), self.traj[i], self.start[i], valid, cables)


def cut_windows(
    nodes: np.ndarray, control: np.ndarray, grid: dict[str, np.ndarray], window: int,
    cables: np.ndarray | None = None, least: int = 0,
) -> Windows:  # fmt: skip
    """Non-overlapping windows of about ``window`` steps over every trajectory.

    ``nodes`` (N, T+1, 2R, 3), ``control`` (N, T, R, 3), ``cables`` (N, T, C) or None;
    initial states are read from
    ``grid``, rod states at every sample (N, T+1, R, ·) (the smoothing, or a previous
    fit). The length is adjusted so that ``T // window`` windows tile each trajectory
    (fewer than that many steps are left over at its end). End caps that were not seen
    (NaN in ``nodes``) get ``valid`` False and count in no residual. A window whose
    initial state is undefined in ``grid`` (a gap too long for the smoothing to bridge)
    starts at the first later sample where it is defined, within its tile, or is left out
    (see :func:`defined_starts`); one that then runs past its trajectory's end (a window
    over the whole trajectory whose first samples fall in a gap) ends there: the samples
    past the end have ``valid`` False. Where that leaves fewer than ``least`` windows,
    windows up to that many (and no more than were left out) start at other samples where
    it is defined, overlapping the tiles (:func:`refill_starts`); with enough tiles the
    windows never overlap.
    """
    N, T1 = nodes.shape[:2]
    W = (T1 - 1) // max(1, (T1 - 1) // window)
    starts = np.arange(0, T1 - W, W)
    traj, start = np.repeat(np.arange(N), len(starts)), np.tile(starts, N)
    defined = np.logical_and.reduce(
        [np.isfinite(grid[k]).all(axis=(2, 3)) for k in STATE_KEYS]
    )  # (N, T+1)
    if not defined[traj, start].all():
        tiles = len(start)
        traj, start = defined_starts(defined, traj, start, W)
        traj, start = refill_starts(defined, traj, start, W, min(tiles, least) - len(start))
        if len(start) == 0:
            raise InputError(
                f"no window of {W} steps starts where the end caps' smoothing is defined: "
                "the gaps are too long or too frequent for windows this long"
            )
    span = start[:, None] + np.arange(W + 1)
    inside = span < T1  # a moved start's window ends with its trajectory
    span = np.minimum(span, T1 - 1)
    obs_np = nodes[traj[:, None], span]
    # (B, W+1, 2R): a gap, or a sample past the end, is compared with nothing
    seen = np.isfinite(obs_np).all(-1) & inside[..., None]
    obs = torch.as_tensor(np.where(seen[..., None], obs_np, 0.0), dtype=DTYPE)
    ctrl = control[traj[:, None], np.minimum(span[:, :-1], T1 - 2)]
    state = State.from_numpy(*(grid[k][traj, start] for k in STATE_KEYS))
    ctrl_t = torch.as_tensor(ctrl, dtype=DTYPE) if np.any(ctrl != 0) else None
    valid = None if seen.all() else torch.as_tensor(seen)
    cable = cable_windows(cables, traj, np.minimum(span, T1 - 2))
    return Windows(obs, ctrl_t, state, traj, start, valid, cable)


def cable_windows(cables: np.ndarray | None, traj: np.ndarray, span: np.ndarray) -> torch.Tensor | None:
    """The cable commands (B, W, C) of windows over samples ``span`` (B, W+1) of
    trajectories ``traj`` (B,); None without commands (or all zero)."""
    if cables is None or not np.any(cables != 0):
        return None
    return torch.as_tensor(cables[traj[:, None], span[:, :-1]], dtype=DTYPE)


def defined_starts(
    defined: np.ndarray, traj: np.ndarray, start: np.ndarray, steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """Window starts moved to the first sample in ``[start, start + steps)`` where
    ``defined`` (N, T+1) holds and at least half a window of ``steps`` is left before the
    trajectory's end (the window is cut there: :func:`cut_windows`); windows with no such
    sample are dropped. Returns the kept ``traj`` and ``start``.

    A window over the whole trajectory has nowhere to move but towards its end: with
    gaps in its first samples it would otherwise be dropped, and with it the only window
    of a one-trajectory split."""
    T1 = defined.shape[1]
    keep_t, keep_s = [], []
    for n, s0 in zip(traj, start, strict=True):
        ok = np.flatnonzero(defined[n, s0 : min(s0 + steps, T1 - (steps + 1) // 2)])
        if len(ok):
            keep_t.append(n)
            keep_s.append(s0 + ok[0])
    return np.array(keep_t, dtype=int), np.array(keep_s, dtype=int)


def refill_starts(
    defined: np.ndarray, traj: np.ndarray, start: np.ndarray, steps: int, lost: int
) -> tuple[np.ndarray, np.ndarray]:
    """``traj`` and ``start`` with up to ``lost`` more window starts, at samples where
    ``defined`` (N, T+1) holds and a window of ``steps`` fits that are no start yet,
    spread evenly over them; sorted by trajectory and start.

    On a take with many gaps the rods' states are defined only in short stretches, and
    fixed tiles keep few windows there; windows that overlap the kept ones fit those
    stretches' samples from more starts instead of leaving them out (the measurement on a
    real take is in docs/decisions.md).
    """
    T1 = defined.shape[1]
    taken = set(zip(traj.tolist(), start.tolist(), strict=True))
    free = [(n, int(t)) for n in range(defined.shape[0]) for t in np.flatnonzero(defined[n, : max(T1 - steps, 0)])
            if (n, int(t)) not in taken]  # fmt: skip
    if lost <= 0 or not free:
        return traj, start
    pick = [free[int(i)] for i in np.unique(np.linspace(0, len(free) - 1, min(lost, len(free))).round())]
    t = np.concatenate([traj, np.array([p[0] for p in pick], dtype=int)])
    s0 = np.concatenate([start, np.array([p[1] for p in pick], dtype=int)])
    order = np.lexsort((s0, t))
    return t[order], s0[order]


@torch.no_grad()
def fill_grid(
    engine: Engine, params: Params, windows: Windows, grid: dict[str, np.ndarray]
) -> None:
    """Write the rollout of every fitted window into ``grid`` (N, T+1, R, ·), in place
    (up to each trajectory's end: a window cut there runs past it, not written)."""
    roll = engine.rollout(windows.state, params, windows.steps, windows.control, windows.cables)
    span = windows.start[:, None] + np.arange(windows.steps + 1)
    b, j = np.nonzero(span < grid["p"].shape[1])
    for k, arr in roll.numpy().items():
        grid[k][windows.traj[b], span[b, j]] = arr[b, j]


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
        roll = eng.rollout(state, vec.params(vec.full(theta)), win.steps, win.control, win.cables)
        r = end_caps(eng, roll.p, roll.q) - win.obs
        w = win.weights()
        return r if w is None else r * w

    return f



def window_schedule(first: int, last: int, factor: float = 4.0) -> list[int]:
    """Window lengths growing geometrically, by at most ``factor``, from ``first`` to ``last``."""
    if first >= last:
        return [last]
    n = int(np.ceil(np.log(last / first) / np.log(factor) - 1e-9))
    return [round(first * (last / first) ** (k / n)) for k in range(n + 1)]


def sample_windows(split: Split, length: int, count: int, seed: int = 0) -> Windows:
    """``count`` random windows of ``length`` steps (fewer if the split is short), drawn
    with replacement, their initial states the split's rod states (measured or derived)."""
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

    init = State(*(pick(getattr(split, k)) for k in STATE_KEYS))
    caps = torch.as_tensor(split.nodes[traj[:, None], t], dtype=DTYPE)
    control = torch.as_tensor(split.control[traj[:, None], t[:, :-1]], dtype=DTYPE)
    cables = None
    if split.cable_control is not None:
        cables = torch.as_tensor(split.cable_control[traj[:, None], t[:, :-1]], dtype=DTYPE)
    return Windows(caps, control, init, traj, start, cables=cables)


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
