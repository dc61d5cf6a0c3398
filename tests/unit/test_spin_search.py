"""Axial spins of rods rolling on a floor: end caps do not show them, a search finds them.

Seed 10 on the floor: 0.68 m rods with sphere end caps that roll on the floor, spinning
about their axes far faster than the structure tumbles.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from plant_family import draw, family_initial_states, simulate_family, truth_of

from identification.trajectory.param_vector import ParamVector
from identification.trajectory.window_states import SPIN_STEPS, prefix, search_spins
from identification.trajectory.windows import Windows, end_caps
from tensegrity_env.engine import Engine, State, substeps_for
from tensegrity_env.mjcf.reader import from_mjcf
from tensegrity_env.rotations import quat_to_matrix

SEED = 10


@pytest.fixture(scope="module")
def rolling():
    """Noise-free windows of the plant with true states, every 5th sample from 0.5 s on."""
    d = draw(SEED, "floor")
    truth, topo = truth_of(d)
    init = family_initial_states(d, 2, np.random.default_rng([SEED, 64, 0, 3]))
    clean = simulate_family(d, truth.xml, init, 1.0)
    effects = from_mjcf("family.xml", xml=truth.xml).declared_effects()
    engine = Engine(topo, 1 / d.rate, effects, substeps=substeps_for(1 / d.rate))
    vec = ParamVector.at(topo, truth.params)
    traj, start = np.meshgrid(np.arange(2), np.arange(100, 180, 5), indexing="ij")
    traj, start = traj.ravel(), start.ravel()
    W = SPIN_STEPS
    obs = np.stack([clean.nodes[t, s : s + W + 1] for t, s in zip(traj, start, strict=True)])
    keys = ("p", "v", "q", "omega")
    state = State(*(torch.as_tensor(getattr(clean, k)[traj, start]) for k in keys))
    return engine, vec, Windows(torch.as_tensor(obs), None, state, traj, start)


def axial(vec: ParamVector, state: State) -> tuple[torch.Tensor, torch.Tensor]:
    """Each rod's axis in the world (B, R, 3) and its spin about it (B, R) [rad/s]."""
    rot = quat_to_matrix(state.q)
    a = torch.stack([rot[:, r, :, int(k)] for r, k in enumerate(vec.axes.axis)], 1)
    return a, (a * state.omega).sum(-1)


def errors(engine: Engine, vec: ParamVector, windows: Windows) -> torch.Tensor:
    """Each window's sum of squared end-cap errors over its first steps (B,) [m^2]."""
    w = prefix(windows, SPIN_STEPS)
    with torch.no_grad():
        out = engine.rollout(w.state, vec.params(vec.start), w.steps)
    return (end_caps(engine, out.p, out.q) - w.obs).pow(2).sum(dim=(1, 2, 3))


def test_a_search_finds_the_spins_of_rods_rolling_on_the_floor(rolling) -> None:
    engine, vec, windows = rolling
    a, spin = axial(vec, windows.state)
    fast = spin.abs() > 5.0  # rad/s: rods spinning about their axes
    assert float(fast.float().mean()) > 0.3
    # what smoothing reads from end caps: no spin about the axis
    seen = State(windows.state.p, windows.state.v, windows.state.q,
                 windows.state.omega - a * spin[..., None])  # fmt: skip
    start = replace(windows, state=seen)
    found = search_spins(engine, vec, start)
    before, after = errors(engine, vec, start), errors(engine, vec, found)
    assert bool((after <= before).all())  # the spin as it was is among those tried
    assert float(after.sum()) < 0.2 * float(before.sum())
    # the fast spins found are nearer the true ones than none is
    off = (axial(vec, found.state)[1] - spin)[fast].abs()
    assert float(off.median()) < 0.5 * float(spin[fast].abs().median())
    # and nothing but the spins moved
    for k in ("p", "v", "q"):
        torch.testing.assert_close(getattr(found.state, k), getattr(seen, k))
