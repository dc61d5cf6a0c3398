"""What a model fitted to noisy end caps cannot predict, against the quantities that reveal effects.

On end-cap data the residual is the multi-step prediction error of each held-out
window (its initial state fitted, the model's parameters held): ``e = predicted -
measured`` per end cap and sample, (B, W+1, 2R, 3) [m]. The noise alone gives a flat
RMS of about the noise level everywhere; a missing effect shows where it acts:

* against **end-cap height**: contact (errors grow near the floor, the vertical
  error is signed);
* against **end-cap speed**: drag (linear or quadratic growth);
* against **time in the window**: anything acting everywhere makes the error grow
  along the window (a force field: quadratically), noise does not.

:func:`window_residuals` computes them, :func:`summarize_window_residuals` gives
numbers and :func:`plot_window_residuals` the PNG the report embeds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from identification.report.plots import plt, save_figure
from tensegrity_env.plot_limits import set_robust_limits


@dataclass(frozen=True)
class WindowResiduals:
    """Held-out end-cap residuals and the quantities they are plotted against.

    Attributes:
        error: predicted minus measured end caps, (B, W+1, 2R, 3) [m]; NaN where unseen.
        height: predicted end-cap height z, (B, W+1, 2R) [m].
        speed: predicted end-cap speed, (B, W+1, 2R) [m/s].
        time: time since the window's start, (W+1,) [s].
        radius: end-cap radius per cap, (2R,) [m] (a cap touches the floor at z = r).
    """

    error: np.ndarray
    height: np.ndarray
    speed: np.ndarray
    time: np.ndarray
    radius: np.ndarray


def window_residuals(
    predicted: torch.Tensor, measured: torch.Tensor, dt: float, radius: np.ndarray,
    seen: torch.Tensor | None = None,
) -> WindowResiduals:  # fmt: skip
    """Residuals of ``predicted`` end caps (B, W+1, 2R, 3) [m] against ``measured``;
    NaN where an end cap was not seen (``seen`` (B, W+1, 2R) False)."""
    pred = predicted.detach().numpy()
    vel = np.gradient(pred, dt, axis=1)
    error = pred - measured.detach().numpy()
    if seen is not None:
        error[~seen.numpy()] = np.nan
    return WindowResiduals(
        error=error,
        height=pred[..., 2],
        speed=np.linalg.norm(vel, axis=-1),
        time=np.arange(pred.shape[1]) * dt,
        radius=np.asarray(radius, dtype=float),
    )


def _binned(x: np.ndarray, y: np.ndarray, bins: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Bin centres of ``x`` (quantile bins) and the RMS of ``y`` in each."""
    x, y = x.reshape(-1), y.reshape(-1)
    keep = np.isfinite(x) & np.isfinite(y)  # (unseen end caps: left out)
    x, y = x[keep], y[keep]
    if x.size == 0:
        return np.full(0, np.nan), np.full(0, np.nan)
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    centre = np.array([x[idx == k].mean() if np.any(idx == k) else np.nan
                       for k in range(len(edges) - 1)])  # fmt: skip
    rms = np.array([np.sqrt(np.mean(y[idx == k] ** 2)) if np.any(idx == k) else np.nan
                    for k in range(len(edges) - 1)])  # fmt: skip
    return centre, rms


def summarize_window_residuals(r: WindowResiduals) -> dict[str, float]:
    """Numbers [m]: overall RMS; RMS near the floor (caps within 2 cm of touching) and
    above it; RMS of the fastest and slowest quarter of samples; RMS in the window's
    last and first fifth. Over the seen end caps only."""
    e = np.linalg.norm(r.error, axis=-1)
    seen = np.isfinite(e)
    gap = r.height - r.radius
    fast = r.speed > np.quantile(r.speed, 0.75)
    slow = r.speed < np.quantile(r.speed, 0.25)
    W1 = r.error.shape[1]
    rms = lambda m: float(np.sqrt(np.mean(e[m & seen] ** 2))) if np.any(m & seen) else float("nan")  # noqa: E731
    late = np.zeros_like(e, dtype=bool)
    late[:, -max(1, W1 // 5) :] = True
    early = np.zeros_like(e, dtype=bool)
    early[:, : max(1, W1 // 5)] = True
    return {
        "rms": rms(np.ones_like(e, dtype=bool)),
        "near_floor": rms(gap < 0.02),
        "above_floor": rms(gap >= 0.02),
        "fast": rms(fast),
        "slow": rms(slow),
        "late": rms(late),
        "early": rms(early),
    }


def plot_window_residuals(r: WindowResiduals, path: Path, title: str, noise: float = 0.0) -> Path:
    """Binned RMS residual against height above touching, speed and time (PNG, atomic)."""
    e = np.linalg.norm(r.error, axis=-1)
    fig, ax = plt.subplots(1, 4, figsize=(16, 3.6))
    x, y = _binned(r.height - r.radius, e)
    ax[0].plot(x * 1e3, y * 1e3, "o-")
    ax[0].set_xlabel("end-cap height above touching [mm]")
    x, y = _binned(r.height - r.radius, r.error[..., 2])
    ax[1].plot(x * 1e3, y * 1e3, "o-", color="C1")
    ax[1].set_xlabel("end-cap height above touching [mm]")
    ax[1].set_ylabel("RMS vertical error [mm]")
    x, y = _binned(r.speed, e)
    ax[2].plot(x, y * 1e3, "o-", color="C2")
    ax[2].set_xlabel("end-cap speed [m/s]")
    t = np.broadcast_to(r.time[None, :, None], e.shape)
    x, y = _binned(t, e)
    ax[3].plot(x * 1e3, y * 1e3, "o-", color="C3")
    ax[3].set_xlabel("time in window [ms]")
    for a in (ax[0], ax[2], ax[3]):
        a.set_ylabel("RMS end-cap error [mm]")
    for a in ax:
        set_robust_limits(a, np.concatenate([np.ravel(line.get_ydata()) for line in a.lines]),
                          what="bins")  # fmt: skip
        if noise > 0:
            a.axhline(noise * 1e3 * np.sqrt(3 if a is not ax[1] else 1), color="gray", ls=":",
                      label="noise")  # fmt: skip
        a.grid(alpha=0.3)
    if noise > 0:
        ax[0].legend(loc="best")
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)
