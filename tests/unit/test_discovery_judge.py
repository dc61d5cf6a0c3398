"""The residual loop's one judge: thresholds, verdicts, ambiguity, and the estimator contract."""

from __future__ import annotations

import numpy as np
import pytest

from identification.discovery import EffectDiscovery, FitSettings, FittedModel, OneStepScorer
from identification.discovery.judge import (
    MIN_BIC_DROP,
    MULTI_STEP,
    ONE_STEP,
    Candidate,
    correlation,
    judge,
    runner_up,
)
from identification.linear.regression import NotFittedError
from tensegrity_env import assemblies
from tensegrity_env.model import Model

ICO = assemblies.icosahedron()
DECLARED = FittedModel(Model(ICO.topology, ICO.params), n_params=0)


def scored(name: str, bic: float, physical: bool = True) -> Candidate[None]:
    return Candidate(name, None, DECLARED, bic=bic, physical=physical)


@pytest.mark.parametrize(
    ("bic", "gain", "physical", "accepted", "reason"),
    [
        (-20.0, 0.5, True, True, "passes"),
        (-20.0, 0.5, False, False, "unphysical"),
        (-(MIN_BIC_DROP - 1), 0.5, True, False, "BIC drops only"),
        (float("nan"), 0.5, True, False, "BIC drops only"),
        (-20.0, 0.1, True, False, "one-step error drops only 10.0%"),
        (-20.0, -np.inf, True, False, "drops only"),
    ],
)
def test_one_step_judge(bic, gain, physical, accepted, reason):
    current, c = scored("nothing", 0.0), scored("x", bic, physical)
    judge(c, current, gain, ONE_STEP)
    assert c.accepted is accepted and reason in c.verdict
    assert c.bic_drop == pytest.approx(-bic, nan_ok=True)


def test_multi_step_judge_uses_chi_square():
    current = scored("nothing", 100.0)
    low, high = scored("a", 50.0), scored("b", 50.0)
    judge(low, current, MULTI_STEP.min_gain - 1, MULTI_STEP)
    judge(high, current, MULTI_STEP.min_gain + 1, MULTI_STEP)
    assert not low.accepted and "held-out chi-square drops only 9" in low.verdict
    assert high.accepted and "ΔBIC -50" in high.verdict


def test_runner_up_is_ambiguous_only_when_correlated_and_close():
    assert runner_up("b", 0.95, 1.5, "", ONE_STEP).ambiguous  # within a factor 2
    assert not runner_up("b", 0.95, 2.5, "", ONE_STEP).ambiguous
    assert not runner_up("b", 0.5, 1.5, "", ONE_STEP).ambiguous
    assert runner_up("b", 0.95, 5.0, "", MULTI_STEP).ambiguous  # chi-square gap < 10
    assert not runner_up("b", 0.95, 50.0, "", MULTI_STEP).ambiguous


def test_correlation():
    x = np.random.default_rng(0).normal(size=100)
    assert correlation(x, 2 * x + 1) == pytest.approx(1.0)
    assert correlation(x, -x) == pytest.approx(-1.0)
    assert correlation(x, np.ones_like(x)) == 0.0


def test_results_before_fit_raise():
    loop = EffectDiscovery(OneStepScorer(FitSettings()))
    with pytest.raises(NotFittedError):
        _ = loop.model_
    with pytest.raises(NotFittedError):
        _ = loop.iterations_
