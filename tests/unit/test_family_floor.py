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

from identification.data.end_caps import RodAxes, odd_window, smooth_rod_states
from identification.trajectory.identifier import TrajectoryIdentifier
from identification.trajectory.param_vector import ParamVector, params_values
from identification.trajectory.stage_check import noise_level
from identification.trajectory.touchdown import Touchdowns, touchdown_residual
from identification.trajectory.window_states import forward_seeds
from identification.trajectory.windows import STATE_KEYS, cut_windows
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
    """The fit's vector holds each rod's axial moment from the start model, else the
    robot file's: friction at an end cap spins a rod about its axis at a rate set by
    that moment, which end caps cannot show."""
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
    # without a start model the vector takes the robot file's axial moment per unit mass
    mass = truth.params.numpy()["mass"]
    np.testing.assert_allclose(topo.axial_gyrations * mass, axial, rtol=1e-9)
    filed = replace(vec, axial=None)
    np.testing.assert_allclose(filed.params(filed.start).numpy()["inertia"], inertia, rtol=1e-9)
    # with a solid rod's axial moment it would not reproduce MuJoCo
    solid = replace(vec, axial=torch.as_tensor(axes.radius**2 / 2))
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


def test_a_windows_first_samples_seed_a_drop_from_rest(plant) -> None:
    """A release from rest at a trajectory's first sample (the prestressed springs
    accelerate the light rods to 7 m/s within a sample): the smoothing filter there
    extrapolates, the window's own first samples read it better."""
    d, _, topo, clean = plant
    assert np.abs(clean.v[:, 0]).max() == 0  # seed 9's first two starts are from rest
    seen = measure(clean.nodes, d.cell, np.random.default_rng(1), fill=False)
    axes = RodAxes.of(topo)
    dt = 1 / d.rate
    smooth = smooth_rod_states(seen, dt, axes, odd_window(0.1 / dt))
    grid = {k: getattr(smooth, k) for k in STATE_KEYS}
    windows = cut_windows(seen, np.zeros((*seen.shape[:2], topo.n_rods, 3))[:, 1:], grid, 4)
    first = windows.take(np.flatnonzero(windows.start == 0))
    fresh = forward_seeds(first, axes, dt)
    err = lambda s: float((s.v - torch.as_tensor(clean.v[first.traj, 0])).norm(dim=-1).max())  # noqa: E731
    assert err(fresh.state) < 0.6 * err(first.state)  # m/s
    np.testing.assert_allclose(fresh.state.p.numpy(), clean.p[first.traj, 0], atol=2e-3)


def test_gaps_count_in_no_residual_of_the_contact_search(plant) -> None:
    d, truth, topo, clean = plant
    seen = measure(clean.nodes, d.cell, np.random.default_rng(1), fill=False)
    state = State(*(torch.as_tensor(getattr(clean, k)[:, 0]) for k in ("p", "v", "q", "omega")))
    contact = from_mjcf("family.xml", xml=truth.xml).declared_effects()[0]
    engine = Engine(topo, 1 / d.rate, substeps=substeps_for(1 / d.rate))
    obs = torch.as_tensor(seen[:, :31])
    valid = torch.isfinite(obs).all(-1)
    assert not bool(valid.all())
    touch = Touchdowns(state=state, obs=torch.nan_to_num(obs), control=None,
                       traj=np.arange(2), first=np.zeros(2, int), prefix_rms=float("nan"),
                       valid=valid)  # fmt: skip
    r = touchdown_residual(engine, truth.params, [], contact, touch, 30)
    assert bool((r[~valid] == 0).all())
    rms = float(torch.sqrt((r**2).sum() / (3 * valid.sum())))
    assert rms == pytest.approx(d.noise, rel=0.15)  # the true model at the true states: noise
