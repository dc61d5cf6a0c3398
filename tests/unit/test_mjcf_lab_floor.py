"""The lab-style prism rocking on a floor with the file's contact: the residual loop
names ground contact from the data alone and recovers what the file says."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_mjcf_lab import lab_mjcf

from identification.discovery.library import FitSettings
from identification.discovery.loop import EffectDiscovery
from identification.discovery.one_step import OneStepScorer
from identification.simulation.generate import GenerateSpec, generate_dataset

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_diagnose_names_the_files_floor_contact(tmp_path: Path) -> None:
    path = tmp_path / "lab.xml"
    path.write_text(lab_mjcf("surface", floor=True, friction=0.9, floor_attrs='solref="-5000 -50"'))
    spec = GenerateSpec(mjcf=str(path), n_train=8, n_val=2, n_test=2, steps=1000, seed=11)
    ds, truth = generate_dataset(spec)
    (planted,) = truth.effects
    settings = FitSettings(anchors={"mass[r0]": float(truth.params.mass[0])})
    with np.errstate(invalid="ignore", divide="ignore"):
        loop = EffectDiscovery(OneStepScorer(settings, horizon_s=1.0), 2,
                               ["ground_contact", "force_field", "linear_drag"], log=lambda s: None)  # fmt: skip
        result = loop.fit(ds).result_
    assert result.model.names == ["ground_contact"]  # not a force field holding the rods up
    contact = result.model.effects[0]
    for key in ("stiffness", "damping", "friction", "impedance"):
        true = planted["params"][key]
        assert abs(float(contact.values[key]) - true) <= 0.01 * true, (key, contact.values[key])
    errors = group_errors_of(result.model.params, truth.params)
    assert max(errors.values()) <= 0.01, errors
    assert result.final_test["rollout"] <= 0.01  # 1-s open-loop rollout [m]
    assert result.baseline_test["rollout"] >= 1.0  # without contact the prism falls through


def group_errors_of(fitted, true) -> dict[str, float]:
    """Largest relative error per parameter group of ``fitted`` against ``true``."""
    out = {}
    for key in ("mass", "inertia", "stiffness", "damping", "rest_length"):
        a, b = getattr(fitted, key).numpy(), getattr(true, key).numpy()
        out[key] = float(np.max(np.abs(a - b) / np.abs(b)))
    return out


def test_a_robot_mjcf_declares_its_floor_contact(tmp_path: Path) -> None:
    """``Model.read`` (diagnose's ``--params``) takes the file's contact as declared."""
    from tensegrity_env.model import Model

    path = tmp_path / "lab.xml"
    path.write_text(lab_mjcf("surface", floor=True, friction=0.7, floor_attrs='solref="-5000 -50"'))
    model = Model.read(path)
    assert [e.name for e in model.effects] == ["ground_contact"]
    contact = model.effects[0]
    assert float(contact.values["friction"]) == 0.7
    assert float(contact.values["stiffness"]) == pytest.approx(5000 / 0.95**2, rel=1e-12)
    bare = tmp_path / "bare.xml"
    bare.write_text(lab_mjcf("surface"))
    assert not Model.read(bare).effects
