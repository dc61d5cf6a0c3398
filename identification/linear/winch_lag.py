"""The winch motors' lag: the one nonlinear unknown of a winch-driven regression.

Given the lag ``tau`` the winding is linear in ``v_max`` and the regression
(:class:`~identification.linear.regression.SpringRodIdentifier`) identifies ``K``,
``c`` and ``K·v`` exactly; the residual then tells how well ``tau`` explains the data,
so ``tau`` is found by a one-dimensional search on the residual: a log grid, then a
bounded search between the best grid point's neighbours. One lag is searched for all
motors (motors of one kind); "no lag" (``tau = 0``) is a candidate too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TypeVar

import numpy as np
from scipy.optimize import minimize_scalar

from identification.data.dataset import Dataset
from identification.linear.regression import SpringRodIdentifier

#: the lags tried first [s]: 1 ms to 1 s, the span of small DC motors with gearboxes
LAG_GRID = tuple(float(x) for x in np.geomspace(1e-3, 1.0, 13))
#: relative tolerance of the bounded search on tau
LAG_TOLERANCE = 1e-3

Fit = TypeVar("Fit")


def search_winch_lag(
    fit: Callable[[float], Fit], rss: Callable[[Fit], float]
) -> tuple[float, Fit, dict[float, float]]:
    """The lag [s] whose fit has the smallest residual (module doc): ``fit(tau)`` fits
    with that lag, ``rss(result)`` is its residual sum of squares. Returns the lag, its
    fit and the residual of every lag tried."""
    fits: dict[float, tuple[float, Fit]] = {}

    def rss_at(tau: float) -> float:
        if tau not in fits:
            result = fit(tau)
            fits[tau] = (float(rss(result)), result)
        return fits[tau][0]

    grid = [rss_at(tau) for tau in LAG_GRID]
    rss_at(0.0)
    k = int(np.argmin(grid))
    lo, hi = np.log(LAG_GRID[max(k - 1, 0)]), np.log(LAG_GRID[min(k + 1, len(LAG_GRID) - 1)])
    minimize_scalar(lambda x: rss_at(float(np.exp(x))), bounds=(lo, hi), method="bounded",
                    options={"xatol": LAG_TOLERANCE})  # fmt: skip
    tau = min(fits, key=lambda t: fits[t][0])
    return tau, fits[tau][1], {t: v[0] for t, v in sorted(fits.items())}


def fit_winch_lag(
    dataset: Dataset,
    identifier: Callable[[float], SpringRodIdentifier],
    split: str = "train",
) -> SpringRodIdentifier:
    """The fitted identifier whose winch lag gives the smallest residual.

    Args:
        dataset: data with winch commands (``winch_control``).
        identifier: builds an unfitted identifier for a lag [s] (for example
            ``lambda tau: SpringRodIdentifier(anchors=..., winch_lag=tau)``).
        split: the split to fit.

    Returns the best fitted identifier; its ``winch_lag_`` is the lag found (its table
    rows ``identified``) and ``lag_search_`` maps every lag tried [s] to its residual sum
    of squares.
    """
    if not dataset.topology.n_winches:
        raise ValueError(f"{dataset.path or 'dataset'}: the robot has no winches")
    _, best, tried = search_winch_lag(
        lambda tau: identifier(tau).fit(dataset, split), lambda f: float(f.solution_.rss)
    )
    best.lag_search_ = tried
    best.table_ = [
        dataclasses.replace(r, status="identified", note="the smallest regression residual")
        if r.group == "winch_lag" else r
        for r in best.table_
    ]  # fmt: skip
    return best
