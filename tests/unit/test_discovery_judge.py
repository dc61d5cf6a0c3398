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
    unphysical,
)
from identification.linear.regression import NotFittedError
from tensegrity_env import assemblies
from tensegrity_env.effects import LinearDrag
from tensegrity_env.model import Model

ICO = assemblies.icosahedron()
DECLARED = FittedModel(Model(ICO.topology, ICO.params), n_params=0)


def with_drag(b_axial: float, se: float = 0.0) -> FittedModel:
    """The declared model plus linear drag whose axial coefficient is ``b_axial`` ± ``se``."""
    drag = LinearDrag(ICO.topology, validate=False, translational=[0.4, 0.4, b_axial],
                      uncertainty={"translational": [0.01, 0.01, se]})  # fmt: skip
    return FittedModel(Model(ICO.topology, ICO.params, [drag]), n_params=6)


#: a fit that drove a drag coefficient negative, 5 standard errors below 0
NEGATIVE_DRAG = with_drag(-0.131, 0.0267)


def scored(name: str, bic: float, physical: bool = True) -> Candidate[None]:
    return Candidate(name, None, DECLARED if physical else NEGATIVE_DRAG, bic=bic)


@pytest.mark.parametrize(
    ("bic", "gain", "physical", "accepted", "reason"),
    [
        (-20.0, 0.5, True, True, "passes"),
        (-20.0, 0.5, False, False, "rejected: unphysical (effect 'linear_drag'"),
        (-(MIN_BIC_DROP - 1), 0.5, True, False, "BIC drops only"),
        (float("nan"), 0.5, True, False, "BIC drops only"),
        (5.0, 0.5, True, False, "BIC rises by 5 (it must drop by"),
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


def test_negative_drag_is_rejected_with_the_value_and_its_standard_error():
    current, c = scored("nothing", 0.0), scored("linear_drag", -500.0, physical=False)
    judge(c, current, 1e4, MULTI_STEP)  # far better on every score, but not physical
    assert not c.accepted
    assert c.verdict == (
        "rejected: unphysical (effect 'linear_drag': 'translational' must be >= 0 (drag "
        "opposes motion), got [2] = -0.131 ± 0.027 N*s/m)"
    )
    # within 3 standard errors of 0 it is zero drag, as Model.load reads it
    c = Candidate("linear_drag", None, with_drag(-0.05, 0.0267), bic=-500.0)
    judge(c, current, 1e4, MULTI_STEP)
    assert c.accepted and unphysical(c.model) == ""


def test_unphysical_declared_parameters_are_named():
    bad = FittedModel(Model(ICO.topology, ICO.params.replace(mass=-ICO.params.mass)), 0)
    assert unphysical(bad).startswith("declared parameters: masses must be positive")
    assert unphysical(DECLARED) == ""


def test_declared_parameters_already_unphysical_are_not_held_against_a_candidate():
    """A thin rod's inertias biased past the triangle inequality by an effect still
    missing: the candidate that may fix it is judged on its own effects."""
    inertia = ICO.params.inertia.clone()
    inertia[0] = inertia[0] * inertia.new_tensor([1.0, 1.0, 0.0]) + inertia.new_tensor(
        [0.0, 0.0, 1e-6]
    )
    inertia[0, 0] *= 1.2  # Ixx > Iyy + Izz
    biased = ICO.params.replace(inertia=inertia)
    current = FittedModel(Model(ICO.topology, biased), n_params=0)
    assert "triangle" in unphysical(current)
    candidate = FittedModel(Model(ICO.topology, biased, with_drag(0.4).model.effects), 6)
    assert unphysical(candidate, current) == ""
    assert "triangle" in unphysical(candidate, DECLARED)  # it made them unphysical
    bad = FittedModel(Model(ICO.topology, biased, NEGATIVE_DRAG.model.effects), 6)
    assert "linear_drag" in unphysical(bad, current)  # its own effect is still checked


def test_a_drag_coefficient_the_data_cannot_see_is_in_the_domain(recwarn):
    """An infinite standard error (unobservable) admits any value, without overflow."""
    assert unphysical(with_drag(-0.5, float("inf"))) == ""
    assert unphysical(with_drag(-0.5, float("nan"))).startswith("effect 'linear_drag'")
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
