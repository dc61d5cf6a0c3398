"""The residual loop on data with undeclared effects (not only the ones it was tuned on)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identification.discovery.library import FitSettings, Proposal
from identification.discovery.loop import EffectDiscovery
from identification.discovery.one_step import OneStepScorer
from identification.discovery.residuals import compute_residuals, summarize
from identification.linear.extended import ExtendedIdentifier
from identification.simulation.planted import PlantSpec
from tensegrity_env.effects import SlackSprings
from tensegrity_env.model import Model
from tensegrity_sr.cli import main as cli

SMALL = {"n_train": 4, "n_val": 2, "n_test": 2, "steps": 500}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def run(mujoco_data, spec: PlantSpec, horizon: float = 0.5, candidates=None, max_effects: int = 2):
    data = mujoco_data.planted(spec)
    settings = FitSettings(anchors={"mass[rod0]": float(data.ground_truth.params.mass[0])},
                           contact_windows=((1, 600),))  # fmt: skip
    with np.errstate(invalid="ignore", divide="ignore"):
        loop = EffectDiscovery(OneStepScorer(settings, horizon_s=horizon), max_effects,
                               candidates, log=lambda s: None)  # fmt: skip
        result = loop.fit(data.dataset).result_
    return data, result


def improvement(result) -> tuple[float, float]:
    b, f = result.baseline_test, result.final_test
    roll_before = b["rollout"] if np.isfinite(b["rollout"]) else np.inf
    return b["one_step"] / f["one_step"], roll_before / f["rollout"]


def test_clean_data_adds_nothing(mujoco_data):
    _, result = run(mujoco_data, PlantSpec("none", seed=3, **SMALL))
    assert result.model.effects == []
    assert all(it.chosen is None for it in result.iterations)
    assert result.unexplained == ""


@pytest.mark.parametrize(("strength", "seed"), [("weak", 1), ("strong", 2)])
def test_quadratic_drag_is_named(mujoco_data, strength, seed):
    _, result = run(mujoco_data, PlantSpec("quadratic_drag", strength, seed=seed, **SMALL),
                    candidates=["linear_drag", "quadratic_drag", "force_field"])  # fmt: skip
    assert result.model.names == ["quadratic_drag"]
    one, roll = improvement(result)
    assert one >= 100 and roll >= 10
    drag = result.model.effects[0].values["translational"].numpy()
    assert drag[0] > 10 * drag[2]  # a rod drags far less along its axis


def test_slack_cables_are_found(mujoco_data):
    data, result = run(mujoco_data, PlantSpec("slack_springs", 6, seed=4, **SMALL),
                       candidates=["slack_springs", "linear_drag", "force_field"])  # fmt: skip
    assert result.model.names == ["slack_springs"]
    found = sorted(result.model.effects[0].values["springs"].tolist())
    assert found == data.ground_truth.effects[0]["params"]["springs"]
    one, roll = improvement(result)
    assert one >= 100 and roll >= 10


def test_ground_contact_is_named_and_identified(mujoco_data):
    _, result = run(mujoco_data, PlantSpec("ground_contact", 2.0, seed=5, **SMALL),
                    candidates=["ground_contact", "quadratic_drag", "force_field"], max_effects=1)  # fmt: skip
    assert result.model.names == ["ground_contact"]
    contact = result.model.effects[0]
    assert abs(float(contact.values["friction"]) - 2.0) < 0.01
    one, roll = improvement(result)
    assert one >= 100 and roll >= 10


def test_residuals_point_at_the_springs_that_go_slack(mujoco_data):
    data = mujoco_data.planted(PlantSpec("slack_springs", "strong", seed=6, **SMALL))
    est = ExtendedIdentifier(anchors={"mass[rod0]": 2.0}).fit(data.dataset)
    res = compute_residuals(
        data.dataset.topology, est.params_, [], data.dataset, max_transitions=3000
    )
    s = summarize(res)
    assert s["rms_force"] > 0.1 and res.tension.shape == res.stretch.shape
    clean = compute_residuals(data.dataset.topology, data.ground_truth.params,
                              [_true_slack(data)], data.dataset, max_transitions=3000)  # fmt: skip
    assert summarize(clean)["rms_force"] < 1e-9


def _true_slack(data):
    return SlackSprings(
        data.dataset.topology, springs=data.ground_truth.effects[0]["params"]["springs"]
    )


def test_cli_writes_report_and_params_the_engine_loads(tmp_path):
    path = tmp_path / "drag.h5"
    assert cli(["plant", "linear_drag", "--strength", "1.0", "--seed", "8", "--n-train", "3",
                "--n-val", "2", "--n-test", "2", "--steps", "300", "-o", str(path)]) == 0  # fmt: skip
    out = tmp_path / "out"
    assert cli(["diagnose", str(path), "--anchor", "mass[rod0]=2.0", "--max-effects", "1",
                "--candidates", "linear_drag,quadratic_drag", "--horizon", "0.2", "-o", str(out)]) == 0  # fmt: skip
    report = (out / "report.md").read_text()
    assert "Added: linear_drag" in report and "residuals_0.png" in report
    assert (out / "residuals_0.png").stat().st_size > 10_000
    assert "(rollout.png)" in report and (out / "rollout.png").stat().st_size > 10_000
    model = Model.load(out / "params.json")
    assert model.effect_names == ["linear_drag"]
    doc = json.loads((out / "params.json").read_text())
    assert doc["diagnose"]["added"] == ["linear_drag"]
    model.engine()  # runs the extended model
    # standard errors of the declared parameters: every fitted one, none exactly 0
    uncertainty = doc["uncertainty"]
    springs = {f"stiffness[{s.name}]" for s in model.topology.springs}
    assert springs <= set(uncertainty) and "mass[rod0]" not in uncertainty  # the anchor
    assert all(0 < v < np.inf for v in uncertainty.values()), uncertainty


# ---------------------------------------------------------------------- thorough
CASES = [("ground_contact", s, seed) for s in ("weak", "moderate", "strong") for seed in (0, 1)] + [
    (e, s, seed)
    for e in ("quadratic_drag", "linear_drag", "slack_springs")
    for s in ("weak", "moderate", "strong")
    for seed in (0, 1)
]


@pytest.mark.slow
@pytest.mark.parametrize(("effect", "strength", "seed"), CASES)
def test_planted_effects_full(mujoco_data, effect, strength, seed):
    spec = PlantSpec(effect, strength, seed=seed, n_train=8, n_val=4, n_test=4, steps=1000)
    _, result = run(mujoco_data, spec, horizon=1.0, max_effects=2)
    assert result.model.names == [effect]
    one, roll = improvement(result)
    assert one >= 100 and roll >= 10


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_control_full(mujoco_data, seed):
    _, result = run(
        mujoco_data, PlantSpec("none", seed=seed, n_train=8, n_val=4, n_test=4, steps=1000), 1.0
    )
    assert result.model.effects == []


def test_indistinguishable_candidates_are_flagged(mujoco_data, monkeypatch):
    """Two candidates that predict the same change: the attribution is flagged, with the correlation."""
    from tensegrity_env.effects import QuadraticDrag

    def twins(self, current, names=None):
        if current.model.effects:
            return []
        topo = self.dataset.topology
        return [Proposal("quadratic_drag", QuadraticDrag(topo), "twin a"),
                Proposal("quadratic_drag_again", QuadraticDrag(topo), "twin b")]  # fmt: skip

    monkeypatch.setattr(OneStepScorer, "propose", twins)
    _, result = run(
        mujoco_data, PlantSpec("quadratic_drag", "moderate", seed=9, **SMALL), max_effects=1
    )
    it = result.iterations[0]
    assert it.chosen is not None and it.ambiguous is not None
    assert it.ambiguous[1] > 0.99
