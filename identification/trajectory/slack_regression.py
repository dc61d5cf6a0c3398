"""Which springs are cables: a segmented regression on smoothed end caps.

A cable pulls like a spring when longer than its rest length ``l0`` and does nothing
when shorter. Fitted without that, a spring model makes up for it with a lower
stiffness and a shorter rest length, and a fit through the windows that starts from
there (a stiffness change in compression, jointly with everything else) stays near that
compromise and misses most of the cables on noisy data.

Here the question is put to the stage-1 regression instead (:func:`smoothed_regression`
on Savitzky-Golay smoothed end caps), which is linear and so has no compromise to stop
in: every spring gets a stiffness change ``ΔK_s`` below a knot, the knot is tied to its
own fitted rest length, and the two are iterated to a fixed point (segmented regression
with the break point at ``l0``). A cable shows ``ΔK_s ≈ -K_s``; a spring ``ΔK_s ≈ 0``.
Smoothing biases the stiffnesses low on fast data, but the ratio ``-ΔK/K`` is a ratio
of two numbers biased alike. Where cables go slack only briefly and shallowly (a small
fraction of the samples at a motion-capture rate) the ratio overshoots 1, so a cable
is a spring that loses at least :data:`CABLE_LOSS` of its stiffness, significantly.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from identification.data.end_caps import SmoothedStates
from identification.linear.smoothed import smoothed_regression
from tensegrity_env.topology import Topology

#: a spring is a cable when compressing it loses at least this fraction of its stiffness
#: (a cable loses all of it; no upper bound: briefly slack cables overshoot 1, and noise
#: is the significance's job) ...
CABLE_LOSS = 0.75
#: ... by at least this many standard errors (above what springs without slack reach
#: on noisy plants with a drag, below what most briefly slack cables reach)
CABLE_SIGNIFICANCE = 10.0


@dataclass(frozen=True)
class SlackRegression:
    """The segmented regression's result.

    Attributes:
        values: natural-unit parameters as :func:`smoothed_regression` returns them,
            with every spring's ``compression_stiffness`` ΔK (S,) [N/m] and its
            standard error ``compression_stiffness_se``.
        iterations: knot updates until the rest lengths stopped moving.
        knot_change: the last update's largest knot move [m].
    """

    values: dict[str, np.ndarray]
    iterations: int
    knot_change: float

    @property
    def loss(self) -> np.ndarray:
        """Fraction of its stiffness each spring loses when compressed, (S,)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return -self.values["compression_stiffness"] / self.values["stiffness"]

    @property
    def significance(self) -> np.ndarray:
        """``|ΔK| / stderr`` per spring, (S,); 0 where it cannot be told."""
        dk, se = self.values["compression_stiffness"], self.values["compression_stiffness_se"]
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.abs(dk) / se
        return np.where(np.isfinite(z), z, 0.0)

    def cables(
        self, loss: float = CABLE_LOSS, significance: float = CABLE_SIGNIFICANCE
    ) -> list[int]:
        """Springs that lose at least ``loss`` of K in compression, significantly."""
        lost = np.nan_to_num(self.loss)
        found = (lost >= loss) & (self.significance >= significance)
        return [int(i) for i in np.flatnonzero(found)]


def slack_regression(
    topology: Topology,
    smooth: SmoothedStates,
    control: np.ndarray,
    anchors: Mapping[str, float] | None = None,
    keep: np.ndarray | None = None,
    max_iter: int = 40,
    rod_keep: np.ndarray | None = None,
    tol: float = 1e-5,
    pivots: np.ndarray | None = None,
    radius: np.ndarray | None = None,
) -> SlackRegression:
    """Fit every spring's compression stiffness change with its knot at its rest length.

    Arguments are :func:`smoothed_regression`'s (``control`` (N, T, R, 3), ``keep``
    (N, T), ``rod_keep`` and ``pivots`` (N, T, R), ``radius`` (R,) [m]). The knots start at the rest lengths of the regression without hinges and
    follow the fitted rest lengths until no knot moves more than ``tol`` [m].
    """
    rows: dict[str, Any] = {"keep": keep, "rod_keep": rod_keep, "pivots": pivots, "radius": radius}
    plain = smoothed_regression(topology, smooth, control, anchors, **rows)
    knots = np.nan_to_num(plain["rest_length"], nan=float(np.nanmedian(plain["rest_length"])))
    values, change, it = plain, np.inf, 0
    for it in range(1, max_iter + 1):  # noqa: B007  (reported)
        values = smoothed_regression(topology, smooth, control, anchors, knots=knots, **rows)
        rest = np.where(np.isfinite(values["rest_length"]), values["rest_length"], knots)
        change = float(np.abs(rest - knots).max())
        knots = rest
        if change < tol:
            break
    return SlackRegression(values=values, iterations=it, knot_change=change)
