"""The lab prism with force actuators (sphere end caps, cables on the cap surfaces, filtered cable
actuators, a floor): the residual loop finds both the floor contact and the filter from
the data and recovers what the file says."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from identification.discovery.library import FitSettings
from identification.discovery.loop import EffectDiscovery
from identification.discovery.one_step import OneStepScorer
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.model import Model

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ROBOT = Path(__file__).resolve().parents[2] / "tensegrity_env" / "assets" / "lab_prism_force_actuators.xml"


def test_floor_contact_and_actuator_filter_found_together() -> None:
    spec = GenerateSpec(mjcf=str(ROBOT), n_train=4, n_val=1, n_test=1, steps=1000, seed=11,
                        control_std=1.0)  # fmt: skip
    ds, truth = generate_dataset(spec)
    settings = FitSettings(anchors={"mass[r0]": float(truth.params.mass[0])})
    with np.errstate(invalid="ignore", divide="ignore"):
        loop = EffectDiscovery(OneStepScorer(settings, horizon_s=1.0), 2,
                               ["ground_contact", "control_lag", "linear_drag"], log=lambda s: None)  # fmt: skip
        result = loop.fit(ds).result_
    assert sorted(result.model.names) == ["control_lag", "ground_contact"]
    declared = {e.name: e for e in Model.read(ROBOT).effects}
    for effect in result.model.effects:
        for key in ("time_constant", "stiffness", "damping", "impedance", "friction"):
            if key in effect.values:
                true = float(declared[effect.name].values[key])
                assert abs(float(effect.values[key]) - true) <= 1e-3 * true, (key, effect.values)
    gains = result.model.params.cable_gain.numpy()
    assert np.allclose(gains, truth.params.cable_gain.numpy(), rtol=1e-3), gains
    assert result.final_test["rollout"] <= 0.01  # 1-s open-loop rollout [m]
    assert result.baseline_test["rollout"] >= 1.0  # without contact the prism falls through
