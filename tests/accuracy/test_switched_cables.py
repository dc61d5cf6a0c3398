"""A further cable asked of the trajectories: switched to a cable in the current model,
only a spring that really is one lowers the training windows' chi-square.

The current model is the truth with one cable missing (a spring that pushes when
compressed in its place). Every other spring is offered as a cable too, as a
regression that cannot tell them apart would: those that push when compressed raise
the chi-square when switched, those never compressed leave it unchanged, so neither
is taken.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from identification.discovery.end_cap_data import EndCapData, TrajectorySettings, fit_trajectory
from identification.discovery.slack_hypothesis import switched_cables
from identification.simulation.planted import PlantSpec, planted_dataset
from identification.trajectory.effect_coords import EffectCoords
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.slack_regression import SlackRegression
from tensegrity_env.effects import SlackSprings

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_only_the_missing_cable_lowers_the_chi_square() -> None:
    d = planted_dataset(PlantSpec("slack_springs", "moderate", noise=0.001, seed=46, n_train=2,
                                  n_val=1, n_test=1, steps=400))  # fmt: skip
    topo, truth = d.dataset.topology, d.ground_truth
    cables = sorted(truth.effects[0]["params"]["springs"])
    missing = cables[len(cables) // 2]
    known = set(cables) - {missing}
    data = EndCapData(d.dataset, TrajectorySettings(window=200, train_windows=4, seed=1))
    vec = ParamVector.at(topo, truth.params)
    vec = replace(vec, free=torch.zeros_like(vec.free),
                  coords=EffectCoords.of([SlackSprings(topo, springs=sorted(known))]))  # fmt: skip
    current = fit_trajectory(data, vec, data.windows["train"], vec.theta0(), 15)
    S = topo.n_springs
    # every spring not yet a cable offered: losing all its stiffness, by 5 standard errors
    offered = SlackRegression(
        values={"stiffness": np.ones(S), "compression_stiffness": -np.ones(S),
                "compression_stiffness_se": np.full(S, 0.2)},
        iterations=1, knot_change=0.0,
    )  # fmt: skip
    assert switched_cables(data, current, offered, known) == [missing]
