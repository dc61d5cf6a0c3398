"""Every figure the demo draws is readable on its own: axes scaled to the data worth
seeing (a diverged model noted, not plotted to 1e112), distinct colours with legends
where lines need them, titles that do not overlap. Small synthetic inputs."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import numpy as np
import pytest
from matplotlib.figure import Figure

from tensegrity_env.plot_limits import robust_limits

DT = 0.01
T = 120


@pytest.fixture
def figures(monkeypatch: pytest.MonkeyPatch) -> Callable[[Any], list[Figure]]:
    """Patch a plotting module's ``save_figure`` to keep each figure it saves."""
    kept: list[Figure] = []

    def patch(module: Any) -> list[Figure]:
        original = module.save_figure

        def keep(fig: Any, path: str | Path) -> Path:
            kept.append(fig.figure if hasattr(fig, "figure") and fig.figure else fig)
            fig.canvas.draw()  # the layout as saved
            return original(fig, path)

        monkeypatch.setattr(module, "save_figure", keep)
        return kept

    return patch


def _caps(n: int = 12, seed: int = 0) -> np.ndarray:
    """End caps bouncing between 0.2 and 0.4 m, (T+1, n, 3) [m]."""
    t = np.arange(T + 1)[:, None] * DT
    caps = np.random.default_rng(seed).normal(size=(T + 1, n, 3)) * 0.01
    caps[..., 2] = 0.3 + 0.1 * np.sin(3 * t + np.arange(n))
    return caps


