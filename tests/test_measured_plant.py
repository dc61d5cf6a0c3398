"""The measured benchmark's own MuJoCo plant: the engine with the true model reproduces it."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from measured_plant import Cell, initial_states, measure, simulate, true_model

from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import ForceField, GroundContact
from tensegrity_env.engine import Engine, State


def _rollout_error(cell: Cell, effects: list, duration: float) -> float:
    truth = true_model(cell)
    init = initial_states(cell, 2, np.random.default_rng(0))
    clean = simulate(cell, truth, init, duration)
    engine = Engine(icosahedron().topology, 1.0 / cell.rate / cell.substeps, effects)
    state = State(*(torch.as_tensor(init[k]) for k in ("p", "v", "q", "omega")))
    worst = 0.0
    with torch.no_grad():
        for t in range(1, clean.n_transitions + 1):
            for _ in range(cell.substeps):
                state = engine.step(state, truth.params)
            worst = max(worst, float(np.abs(state.p.numpy() - clean.p[:, t]).max()))
    return worst


def test_engine_reproduces_the_plant_in_flight_with_a_force_field():
    topo = icosahedron().topology
    field = ForceField(topo, force=[0.4, -0.3, 0.5])
    cell = Cell("flight", 120.0, 0.0, 0.0, "force_field")
    assert cell.substeps == 9
    assert _rollout_error(cell, [field], 0.5) < 1e-10
    # the force is really there: without it the model drifts by centimetres
    assert _rollout_error(cell, [], 0.5) > 1e-2


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
