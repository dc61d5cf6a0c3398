"""Drawn floor plants (``benchmarks/plant_family.py``): what the floor fit takes from the
data and the start model holds whatever the plant's conventions and proportions.

Seed 9 on the floor: 1.9 m rods at 60 Hz with 0.13 mm of noise, sphere end caps, body
frames off the centre of mass on three rods, the axial moment of inertia 1-5 % of the
perpendicular one (end-cap housings), not a solid rod's ``M r^2 / 2``.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import measure
from plant_family import draw, family_initial_states, simulate_family, truth_of

from identification.data.end_caps import RodAxes
from identification.trajectory.identifier import TrajectoryIdentifier
from identification.trajectory.param_vector import ParamVector, params_values
from identification.trajectory.stage_check import noise_level
from tensegrity_env.engine import Engine, State, substeps_for
from tensegrity_env.mjcf.reader import from_mjcf

SEED = 9


@pytest.fixture(scope="module")
def plant():
    d = draw(SEED, "floor")
    truth, topo = truth_of(d)
    init = family_initial_states(d, 2, np.random.default_rng([SEED, 64, 0, 3]))
    clean = simulate_family(d, truth.xml, init, 1.0)
    return d, truth, topo, clean


def test_the_start_models_axial_inertia_is_kept(plant) -> None:
    """The fit's vector holds each rod's axial moment from the start model: friction
    at an end cap spins a rod about its axis at a rate set by that moment."""
    d, truth, topo, clean = plant
    inertia = truth.params.numpy()["inertia"]
    axes = RodAxes.of(topo)
    assumed = truth.params.numpy()["mass"] * axes.radius**2 / 2
    axial = inertia[np.arange(topo.n_rods), axes.axis]
    assert (axial > 3 * assumed).all()  # the plant is no solid rod
    vec = ParamVector.at(topo, truth.params)
    np.testing.assert_allclose(vec.params(vec.start).numpy()["inertia"], inertia, rtol=1e-12)
    anchor = {("mass", 0): float(truth.params.numpy()["mass"][0])}
    start = TrajectoryIdentifier().start_vector(topo, axes, params_values(truth.params, axes),
                                                anchor, False)  # fmt: skip
    got = start.params(start.full(start.theta0())).numpy()["inertia"]
    np.testing.assert_allclose(got, inertia, rtol=1e-12)
    # the engine at the vector's values reproduces MuJoCo on the floor
    effects = from_mjcf("family.xml", xml=truth.xml).declared_effects()
    engine = Engine(topo, 1 / d.rate, effects, substeps=substeps_for(1 / d.rate))
    state = State(*(torch.as_tensor(getattr(clean, k)[:, 0]) for k in ("p", "v", "q", "omega")))
    with torch.no_grad():
        roll = engine.rollout(state, vec.params(vec.start), clean.n_transitions)
    assert np.abs(roll.p.numpy() - clean.p).max() < 1e-9
    # with a solid rod's axial moment it would not
    solid = replace(vec, axial=None)
    with torch.no_grad():
        other = engine.rollout(state, solid.params(solid.start), clean.n_transitions)
    assert np.abs(other.p.numpy() - clean.p).max() > 1e-4


def test_the_noise_level_comes_from_the_rigid_rods_lengths(plant) -> None:
    """At 60 Hz a tumbling 1.9 m structure's third differences are motion, not noise;
    the spread of each rod's measured length is noise alone."""
    d, _, _, clean = plant
    seen = measure(clean.nodes, d.cell, np.random.default_rng(1), fill=False)
    assert np.isnan(seen).any()  # gaps
    assert noise_level(seen, rods=True) == pytest.approx(d.noise, rel=0.1)
    assert noise_level(seen) > 3 * d.noise  # third differences read the motion
    assert noise_level(clean.nodes, rods=True) < 1e-9
