"""The measured benchmark's own MuJoCo plant: the engine with the true model reproduces it."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import Cell, initial_states, measure, simulate, true_model

from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import ForceField, GroundContact
from tensegrity_env.engine import Engine, State, substeps_for


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
