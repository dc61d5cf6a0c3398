"""The residual network: absorbs what no candidate explains, reported as unexplained."""

from __future__ import annotations

import json
from collections.abc import Iterator

import numpy as np
import pytest
import torch

from identification.discovery.library import FitSettings
from identification.discovery.loop import DiscoveryResult, EffectDiscovery
from identification.discovery.one_step import OneStepScorer
from identification.discovery.report import NETWORK_PARAMS, write_params, write_report
from identification.simulation.planted import PlantedData, PlantSpec
from tensegrity_env.effects import ResidualNetwork, effects_from_document
from tensegrity_env.effects.residual_network import ResidualMLP
from tensegrity_env.engine import Engine, State
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model
from tensegrity_env.params import load_params_document, params_from_dict
from tensegrity_env.topology import Topology

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def drag_run(mujoco_data) -> Iterator[tuple[PlantedData, DiscoveryResult]]:
    """Planted linear drag; the loop may only try cubic stiffness, which cannot explain it."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    data = mujoco_data.planted(
        PlantSpec("linear_drag", "moderate", seed=2, n_train=4, n_val=2, n_test=2, steps=500)
    )
    settings = FitSettings(anchors={"mass[rod0]": float(data.ground_truth.params.mass[0])})
    with np.errstate(invalid="ignore", divide="ignore"):
        loop = EffectDiscovery(OneStepScorer(settings, horizon_s=0.5), max_effects=1,
                               candidates=["cubic_stiffness"], log=lambda s: None)  # fmt: skip
        result = loop.fit(data.dataset).result_
    yield data, result
    torch.set_num_threads(n)


def test_network_absorbs_what_no_candidate_explains(drag_run):
    data, result = drag_run
    assert result.model.names == []  # the physical model names nothing, holds no network
    fit = result.residual_network
    assert fit is not None
    assert "residual network absorbs it" in result.unexplained
    assert "NOT a physical effect" in result.unexplained
    # measured 25.3x on the test split (2.79e-6 m -> 1.10e-7 m); 0.5-s rollout 16 cm -> 5.9 mm
    assert fit.gain("test") > 10 and fit.gain("val") > 10
    assert np.isfinite(fit.after["test"]["rollout"]) and fit.after["test"]["rollout"] < 0.05
    # what it absorbs is the drag the regression had folded into the masses: refitted
    # with it, they come back (measured within 1.4 %; the loop's are 62-78 % off)
    truth = data.ground_truth.params.mass.numpy()
    loop = np.abs(result.model.params.mass.numpy() / truth - 1)
    joint = np.abs(fit.params.mass.numpy() / truth - 1)
    assert loop.max() > 0.2 and joint.max() < 0.03
    assert isinstance(fit.effects[-1], ResidualNetwork) and fit.effect is fit.effects[-1]


def test_opt_out_only_says_structure_is_left(drag_run):
    data, _ = drag_run
    settings = FitSettings(anchors={"mass[rod0]": float(data.ground_truth.params.mass[0])})
    with np.errstate(invalid="ignore", divide="ignore"):
        scorer = OneStepScorer(settings, horizon_s=0.5, residual_network=False)
        loop = EffectDiscovery(scorer, max_effects=0, log=lambda s: None)
        result = loop.fit(data.dataset).result_
    assert result.residual_network is None
    assert "structure remains" in result.unexplained and "network" not in result.unexplained


def test_sidecar_and_params_load_back_into_the_engine(drag_run, tmp_path):
    data, result = drag_run
    fit = result.residual_network
    write_report(result, tmp_path, "drag")
    write_params(result, tmp_path / "params.json", {})
    report = (tmp_path / "report.md").read_text()
    assert "Residual network (unexplained: NOT a physical effect)" in report
    # params.json keeps the physical model and points at the network's files (read as
    # JSON: this drag-blind fit has an axial inertia <= 0, which Model.load refuses)
    doc = json.loads((tmp_path / "params.json").read_text())
    assert doc["effects"] == []
    assert doc["diagnose"]["residual_network"]["params_file"] == NETWORK_PARAMS
    assert np.allclose(doc["params"]["mass"], result.model.params.mass.numpy())
    # the network's own params file: refitted parameters, the network entry, the sidecar
    # (read without Model.load's checks: the refit inherits the drag-blind fit's
    # unphysical inertias, which Model.load refuses in one line)
    with pytest.raises(InputError, match="inertia"):
        Model.load(tmp_path / NETWORK_PARAMS, dt=data.dataset.dt)
    doc = load_params_document(tmp_path / NETWORK_PARAMS)
    topology = Topology.from_dict(doc["topology"])
    params = params_from_dict(doc["params"])
    entry = json.loads((tmp_path / NETWORK_PARAMS).read_text())["effects"][-1]
    assert entry["name"] == "residual_network" and entry["unexplained"] is True
    assert (tmp_path / entry["sidecar"]).is_file()
    with pytest.raises(InputError, match="not found"):
        effects_from_document(doc, topology, root=tmp_path / "elsewhere")
    loaded = effects_from_document(doc, topology, root=tmp_path)
    split = data.dataset.split("test")
    state = State(*(torch.as_tensor(getattr(split, k)[:, ::50].reshape(-1, *getattr(split, k).shape[2:]))
                    for k in ("p", "v", "q", "omega")))  # fmt: skip
    a0 = Engine(topology, data.dataset.dt, effects=fit.effects).accelerations(state, fit.params)
    a1 = Engine(topology, data.dataset.dt, effects=loaded).accelerations(state, params)
    for x, y in zip(a0, a1, strict=True):
        assert torch.allclose(x, y, rtol=1e-12, atol=1e-12)
    # the network is not negligible in them: it moves accelerations by metres per s^2
    a2 = Engine(topology, data.dataset.dt, effects=loaded[:-1]).accelerations(state, params)
    assert float((a1[0] - a2[0]).abs().max()) > 0.1


def test_readout_is_linear_basis_times_theta(ico_state):
    topology, state, kin = ico_state
    torch.manual_seed(0)
    net = ResidualMLP((16, 16))
    with torch.no_grad():
        net.out_scale.copy_(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3], dtype=torch.float64))
    effect = ResidualNetwork(topology, net)
    force, torque = effect.wrench(state, kin, None)
    bf, bt = effect.basis(state, kin, None)
    theta = effect.theta()
    assert torch.allclose(bf @ theta, force, atol=1e-12)
    assert torch.allclose(bt @ theta, torque, atol=1e-12)
    doubled = effect.with_theta(2 * theta)
    assert torch.allclose(doubled.wrench(state, kin, None)[0], 2 * force, atol=1e-12)
    assert "NOT a physical effect" in effect.describe()


@pytest.fixture
def ico_state():
    from tensegrity_env import assemblies
    from tensegrity_env.engine.kinematics import node_kinematics

    ico = assemblies.icosahedron()
    topology = ico.topology
    rng = np.random.default_rng(0)
    R = topology.n_rods
    q = rng.normal(size=(3, R, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    state = State(
        torch.as_tensor(rng.normal(size=(3, R, 3))),
        torch.as_tensor(rng.normal(size=(3, R, 3))),
        torch.as_tensor(q),
        torch.as_tensor(rng.normal(size=(3, R, 3))),
    )
    kin = node_kinematics(
        state,
        torch.as_tensor(topology.end_offsets, dtype=torch.float64),
        torch.as_tensor(topology.anchor_positions, dtype=torch.float64),
    )
    return topology, state, kin
