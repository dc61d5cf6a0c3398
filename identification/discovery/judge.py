"""The residual loop's thresholds and its one judge.

A candidate (the current model plus one effect, fitted) is accepted only when

1. its model lies in the physical domain (:func:`unphysical`: the checks a params file
   must pass to load, e.g. drag coefficients >= 0), each part of a drag it adds removes
   energy over the data (:func:`~identification.discovery.negligible.group_power`), and
   it is not negligible: the force
   it adds on the rods is at least :data:`~identification.discovery.negligible.NEGLIGIBLE`
   of their weight (:func:`~identification.discovery.negligible.force_ratio`);
2. it lowers the **Bayesian information criterion** of the training errors by at least
   :data:`MIN_BIC_DROP` (``n ln(SSE / n) + k ln n``: each added parameter must pay);
3. it lowers the **held-out** (validation) error by at least the scorer's minimum
   gain: the fraction :data:`MIN_GAIN` of the one-step error on rod states, or
   :data:`MIN_CHI2_GAIN` of the chi-square of multi-step end-cap predictions.

The best accepted candidate is added; if the scorer's refit of it leaves the physical
domain, :func:`overrule` rejects it after all and the next passing one is tried. When
the runner-up also passes, the two are
**ambiguous** if their predicted changes (against the current model) correlate above
:data:`AMBIGUOUS_CORRELATION` and their held-out errors are closer than the scorer's
separation (a factor :data:`AMBIGUOUS_RATIO` of one-step errors, or
:data:`AMBIGUOUS_CHI2` of chi-square): the data cannot tell them apart.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Generic, TypeVar

import numpy as np

from identification.discovery.negligible import NEGLIGIBLE
from identification.trajectory.fitted_model import FittedModel

#: a candidate must lower the training BIC by this much ...
MIN_BIC_DROP = 10.0
#: ... and the held-out one-step error (rod states) by this fraction ...
MIN_GAIN = 0.2
#: ... or the held-out chi-square (multi-step end caps) by this much
MIN_CHI2_GAIN = 10.0
#: two passing candidates whose predicted changes correlate above this ...
AMBIGUOUS_CORRELATION = 0.9
#: ... with held-out one-step errors within this factor ...
AMBIGUOUS_RATIO = 2.0
#: ... or held-out chi-squares closer than this cannot be told apart
AMBIGUOUS_CHI2 = 10.0
#: held-out one-step error [m] below which the residual is round-off (float64 at 1 ms);
#: errors and the BIC's mean square are floored there
ROUND_OFF = 1e-12

F = TypeVar("F")


@dataclass(frozen=True)
class Criteria:
    """How a scorer's held-out gain is judged.

    Attributes:
        measure: what the gain lowers, e.g. ``"held-out one-step error"``.
        min_gain: the gain a candidate must reach.
        relative: the gain is a fraction (printed as a percentage), else a number.
        max_separation: a passing runner-up closer than this to the chosen candidate
            (see :meth:`~identification.discovery.scorer.Judged.separation`), with
            correlated predicted changes, cannot be told apart from it.
    """

    measure: str
    min_gain: float
    relative: bool
    max_separation: float

    def format_gain(self, gain: float) -> str:
        return f"{gain:.1%}" if self.relative else f"{gain:.4g}"


#: one-step errors on rod states: the fraction of the held-out error removed
ONE_STEP = Criteria("held-out one-step error", MIN_GAIN, True, AMBIGUOUS_RATIO)
#: multi-step end-cap predictions: the held-out chi-square removed
MULTI_STEP = Criteria("held-out chi-square", MIN_CHI2_GAIN, False, AMBIGUOUS_CHI2)


@dataclass
class Candidate(Generic[F]):
    """A model fitted and scored: the current one plus a candidate effect, or the
    current model itself (``name == "nothing"``).

    Attributes:
        name: the effect added (``"nothing"`` for the current model).
        fit: what the scorer fitted (what it needs to score, compare and refit).
        model: the model it stands for (parameters, effects, fitted-parameter count).
        heldout: held-out (validation) errors [m] by name, as the scorer reports them.
        bic: information criterion of the training errors.
        rank: the scorer's ordering among candidates, lower is better.
        gate: why the candidate may act here.
        seconds: fit and score wall time [s].
        gain: how much it lowers the held-out error (:class:`Criteria` unit).
        bic_drop: how much it lowers the BIC.
        accepted: it passes every test of :func:`judge`.
        verdict: one line saying why it passes or not.
        size: the RMS force it adds on the rods, in rod weights (NaN: not measured).
    """

    name: str
    fit: F
    model: FittedModel
    heldout: dict[str, float] = field(default_factory=dict)
    bic: float = float("nan")
    rank: float = 0.0
    gate: str = ""
    seconds: float = 0.0
    gain: float = 0.0
    bic_drop: float = 0.0
    accepted: bool = False
    verdict: str = ""
    size: float = float("nan")


def judge(
    candidate: Candidate[F],
    current: Candidate[F],
    gain: float,
    criteria: Criteria,
    size: float = float("nan"),
    power: Mapping[str, float] | None = None,
) -> None:
    """Accept or reject ``candidate`` against ``current`` (sets its verdict fields).

    ``size``: the force the candidate adds, in rod weights (NaN: not checked);
    ``power``: the mean power [W] each part of the drag it adds puts in over the data
    (:func:`~identification.discovery.negligible.group_power`; None: not a drag).
    """
    c = candidate
    c.gain, c.bic_drop, c.size = gain, current.bic - c.bic, size
    reason = unphysical(c.model, current.model)
    adding = {k: p for k, p in (power or {}).items() if p > 0}
    if reason:
        c.verdict = f"rejected: unphysical ({reason})"
    elif adding:
        key, p = next(iter(adding.items()))
        c.verdict = (f"rejected: unphysical ({c.name}: its {key} part adds {p:.3g} W over "
                     "the data; drag only removes energy)")  # fmt: skip
    elif size < NEGLIGIBLE:
        c.verdict = (
            f"negligible: its force on the rods is {size:.2%} of their weight (< {NEGLIGIBLE:.1%})"
        )
    elif c.bic_drop < 0:
        c.verdict = f"rejected: BIC rises by {-c.bic_drop:.3g} (it must drop by {MIN_BIC_DROP:g})"
    elif not c.bic_drop >= MIN_BIC_DROP:
        c.verdict = f"rejected: BIC drops only {c.bic_drop:.3g} (< {MIN_BIC_DROP:g})"
    elif not c.gain >= criteria.min_gain:
        c.verdict = f"rejected: {criteria.measure} drops only {criteria.format_gain(c.gain)}"
    else:
        c.accepted = True
        c.verdict = (
            f"passes ({criteria.measure} -{criteria.format_gain(c.gain)}, ΔBIC -{c.bic_drop:.4g})"
        )


def unphysical(model: FittedModel, current: FittedModel | None = None) -> str:
    """Why ``model`` lies outside the physical domain (one line), or ``""``.

    The domain is the one a params file must lie in to load
    (:meth:`~tensegrity_env.model.Model.violation`): positive masses, inertias and
    stiffnesses, and each effect's own checks (drag coefficients >= 0 within 3 of their
    standard errors, contact parameters in range, ...).

    ``current``: the model ``model`` would replace. When its declared parameters are
    already outside the domain (an effect still missing biases them, e.g. a thin rod's
    inertias past the triangle inequality), only ``model``'s effects are checked: the
    candidate did not put the declared parameters there, and it may be what brings them
    back.
    """
    if current is not None and current.model.params_violation():
        return model.model.effects_violation()
    return model.model.violation()


def overrule(candidate: Candidate[F], reason: str) -> None:
    """Reject an accepted ``candidate`` after all: its refit (as the next current model)
    ``reason`` (a clause: "is unphysical (...)", "fits ... worse ...")."""
    candidate.accepted = False
    candidate.verdict = f"rejected: its refit as the model {reason}"


@dataclass
class RunnerUp:
    """The second candidate that also passed, compared with the chosen one.

    Attributes:
        name: its effect.
        correlation: of the two models' predicted changes against the current model.
        separation: how far apart their held-out errors are (the scorer's measure).
        note: the separation in words.
        ambiguous: the data cannot tell the two apart.
    """

    name: str
    correlation: float
    separation: float
    note: str
    ambiguous: bool


def runner_up(
    name: str, correlation: float, separation: float, note: str, criteria: Criteria
) -> RunnerUp:
    """The runner-up, flagged ambiguous by :data:`AMBIGUOUS_CORRELATION` and the separation."""
    ambiguous = correlation > AMBIGUOUS_CORRELATION and separation < criteria.max_separation
    return RunnerUp(name, correlation, separation, note, ambiguous)


def correlation(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson correlation of two flattened arrays (0 when either is constant)."""
    x, y = np.ravel(x), np.ravel(y)
    sx, sy = x.std(), y.std()
    if not (sx > 0 and sy > 0):
        return 0.0
    return float(np.mean((x - x.mean()) * (y - y.mean())) / (sx * sy))


def finite(x: float) -> float:
    """``x``, or infinity where it is NaN or infinite (a diverged error)."""
    return x if np.isfinite(x) else float("inf")
