"""MuJoCo tendon friction loss the model is not told about: the one-step residual loop
names dry friction along the springs, among the candidates that act everywhere."""

from __future__ import annotations

import numpy as np
import pytest

from identification.discovery.choose import choose_scorer
from identification.discovery.library import FitSettings
from identification.discovery.loop import EffectDiscovery
from identification.discovery.one_step import OneStepScorer
from identification.simulation.planted import PlantSpec, planted_dataset
from tensegrity_env.effects import SpringFriction

pytestmark = [pytest.mark.usefixtures("one_torch_thread"), pytest.mark.slow]


def test_tendon_friction_loss_is_named_as_spring_friction() -> None:
    spec = PlantSpec("spring_friction", "weak", n_train=4, n_val=2, n_test=2, steps=500, seed=0)
    data = planted_dataset(spec)
    settings = FitSettings(anchors={"mass[rod0]": float(data.ground_truth.params.mass[0])})

    def trajectory(d: object) -> OneStepScorer:
        raise AssertionError("clean MuJoCo data has rod states: the one-step scorer judges it")

    dataset, scorer = choose_scorer(
        data.dataset, "auto", lambda d: OneStepScorer(settings, horizon_s=1.0), trajectory
    )
    names = ["spring_friction", "linear_drag", "quadratic_drag", "cubic_stiffness"]
    with np.errstate(invalid="ignore", divide="ignore"):
        result = EffectDiscovery(scorer, 2, names, log=lambda s: None).fit(dataset).result_
    assert result.model.names == ["spring_friction"]
    (friction,) = result.model.effects
    assert isinstance(friction, SpringFriction)
    # MuJoCo's soft friction constraint holds less than F near sticking: the velocity law
    # identifies a friction below the planted 0.2 N on every spring, never above it
    f = friction.values["friction"].numpy()
    assert np.all((f > 0.02) & (f < 0.2)), f
    assert result.final_test["one_step"] < 0.7 * result.baseline_test["one_step"]
