"""MuJoCo free-joint damping the model is not told about: the one-step residual loop names
linear drag in its implicit form, exactly, with no spurious force field."""

from __future__ import annotations

import numpy as np
import pytest

from identification.discovery.library import FitSettings
from identification.discovery.loop import EffectDiscovery
from identification.discovery.one_step import OneStepScorer
from identification.simulation.planted import PlantSpec, planted_dataset
from tensegrity_env.effects import ImplicitLinearDrag

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_joint_damping_is_named_as_implicit_linear_drag() -> None:
    data = planted_dataset(PlantSpec("joint_damping", n_train=4, n_val=2, n_test=2, seed=4))
    assert data.ground_truth.effects[0]["form"] == "implicit"
    settings = FitSettings(anchors={"mass[rod0]": float(data.ground_truth.params.mass[0])})
    with np.errstate(invalid="ignore", divide="ignore"):
        loop = EffectDiscovery(OneStepScorer(settings, horizon_s=1.0), 3, None, log=lambda s: None)
        result = loop.fit(data.dataset).result_
    assert result.model.names == ["linear_drag"]
    (drag,) = result.model.effects
    assert isinstance(drag, ImplicitLinearDrag)
    # MuJoCo damps every free-joint velocity by 0.4 (the axial spin's coefficient rests on
    # the tiny axial inertia: looser)
    values = np.concatenate(
        [drag.values["translational"].numpy(), drag.values["rotational"].numpy()]
    )
    assert np.allclose(values[:5], 0.4, rtol=1e-8), values
    assert abs(values[5] / 0.4 - 1) < 1e-4, values
    # the explicit form would leave b g dt = 3.9 mN upward on every rod, at 1e-9 m per step
    assert result.final_test["one_step"] < 1e-14
    assert result.final_test["rollout"] < 1e-9  # 1-s open-loop rollout [m]
    assert result.residual_network is None
    stated = np.concatenate([drag.uncertainty[k] for k in ("translational", "rotational")])
    assert np.all(stated > 0) and np.all(np.abs(values - 0.4) < 3 * stated), stated
