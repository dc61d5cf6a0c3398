"""What end caps on a floor show: rest, motion along the floor and impacts, from noisy caps."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import Cell, drop_states, measure, simulate, true_model

from identification.trajectory.floor_evidence import (
    FRICTION_SHARE,
    REST_S,
    floor_evidence,
)
from tensegrity_env.assemblies import icosahedron

RATE = 120.0


def _standing(seconds: float, speed: float, noise: float, seed: int = 0) -> np.ndarray:
    """The icosahedron's end caps (1, T+1, 12, 3) [m] with its lowest caps on the floor,
    moving along x at ``speed`` [m/s], with ``noise`` [m] of Gaussian noise."""
    a = icosahedron()
    nodes = a.node_positions().copy()
    nodes[:, 2] += a.topology.rods[0].radius - nodes[:, 2].min()
    t = np.arange(round(seconds * RATE) + 1) / RATE
    caps = np.repeat(nodes[None, None], t.size, axis=1)
    caps[..., 0] += speed * t[None, :, None]
    return caps + noise * np.random.default_rng(seed).standard_normal(caps.shape)


def test_a_structure_at_rest_shows_static_equilibrium_but_not_friction_or_damping():
    ev = floor_evidence(_standing(2.0, 0.0, 0.001), 1 / RATE, icosahedron().topology)
    assert ev.touching_share == 1.0
    assert ev.rest_s > 2.0 - 2 * REST_S  # the smoothing filter's ends aside
    assert ev.moving_share < FRICTION_SHARE and ev.impacts == 0
    assert set(ev.unseen()) == {"friction", "damping"}
    assert "ground_contact.friction" in ev.markdown()


def test_sliding_end_caps_show_friction_and_no_rest():
    ev = floor_evidence(_standing(2.0, 0.3, 0.001), 1 / RATE, icosahedron().topology)
    assert ev.moving_share > 0.95 and ev.rest_s == 0.0
    assert "friction" not in ev.unseen()


def test_drops_on_the_mujoco_plant_show_impacts_and_rolling():
    """Independent MuJoCo data: the benchmark plant's icosahedron dropped from 0.1-0.5 m
    lands (each drop brings at least two end caps down onto the floor) and rolls."""
    cell = Cell("floor", RATE, 0.001, 0.0, "none", seed=3)
    rng = np.random.default_rng(3)
    clean = simulate(cell, true_model(cell), drop_states(2, rng), 2.0)
    ev = floor_evidence(measure(clean.nodes, cell, rng), 1 / RATE, icosahedron().topology)
    assert ev.impacts >= 4
    assert ev.moving_share > 0.3 and ev.touching_share > 0.7
    assert ev.unseen() == {}


def test_gaps_are_skipped_and_no_floor_contact_sees_nothing():
    caps = _standing(1.0, 0.0, 0.001)
    caps[:, 40:60, 3] = np.nan
    assert floor_evidence(caps, 1 / RATE, icosahedron().topology).touching_share > 0.9
    caps[..., 2] += 1.0  # a metre above the floor throughout
    ev = floor_evidence(caps, 1 / RATE, icosahedron().topology)
    assert ev.touching_share == 0.0 and ev.impacts == 0
    assert set(ev.unseen()) == {"stiffness", "damping", "impedance", "friction"}
