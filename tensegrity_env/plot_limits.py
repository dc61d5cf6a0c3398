"""Axis limits scaled to the data worth seeing, for every figure the tools draw.

A diverged rollout (1e112 m), a handful of outlying residuals or a NaN would otherwise
set a figure's axis and flatten what it is there to show. :func:`robust_limits` takes
the inner finite values (all but the most extreme :data:`TAIL` at each end), widens
that to the extremes within :data:`REACH` of it, pads it and keeps it inside the
quantity's physical bounds;
:func:`set_robust_limits` applies that to one axis of a matplotlib ``Axes`` and marks
what it leaves out with a note in the panel, so a clipped curve is never mistaken for
the data.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

#: fraction of the finite values at each end that may fall outside the axis (at least
#: one value): the 0.5 % most extreme residuals never decide a scatter's scale, nor
#: one wild bin a curve's
TAIL = 0.005
#: fewer values than this are all shown: too few to tell an outlier from the data
FEWEST = 10
#: extremes within this multiple of the inner span beyond it are shown all the same: an
#: ordinary data set (an error growing exponentially included) is drawn whole, only
#: values far from all the others are cut
REACH = 1.0
#: margin around the limits, as a fraction of their span (matplotlib's own default)
PAD = 0.05


def _finite(values: Any, log: bool) -> np.ndarray:
    a = np.asarray(values, dtype=float).ravel()
    keep = np.isfinite(a) & (a > 0 if log else True)
    result: np.ndarray = np.log10(a[keep]) if log else a[keep]
    return result


def robust_limits(
    values: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    log: bool = False,
) -> tuple[float, float] | None:
    """``(lo, hi)`` that show the bulk of ``values`` (any shape, NaN/inf ignored).

    Args:
        values: the data the axis is scaled to.
        low, high: physical bounds of the quantity (e.g. a length is >= 0); the limits
            pass them only where every value lies beyond them.
        log: a log axis: limits from the positive values, in their decades.

    Returns:
        the limits in data units, or None where no value is finite (positive for ``log``).
    """
    v = _finite(values, log)
    if v.size == 0:
        return None
    v = np.sort(v)
    k = max(1, int(np.ceil(TAIL * v.size))) if v.size >= FEWEST else 0
    q_lo, q_hi = v[k], v[-1 - k]  # the inner values, the extremes left aside
    reach = REACH * (q_hi - q_lo)
    lo = v[np.searchsorted(v, q_lo - reach, side="left")]  # the outermost values in reach
    hi = v[np.searchsorted(v, q_hi + reach, side="right") - 1]
    if hi - lo <= 0:  # one value: a window around it
        half = 0.05 * abs(lo) if lo != 0 else (0.5 if log else 1.0)
        lo, hi = lo - half, hi + half
    pad = PAD * (hi - lo)
    lo, hi = lo - pad, hi + pad
    if log:
        lo, hi = 10.0**lo, 10.0**hi
    bounded = (lo if low is None else max(lo, low), hi if high is None else min(hi, high))
    if bounded[0] < bounded[1]:  # else every value lies outside the bounds: show them
        lo, hi = bounded
    return float(lo), float(hi)


def set_robust_limits(
    ax: Any,
    values: Any,
    axis: str = "y",
    *,
    also: Iterable[Any] = (),
    low: float | None = None,
    high: float | None = None,
    what: str = "values",
) -> tuple[float, float] | None:
    """Scale ``ax``'s ``axis`` ("x" or "y") to ``values`` and note what it leaves out.

    Args:
        ax: a matplotlib ``Axes``; a log axis is scaled in decades.
        values: the data the axis is scaled to (e.g. the measured curve).
        also: more data drawn on the axis that must not widen it (e.g. a model's
            rollout, which may diverge); it is counted in the note, its NaN and inf
            too (NaN in ``values`` are gaps in the data, not noted).
        low, high: physical bounds of the quantity.
        what: what the values are, for the note ("values outside the axis ...").

    Returns:
        the limits set, or None where nothing is finite (the axis is left alone).
    """
    log = (ax.get_yscale() if axis == "y" else ax.get_xscale()) == "log"
    limits = robust_limits(values, low=low, high=high, log=log)
    if limits is None:
        return None
    (ax.set_ylim if axis == "y" else ax.set_xlim)(*limits)
    base = np.asarray(values, dtype=float).ravel()
    more = [np.asarray(a, dtype=float).ravel() for a in also]
    allv = np.concatenate([base, *more])
    finite = allv[np.isfinite(allv)]
    lo, hi = limits
    below, above = int(np.sum(finite < lo)), int(np.sum(finite > hi))
    bad = sum(int(np.sum(~np.isfinite(m))) for m in more)  # NaN in ``values``: gaps
    if below or above or bad:
        parts = []
        if below:
            parts.append(f"{below} below (min {finite.min():.3g})")
        if above:
            parts.append(f"{above} above (max {finite.max():.3g})")
        if bad:
            parts.append(f"{bad} not finite")
        ax.text(0.01, 0.99 if axis == "y" else 0.06, f"{what} off the {axis} axis: "
                + ", ".join(parts), transform=ax.transAxes, va="top", ha="left", fontsize=7,
                color="firebrick", bbox={"facecolor": "white", "alpha": 0.8, "lw": 0})  # fmt: skip
    return limits