def _diverged(caps: np.ndarray) -> np.ndarray:
    """The caps of a model that blows up halfway, to 1e112 m and then inf."""
    bad = caps.copy()
    bad[T // 2 :, :, 2] = -np.logspace(0, 112, T + 1 - T // 2)[:, None]
    bad[-3:] = np.inf
    return bad


def _within(lim: tuple[float, float], data: np.ndarray, slack: float = 0.2) -> None:
    """The axis spans the data and no more than ``slack`` of its range beyond it."""
    lo, hi = float(np.nanmin(data)), float(np.nanmax(data))
    span = hi - lo
    assert lim[0] <= lo and lim[1] >= hi, (lim, lo, hi)
    assert lim[0] >= lo - slack * span and lim[1] <= hi + slack * span, (lim, lo, hi)


def _no_overlap(fig: Figure) -> None:
    """The figure's title sits above every panel title."""
    if fig._suptitle is None:
        return
    sup = fig._suptitle.get_window_extent()
    for ax in fig.axes:
        if ax.get_title():
            assert ax.title.get_window_extent().y1 <= sup.y0 + 1, ax.get_title()


def _notes(ax: Any) -> str:
    return " ".join(t.get_text() for t in ax.texts)


def test_robust_limits_leave_far_outliers_and_keep_physical_bounds() -> None:
    v = np.concatenate([np.random.default_rng(1).normal(size=10_000), [1e112, -1e30, np.nan]])
    lo, hi = robust_limits(v) or (0.0, 0.0)
    assert -6 < lo < -2 and 2 < hi < 6
    assert robust_limits(np.array([np.nan, np.inf])) is None
    assert robust_limits(np.array([0.5, 1.0, 2.0]), low=0.8)[0] == 0.8  # type: ignore[index]
    lo, hi = robust_limits(np.array([1e-6, 1e-3, 1e-1]), log=True) or (0.0, 0.0)
    assert 1e-7 < lo < 1e-6 and 1e-1 < hi < 1  # decades padded, never below zero
    # an ordinary set is shown whole
    x = np.linspace(-1, 3, 50)
    _within(robust_limits(x) or (0.0, 0.0), x)


def test_rollout_comparison(figures: Callable[[Any], list[Figure]], tmp_path: Path) -> None:
    from identification.report import plots

    kept = figures(plots)
    truth = _caps()
    err = np.abs(np.random.default_rng(2).normal(size=T + 1)) * 1e-3
    plots.plot_rollout_comparison(truth, _diverged(truth), DT, err, tmp_path / "r.png")
    (fig,) = kept
    heights, errors = fig.axes[:2]
    _within(heights.get_ylim(), truth[..., 2])
    assert "model off the y axis" in _notes(heights)
    colours = {tuple(line.get_color()) for line in heights.lines}
    assert len(colours) == 12  # one per end cap, none repeated
    labels = [t.get_text() for leg in heights.findobj(matplotlib.legend.Legend)
              for t in leg.get_texts()]  # fmt: skip
    assert {"MuJoCo", "model"} <= set(labels) and sum(s.startswith("cap") for s in labels) == 12
    dashed = [line for line in heights.lines if line.get_linestyle() == "--"]
    solid = [line for line in heights.lines if line.get_linestyle() == "-"]
    assert min(d.get_zorder() for d in dashed) > max(s.get_zorder() for s in solid)  # on top
    lo, hi = errors.get_ylim()
    assert lo <= err[1:].min() and hi >= err[1:].max() and hi < 10 * err.max()
    _no_overlap(fig)


def test_end_cap_rollouts(figures: Callable[[Any], list[Figure]], tmp_path: Path) -> None:
    from identification.report import plots

    kept = figures(plots)
    measured = _caps(seed=3)
    measured[10:14, 2] = np.nan  # a gap
    model = np.nan_to_num(measured, nan=0.3) + 0.002  # a model has no gaps
    models = {"declared model": _diverged(model), "diagnosed model": model}
    plots.plot_end_cap_rollouts(DT, measured, models, tmp_path / "e.png", "a long title " * 6)
    (fig,) = kept
    declared, diagnosed = fig.axes
    for ax in (declared, diagnosed):
        _within(ax.get_ylim(), np.concatenate([measured[..., 2], model[..., 2]]))
    assert "model off the y axis" in _notes(declared) and not _notes(diagnosed)
    assert "not finite" in _notes(declared)
    _no_overlap(fig)


def test_residual_panels(figures: Callable[[Any], list[Figure]], tmp_path: Path) -> None:
    """A spring fitted with an absurd rest length (l - l0 = -2.7 m on 0.64 m springs)
    stays off the stretch axis; outlying forces do not set the force axes."""
    from identification.discovery import residuals

    kept = figures(residuals)
    rng = np.random.default_rng(4)
    n, R, S = 400, 6, 24
    length = 0.64 + 0.02 * rng.normal(size=(n, S))
    stretch = 0.01 * rng.normal(size=(n, S))
    stretch[:, 3] = -2.7  # 1 spring in 24: too many points for a quantile to cut
    tension = rng.normal(size=(n, S))
    tension[0, 0] = 1e9  # one wild point
    res = residuals.Residuals(
        force=rng.normal(size=(n, R, 3)), torque=rng.normal(size=(n, R, 3)),
        along_v=rng.normal(size=(n, R)), speed=rng.uniform(0, 2, (n, R)),
        along_w=rng.normal(size=(n, R)), spin=rng.uniform(0, 5, (n, R)), tension=tension,
        stretch=stretch, length=length, rate=rng.normal(size=(n, S)),
        cap_force=rng.normal(size=(n, 2 * R, 3)), cap_height=rng.uniform(0, 0.5, (n, 2 * R)),
        cap_slip=rng.uniform(0, 1, (n, 2 * R)), command=np.zeros((n, R, 3)),
        time=np.arange(n) * DT,
    )  # fmt: skip
    residuals.plot_residuals(res, tmp_path / "res.png", "iteration 0")
    (fig,) = kept
    springs = fig.axes[2]
    lo, hi = springs.get_xlim()
    longest = 1e3 * length.max()  # mm: a rest length between 0 and twice the length
    assert -longest <= lo < -30 and 30 < hi <= longest
    assert "below" in _notes(springs)
    assert springs.get_ylim()[1] < 10  # the 1e9 N point is left out
    for ax in fig.axes:
        assert all(np.isfinite(ax.get_xlim())) and all(np.isfinite(ax.get_ylim()))
    _no_overlap(fig)


def test_window_residuals(figures: Callable[[Any], list[Figure]], tmp_path: Path) -> None:
    from identification.discovery import end_cap_residuals as ecr

    kept = figures(ecr)
    rng = np.random.default_rng(5)
    B, W, C = 8, 30, 12
    error = 1e-3 * rng.normal(size=(B, W + 1, C, 3))
    error[0, -1, 0] = 1e6  # one diverged sample
    r = ecr.WindowResiduals(error=error, height=rng.uniform(0, 0.4, (B, W + 1, C)),
                            speed=rng.uniform(0, 2, (B, W + 1, C)), time=np.arange(W + 1) * DT,
                            radius=np.full(C, 0.02))  # fmt: skip
    ecr.plot_window_residuals(r, tmp_path / "w.png", "window residuals", noise=1e-3)
    (fig,) = kept
    for ax in fig.axes:
        ys = np.concatenate([np.ravel(line.get_ydata()) for line in ax.lines])
        assert np.nanmedian(ys) >= ax.get_ylim()[0]
        assert ax.get_ylim()[1] < 1e5  # mm: the 1e6 m sample does not set the axis
    _no_overlap(fig)
