"""Which candidates the multi-step scorer looks at again: on the floor, where no screened
candidate passes and the current model misfits, the most promising ones are fitted
again with everything free (``MultiStepScorer.second_look``; the loop's side is tested
in ``test_discovery_domain.py``)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from identification.discovery.multi_step import MISFIT, RIVALS, SECOND_LOOKS, MultiStepScorer


def looks(rms: float, gains: dict[str, float], on_floor: bool = True, accepted: str = "",
          sizes: dict[str, float] | None = None, joint: tuple[str, ...] = (),
          heldout: float | None = None) -> list[str]:  # fmt: skip
    """``MultiStepScorer.second_look`` with a current model fitting the training windows
    to ``rms`` [m] and the held-out ones to ``heldout`` (None: ``rms``) at a noise level of
    1 mm, and candidates with ``gains`` (those in ``joint`` fitted with a floor fit of their
    own already)."""
    scorer = MultiStepScorer.__new__(MultiStepScorer)
    scorer.data = SimpleNamespace(on_floor=on_floor)  # type: ignore[assignment]
    scorer.noise = 1e-3
    current: Any = SimpleNamespace(fit=SimpleNamespace(final=SimpleNamespace(rms=rms)),
                                   heldout={"caps_rms": rms if heldout is None else heldout})  # fmt: skip
    size = sizes or {}
    tried: Any = [SimpleNamespace(name=n, gain=g, accepted=n == accepted, size=size.get(n, 0.01),
                                  fit=SimpleNamespace(floor="floor fit" if n in joint else None))
                  for n, g in gains.items()]  # fmt: skip
    return scorer.second_look(current, tried)


def test_the_second_look_takes_the_largest_positive_gains_of_a_misfitting_floor_model():
    gains = {"linear_drag": 6.4, "quadratic_drag": 8.2, "force_field": 0.8, "cubic": -3.0}
    assert SECOND_LOOKS == 2
    assert looks(2.7e-3, gains) == ["quadratic_drag", "linear_drag"]
    assert looks(2.7e-3, {"force_field": 0.8, "cubic": -3.0}) == ["force_field"]
    assert looks(2.7e-3, {"cubic": -3.0}) == []


def test_a_drag_looked_at_again_brings_its_rival_whatever_its_screened_gain():
    """The quadratic-drag floor cell's screens put quadratic drag third, behind linear drag
    and cubic stiffness: fitted again alone, linear drag passed."""
    assert RIVALS["linear_drag"] == "quadratic_drag" and RIVALS["quadratic_drag"] == "linear_drag"
    gains = {"linear_drag": 30.0, "cubic": 12.0, "quadratic_drag": 9.0, "force_field": 1.0}
    assert looks(1.4e-3, gains) == ["linear_drag", "cubic", "quadratic_drag"]
    gains["quadratic_drag"] = -5.0  # a screen that made held-out prediction worse: still
    assert looks(1.4e-3, gains) == ["linear_drag", "cubic", "quadratic_drag"]
    # not a rival whose force is negligible, nor one never screened
    sizes = {"quadratic_drag": 1e-6}
    assert looks(1.4e-3, gains, sizes=sizes) == ["linear_drag", "cubic"]
    del gains["quadratic_drag"]
    assert looks(1.4e-3, gains) == ["linear_drag", "cubic"]


def test_no_second_look_at_the_noise_level_in_flight_or_once_a_screen_passes():
    gains = {"linear_drag": 6.4, "quadratic_drag": 8.2}
    assert looks(1.07e-3, gains) == []  # a floor-only control's fit
    assert looks(MISFIT * 1e-3 * 0.999, gains) == []
    assert looks(MISFIT * 1e-3 * 1.001, gains) == ["quadratic_drag", "linear_drag"]
    assert looks(2.7e-3, gains, on_floor=False) == []
    assert looks(2.7e-3, gains, accepted="linear_drag") == []


def test_no_second_look_at_a_candidate_whose_force_is_negligible():
    """After linear drag on the joint-damping floor cell, force field and cubic stiffness
    gained about 104 with forces of 0.00 % of the rods' weight: the states' gain."""
    gains = {"quadratic_drag": 72.1, "force_field": 104.7, "cubic_stiffness": 104.2}
    sizes = {"force_field": 1e-6, "cubic_stiffness": 2e-6, "quadratic_drag": float("nan")}
    assert looks(1.37e-3, gains, sizes=sizes) == ["quadratic_drag"]


def test_no_second_look_at_a_candidate_fitted_with_everything_free_already():
    """Slack cables on the floor come with a floor fit of their own: fitted again, the
    same fit would come out."""
    gains = {"slack_springs": 960.0, "linear_drag": 97.6, "quadratic_drag": 141.0}
    assert looks(6.0e-3, gains) == ["slack_springs", "quadratic_drag", "linear_drag"]
    assert looks(6.0e-3, gains, joint=("slack_springs",)) == ["quadratic_drag", "linear_drag"]


def test_no_second_look_where_only_the_training_windows_misfit():
    """The slack-cable floor cell's accepted cables fitted their training windows to
    1.273 mm, their states stopped in other basins through the impacts, while the model
    predicted the held-out windows to about 1.06 mm (1 mm noise)."""
    gains = {"cubic_stiffness": 10.1, "linear_drag": -98.7}
    assert looks(1.273e-3, gains) == ["cubic_stiffness"]
    assert looks(1.273e-3, gains, heldout=1.06e-3) == []
    assert looks(1.06e-3, gains, heldout=1.273e-3) == []  # a good training fit says enough
    assert looks(2.7e-3, gains, heldout=2.5e-3) == ["cubic_stiffness"]  # both misfit
