"""Figures people would rather look at than read: rollouts against ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D

from tensegrity_env.io_utils import InputError, atomic_path
from tensegrity_env.plot_limits import set_robust_limits


def check_figure_path(path: str | Path, option: str = "--plot") -> Path:
    """Raise :class:`InputError` unless ``path``'s extension names a picture format that
    matplotlib writes (``.png``, ``.pdf``, ``.svg``, ...); returns it as a Path."""
    from matplotlib.backend_bases import FigureCanvasBase

    p = Path(path)
    formats = sorted(FigureCanvasBase.get_supported_filetypes())
    ext = p.suffix[1:].lower()
    if ext not in formats:
        what = f"'.{ext}' is not a picture format" if ext else "has no file extension"
        raise InputError(f"{option} {p}: {what}; name a picture file ending in one of "
                         f"{', '.join('.' + f for f in formats)}")
    return p


def save_figure(fig: plt.Figure, path: str | Path) -> Path:
    """Save ``fig`` as PNG atomically and close it."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight", format="png")
    plt.close(fig)
    return Path(path)


def cap_colours(n: int) -> list[Any]:
    """``n`` distinct colours, one per end cap (matplotlib's cycle repeats after 10)."""
    if n <= 10:
        return [plt.get_cmap("tab10")(k) for k in range(n)]
    pairs = plt.get_cmap("tab20")  # dark shades first, then their light pairs
    order = [*range(0, 20, 2), *range(1, 20, 2)]
    return [pairs(order[k % 20]) for k in range(n)]


def plot_rollout_comparison(
    truth_nodes: np.ndarray,
    model_nodes: np.ndarray,
    dt: float,
    error_curve: np.ndarray,
    path: str | Path,
    title: str = "identified engine vs MuJoCo",
) -> Path:
    """End-cap heights of one trajectory (truth wide and faint, model dashed on top) and
    the error curve; the height axis is scaled to the truth (a diverging model is noted).

    Args:
        truth_nodes: ground-truth end caps of one trajectory, (T+1, n_nodes, 3) [m].
        model_nodes: the model's end caps from the same initial state, (T+1, n_nodes, 3) [m].
        dt: sample period [s].
        error_curve: mean rod position error per step over a split, (T+1,) [m].
        path: output PNG.
    """
    t = np.arange(truth_nodes.shape[0]) * dt
    n = truth_nodes.shape[1]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.4), layout="constrained")
    for k, colour in enumerate(cap_colours(n)):
        ax1.plot(t, truth_nodes[:, k, 2], lw=2.6, alpha=0.45, color=colour, label=f"cap {k}")
        ax1.plot(t, model_nodes[:, k, 2], "--", lw=1.0, color=colour, zorder=3)
    set_robust_limits(ax1, truth_nodes[..., 2], also=[model_nodes[..., 2]], what="model")
    ax1.set(xlabel="time [s]", ylabel="end-cap height z [m]", title=title)
    styles = [Line2D([], [], color="0.4", lw=2.6, alpha=0.45, label="MuJoCo"),
              Line2D([], [], color="0.2", lw=1.0, ls="--", label="model")]  # fmt: skip
    first = ax1.legend(handles=styles, loc="lower left", fontsize=8)
    ax1.add_artist(first)
    ax1.legend(loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=7, ncols=1 + n // 13,
               title="end cap", title_fontsize=7)  # fmt: skip
    te = np.arange(len(error_curve)) * dt
    ax2.semilogy(te[1:], np.maximum(error_curve[1:], 1e-17))
    set_robust_limits(ax2, np.maximum(error_curve[1:], 1e-17), what="error")
    ax2.set(
        xlabel="horizon [s]",
        ylabel="mean rod position error [m]",
        title="rollout error, test split",
    )
    ax2.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def plot_end_cap_rollouts(
    dt: float,
    measured: np.ndarray,
    models: dict[str, np.ndarray],
    path: str | Path,
    title: str,
) -> Path:
    """Measured end-cap heights against each model's open-loop rollout, one panel a model.

    Every panel's height axis is scaled to the measured end caps: a model that diverges
    leaves it, with a note, instead of flattening the others.

    Args:
        dt: sample period [s].
        measured: measured end caps of one stretch, (T+1, n_caps, 3) [m] (NaN in gaps).
        models: label -> the model's end caps from the stretch's initial state,
            (T+1, n_caps, 3) [m].
        path: output PNG.
        title: what the stretch is (the figure's title).
    """
    t = np.arange(measured.shape[0]) * dt
    every = max(1, measured.shape[0] // 150)  # at most ~150 dots a cap: the lines stay visible
    colours = cap_colours(measured.shape[1])
    fig, axes = plt.subplots(1, len(models), figsize=(5.5 * len(models), 4.4), squeeze=False,
                             layout="constrained")  # fmt: skip
    for ax, (label, caps) in zip(axes[0], models.items(), strict=True):
        err = np.sqrt(np.nanmean(np.sum((caps - measured) ** 2, axis=-1)))
        for k, colour in enumerate(colours):
            ax.plot(t, caps[:, k, 2], lw=1.2, color=colour)
            ax.plot(t[::every], measured[::every, k, 2], ".", ms=3, color=colour)
        set_robust_limits(ax, measured[..., 2], also=[caps[..., 2]], what="model")
        ax.set(xlabel="time [s]", title=f"{label}: end-cap RMS {err * 1e3:.3g} mm")
        ax.grid(True, alpha=0.3)
    styles = [Line2D([], [], color="0.3", ls="", marker=".", label="measured"),
              Line2D([], [], color="0.3", lw=1.2, label="model")]  # fmt: skip
    axes[0, 0].legend(handles=styles, loc="lower left", fontsize=8)
    axes[0, 0].set_ylabel("end-cap height z [m]  (colour: end cap)")
    fig.suptitle(title)
    return save_figure(fig, path)
