"""Each window's end-cap error in a windowed trajectory fit, and the choices made on it:
which windows a fit keeps (:func:`windows_within`), which of two initial states a
window keeps (:func:`better_states`), which windows' error jumped at a short step
(:func:`jumped_windows`).

The windows are :mod:`identification.trajectory.windows`; the fit that calls these is
:func:`identification.trajectory.windowed_problem.fit`.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import numpy as np
import torch

from identification.trajectory.forked import side_by_side, window_groups, window_jobs
from identification.trajectory.param_vector import DTYPE, ParamVector
from identification.trajectory.windows import Windows, local_basis, window_residual
from tensegrity_env.engine import Engine, State

#: with ``line_search``, a window whose error rose by more than this many noise variances
#: at a step too short to matter has a discontinuity at the current point (an impact on
#: the edge of a physics step; :func:`jumped_windows`)
JUMP = 25.0


@torch.no_grad()
def window_sse(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor, theta: torch.Tensor,
    chunk: int,
) -> float:  # fmt: skip
    """Sum of squared end-cap errors of all windows [m^2], in the groups of
    :func:`linearize`."""
    return window_sses(engine, vec, win, basis, theta, chunk)[1]


def window_sses(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor, theta: torch.Tensor,
    chunk: int,
) -> tuple[np.ndarray, float]:  # fmt: skip
    """Each window's sum of squared end-cap errors (B,) [m^2] and their sum [m^2] (summed
    group by group), in the groups of :func:`linearize`."""
    groups = window_groups(win.size, chunk)
    tasks = [partial(group_sse, engine, vec, win.take(g), basis, theta) for g in groups]
    most = max(g.stop - g.start for g in groups)
    parts = side_by_side(tasks, window_jobs(most * win.steps))  # one rollout per window
    return np.concatenate([each for each, _ in parts]), float(sum(total for _, total in parts))


def group_sse(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor, theta: torch.Tensor
) -> tuple[np.ndarray, float]:
    """One group of windows' share of :func:`window_sses`: each window's (B_group,) and
    their sum [m^2]."""
    z0 = torch.zeros(win.size, basis.shape[0], dtype=DTYPE)
    with torch.no_grad():
        r2 = window_residual(engine, vec, win, basis)(z0, theta) ** 2
        return r2.sum(dim=tuple(range(1, r2.dim()))).numpy(), float(r2.sum())


def window_errors(
    engine: Engine, vec: ParamVector, windows: Windows, theta: torch.Tensor
) -> torch.Tensor:
    """Sum of squared end-cap errors of each window at ``theta``, (B,) [m^2] (per window,
    where :func:`window_sse` sums them), its initial state as it is; ``inf`` where a
    window's rollout is not finite."""
    basis = local_basis(vec.axes, spin=True)
    z0 = torch.zeros(windows.size, basis.shape[0], dtype=theta.dtype)
    with torch.no_grad():
        r = window_residual(engine, vec, windows, basis)(z0, theta)
    e = (r**2).sum(dim=(1, 2, 3))
    return torch.where(torch.isfinite(e), e, torch.full_like(e, float("inf")))


def windows_within(
    engine: Engine, vec: ParamVector, windows: Windows, theta: torch.Tensor, rms: float
) -> tuple[Windows, np.ndarray]:
    """The windows whose end-cap RMS at ``theta`` (their initial states as they are) is
    at most ``rms`` [m], or the better half where fewer are; and every window's RMS,
    (B,) [m].

    Through an impact a window's fitted state can stay in another basin, even at the
    true model. Such a window pulls a joint fit towards a wrong model or stalls it
    (measured in docs/decisions.md, "Windows left out of the final floor refit").
    """
    sse = window_errors(engine, vec, windows, theta).numpy()
    n = windows.window_residuals()
    err = np.sqrt(np.divide(sse, n, out=np.full_like(sse, np.inf), where=n > 0))
    keep = err <= rms
    if 2 * int(keep.sum()) < windows.size:  # (a model this far off is not trimmed to fit)
        keep = err <= np.sort(err)[(windows.size - 1) // 2]
    return windows.take(np.flatnonzero(keep)), err


def better_states(
    engine: Engine, vec: ParamVector, theta: torch.Tensor, a: Windows, b: Windows
) -> tuple[Windows, torch.Tensor, torch.Tensor]:
    """The same windows with, per window, the initial state of ``a`` or ``b`` that fits
    better at ``theta``.

    A window's state is a nuisance of the fit: each of two state fits (from smoothing,
    from a nearby model's states) can stop in another basin through an impact, and the
    smaller error of the two is the better estimate of the model's. Returns the windows
    and the per-window sums of squared end-cap errors (B,) [m^2] of ``b`` and of the pick.
    """
    ea, eb = window_errors(engine, vec, a, theta), window_errors(engine, vec, b, theta)
    pick = ea < eb
    states = [torch.where(pick.view(-1, *[1] * (x.ndim - 1)), x, y)
              for x, y in zip(a.state.tensors(), b.state.tensors(), strict=True)]  # fmt: skip
    return replace(b, state=State(*states)), eb, torch.minimum(ea, eb)


def jumped_windows(now: np.ndarray, trial: np.ndarray, noise_var: float) -> np.ndarray:
    """Which windows' error (B,) bool rose by more than :data:`JUMP` times the noise
    variance ``noise_var`` [m^2] from ``now`` to ``trial`` (each (B,) [m^2]): at a step
    too short to matter, only a discontinuity does that."""
    return (trial - now) > JUMP * noise_var
