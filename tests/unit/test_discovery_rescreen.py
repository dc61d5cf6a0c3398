"""Which candidates the loop fits again after it added an effect."""

from __future__ import annotations

from types import SimpleNamespace

from identification.discovery.judge import MULTI_STEP, ONE_STEP, Candidate
from identification.discovery.loop import EffectDiscovery, Iteration
from identification.discovery.multi_step import MultiStepScorer
from identification.trajectory.end_cap_data import TrajectorySettings


def _pass(chosen_gain: float, others: dict[str, float]) -> Iteration:
    chosen = Candidate("linear_drag", None, None, gain=chosen_gain, accepted=True)  # type: ignore[arg-type]
    tried = [chosen] + [Candidate(n, None, None, gain=g) for n, g in others.items()]  # type: ignore[arg-type]
    return Iteration(chosen, tried, [], chosen, None, None, {})  # type: ignore[arg-type]


def test_a_candidate_that_hurt_more_than_the_added_effect_helped_is_not_refitted():
    loop = EffectDiscovery(SimpleNamespace(criteria=MULTI_STEP))  # type: ignore[arg-type]
    last = _pass(710.0, {"quadratic_drag": 572.0, "force_field": -3.0, "cubic_stiffness": -1186.0})
    why = loop.settled("cubic_stiffness", last)
    assert "-1186" in why and "linear_drag" in why
    # a passing one, one that barely lost, one not tried before: fitted again
    assert loop.settled("quadratic_drag", last) == ""
    assert loop.settled("force_field", last) == ""
    assert loop.settled("slack_springs", last) == ""
    assert loop.settled("cubic_stiffness", None) == ""  # the first pass fits all


def test_the_bound_moves_with_the_added_effect_gain():
    loop = EffectDiscovery(SimpleNamespace(criteria=MULTI_STEP))  # type: ignore[arg-type]
    assert loop.settled("cubic_stiffness", _pass(2000.0, {"cubic_stiffness": -1186.0})) == ""
    assert loop.settled("cubic_stiffness", _pass(1000.0, {"cubic_stiffness": -1186.0})) != ""


def test_fractional_gains_are_always_refitted():
    loop = EffectDiscovery(SimpleNamespace(criteria=ONE_STEP))  # type: ignore[arg-type]
    assert loop.settled("cubic_stiffness", _pass(0.5, {"cubic_stiffness": -0.9})) == ""


def test_the_report_names_the_windows_its_fits_use_on_the_floor_and_in_flight():
    s = TrajectorySettings(fit_windows=32, floor_windows=8, final_floor_windows=48)
    scorer = MultiStepScorer(s, 1.0)
    scorer.data = SimpleNamespace(on_floor=False)
    assert "refitted on 32 training windows" in scorer.describe()
    scorer.data = SimpleNamespace(on_floor=True)
    text = scorer.describe()
    assert "on 8 floor windows" in text and "up to 48" in text and "32" not in text
