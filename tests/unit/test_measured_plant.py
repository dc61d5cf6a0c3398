"""The measured benchmark's own MuJoCo plant: the engine with the true model reproduces it."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import Cell, initial_states, measure, simulate, true_model

from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import ForceField, GroundContact, SlackSprings
from tensegrity_env.engine import Engine, State, substeps_for
from tensegrity_env.model import Model
from tensegrity_env.rotations import quat_to_matrix


def _rollout_error(cell: Cell, effects: list, duration: float) -> float:
    truth = true_model(cell)
    init = initial_states(cell, 2, np.random.default_rng(0))
    clean = simulate(cell, truth, init, duration)
    dt = 1.0 / cell.rate  # one engine step per sample, substepping at <= 1 ms
    engine = Engine(icosahedron().topology, dt, effects, substeps=substeps_for(dt))
    state = State(*(torch.as_tensor(init[k]) for k in ("p", "v", "q", "omega")))
    with torch.no_grad():
        roll = engine.rollout(state, truth.params, clean.n_transitions)
    return float(np.abs(roll.p.numpy() - clean.p).max())


def test_engine_reproduces_the_plant_in_flight_with_a_force_field():
    topo = icosahedron().topology
    field = ForceField(topo, force=[0.4, -0.3, 0.5])
    cell = Cell("flight", 120.0, 0.0, 0.0, "force_field")
    assert cell.substeps == 9
    assert _rollout_error(cell, [field], 0.5) < 1e-10
    # the force is really there: without it the model drifts by centimetres
    assert _rollout_error(cell, [], 0.5) > 1e-2


def test_true_model_at_120_hz_sample_spacing_reproduces_one_second_of_flight():
    cell = Cell("flight", 120.0, 0.0, 0.0, "none")
    assert substeps_for(1 / 120) == cell.substeps == 9
    assert _rollout_error(cell, [], 1.0) <= 1e-6
    # one engine step per 8.33 ms sample, as without substeps, is millimetres off
    truth, init = true_model(cell), initial_states(cell, 2, np.random.default_rng(0))
    clean = simulate(cell, truth, init, 1.0)
    coarse = Engine(icosahedron().topology, 1 / 120)
    state = State(*(torch.as_tensor(init[k]) for k in ("p", "v", "q", "omega")))
    with torch.no_grad():
        roll = coarse.rollout(state, truth.params, clean.n_transitions)
    assert np.abs(roll.p.numpy() - clean.p).max() > 1e-3


def test_a_model_at_the_sample_interval_steps_at_its_physics_step():
    """``Model.engine`` substeps a 120 Hz model at <= 1 ms: it reproduces the plant as the
    engine built with :func:`substeps_for` does; asked for one step per sample, it does not."""
    cell = Cell("flight", 120.0, 0.0, 0.0, "none")
    truth, init = true_model(cell), initial_states(cell, 2, np.random.default_rng(0))
    clean = simulate(cell, truth, init, 1.0)
    model = Model(icosahedron().topology, truth.params, [], 1 / 120)
    state = State(*(torch.as_tensor(init[k]) for k in ("p", "v", "q", "omega")))
    errors = []
    for engine in (model.engine(), model.engine(physics_dt=1 / 120)):
        with torch.no_grad():
            roll = engine.rollout(state, truth.params, clean.n_transitions)
        errors.append(np.abs(roll.p.numpy() - clean.p).max())
    assert model.engine().substeps == 9
    assert errors[0] <= 1e-6 < 1e-3 < errors[1]


def test_slack_cables_go_slack_in_flight_and_the_true_model_follows_them():
    """The planted cables (rest length the nominal length) are slack in a real share of
    the samples, and the engine with them as tension-only springs follows the plant."""
    cell = Cell("flight", 120.0, 0.0, 0.0, "slack_cables")
    truth = true_model(cell)
    topo = icosahedron().topology
    cables = truth.effects[0]["params"]["springs"]
    init = initial_states(cell, 4, np.random.default_rng(0))
    clean = simulate(cell, truth, init, 0.6)
    a = [s.node_a for s in topo.springs]
    b = [s.node_b for s in topo.springs]
    length = np.linalg.norm(clean.nodes[:, :, a] - clean.nodes[:, :, b], axis=-1)
    slack = (length[..., cables] < truth.params.numpy()["rest_length"][cables]).mean(axis=(0, 1))
    assert len(cables) == 12 and slack.min() > 0.01 and slack.mean() > 0.05, slack
    assert _rollout_error(cell, [SlackSprings(topo, springs=cables)], 0.6) < 1e-9
    assert _rollout_error(cell, [], 0.6) > 1e-3  # the cables' slack is visible


def test_engine_reproduces_the_plant_on_the_floor():
    cell = Cell("floor", 1000.0, 0.0, 0.0, "none")
    assert _rollout_error(cell, [GroundContact(icosahedron().topology)], 0.5) < 1e-9


def test_measurement_noise_and_dropouts():
    cell = Cell("flight", 120.0, 1e-3, 0.02, "none")
    nodes = np.zeros((4, 301, 12, 3))
    seen = measure(nodes, cell, np.random.default_rng(1))
    assert abs(seen.std() / 1e-3 - 1.0) < 0.05
    # gaps are filled by interpolation: their values lie between their neighbours
    # and are no longer independent draws, so some consecutive samples fall on lines
    second = np.abs(seen[:, 2:] - 2 * seen[:, 1:-1] + seen[:, :-2]).max(axis=-1)
    filled = (second < 1e-12).mean()
    assert 0.018 < filled < 0.022


def test_drops_start_at_rest_and_the_true_model_follows_them(tmp_path):
    """The floor cells' checks: the plant's drops from rest and its rolling test
    trajectories, followed to round-off by the engine with the true model and MuJoCo's
    default contact at the plant's physics step; its end caps and rod states are of the
    same instant."""
    from measured_plant import drop_states, write_cell
    from measured_report import DROP_SECONDS, drop_error, rollout_error

    from tensegrity_env.model import Model

    init = drop_states(3, np.random.default_rng(0))
    assert not init["v"].any() and not init["omega"].any()
    topo = icosahedron().topology
    offsets = topo.end_offsets
    caps = init["p"][:, :, None] + np.einsum(
        "nrij,rkj->nrki", quat_to_matrix(torch.as_tensor(init["q"])).numpy(), offsets
    )
    low = caps[..., 2].reshape(3, -1).min(axis=1) - topo.rods[0].radius
    assert np.all((low > 0.1 - 1e-9) & (low < 0.5 + 1e-9))
    cell = Cell("floor", 120.0, 0.0, 0.0, "none")
    data = write_cell(cell, tmp_path / "cell")
    path = tmp_path / "true.json"
    Model(topo, data.truth.params, [GroundContact(topo, friction=1.0, height=0.0)]).save(path, {})
    doc = json.loads(path.read_text())
    drop = drop_error(data, doc, path)
    assert drop["seconds"] == DROP_SECONDS and drop["worst"] < 1e-8, drop
    assert rollout_error(data, doc, path)["worst"] < 1e-8
    # without the floor the model falls through it: the check sees it
    bare = tmp_path / "bare.json"
    Model(topo, data.truth.params).save(bare, {})
    assert drop_error(data, json.loads(bare.read_text()), bare)["worst"] > 0.1
