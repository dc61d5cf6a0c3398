"""Window states with the rods' roll: what quadratic drag sees and end caps do not.

A rod's roll about its own axis leaves its end caps in place, so fits through end caps
leave it out, unless an effect depends on it (``sees_roll``): MuJoCo's box drag, which
:class:`QuadraticDrag` mirrors, acts per axis of the rod's box.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from identification.data.end_caps import RodAxes
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.window_states import fit_states
from identification.trajectory.windows import Windows, end_caps, local_basis, sees_roll
from tensegrity_env.assemblies import Assembly, icosahedron
from tensegrity_env.effects import LinearDrag, QuadraticDrag
from tensegrity_env.engine import Engine
from tensegrity_env.engine.state import State
from tensegrity_env.rotations import quat_mul, quat_to_matrix

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_basis_gains_one_roll_per_rod_and_only_quadratic_drag_asks_for_it() -> None:
    a = icosahedron()
    axes = RodAxes.of(a.topology)
    R = a.topology.n_rods
    assert (
        local_basis(axes, spin=False, roll=True).shape[0] == local_basis(axes, False).shape[0] + R
    )
    e = Engine(a.topology, 1e-3)
    assert not sees_roll(e)
    assert not sees_roll(e.with_effects([LinearDrag(a.topology, translational=[1, 1, 0.1])]))
    assert sees_roll(e.with_effects([QuadraticDrag(a.topology, translational=[1, 1, 0.1])]))


def _quad_drag_engine() -> tuple[Assembly, ParamVector, Engine]:
    """The icosahedron, its parameter vector at the nominal values and an engine with
    MuJoCo-sized box drag (1 ms step)."""
    a = icosahedron()
    drag = QuadraticDrag(a.topology, translational=[1.44, 1.44, 0.04],
                         rotational=[0.05, 0.05, 0.0])  # fmt: skip
    engine = Engine(a.topology, 1e-3, effects=[drag], native=True)  # the C kernel: same physics
    return a, ParamVector.at(a.topology, a.params), engine


def _rolled(q: torch.Tensor, angle: torch.Tensor, axis: np.ndarray) -> torch.Tensor:
    """Orientations q (B, R, 4) turned by angle (B, R) [rad] about each rod's own axis."""
    half = torch.zeros(*angle.shape, 4, dtype=torch.float64)
    half[..., 0] = torch.cos(angle / 2)
    for r in range(angle.shape[1]):
        half[:, r, 1 + axis[r]] = torch.sin(angle / 2)[:, r]
    return quat_mul(q, half)


def test_rolls_are_recovered_under_quadratic_drag() -> None:
    """Clean end caps of rolled rods (0.3 s, MuJoCo-sized drag): a state fit with the
    rolls matches them to round-off (4e-16 m RMS measured), one without cannot get below
    a millimetre (1.14 mm)."""
    a, vec, engine = _quad_drag_engine()
    topo = a.topology
    rng = np.random.default_rng(7)
    B, R, W = 3, topo.n_rods, 300
    p = np.broadcast_to(a.pose_p, (B, R, 3)) + rng.normal(0, 0.01, (B, R, 3))
    q = np.broadcast_to(a.pose_q, (B, R, 4)).copy()
    plain = State.from_numpy(p, rng.normal(0, 2.0, (B, R, 3)), q, np.zeros((B, R, 3)))
    axis = RodAxes.of(topo).axis
    angle = torch.as_tensor(rng.uniform(0, np.pi / 2, (B, R)))
    rolled = State(plain.p, plain.v, _rolled(plain.q, angle, axis), plain.omega)
    params = vec.params(vec.start)
    truth = engine.rollout(rolled, params, W)
    obs = end_caps(engine, truth.p, truth.q)
    seen = end_caps(engine, plain.p, plain.q)
    assert torch.allclose(obs[:, 0], seen, atol=1e-12)  # the roll is invisible at the start
    win = Windows(obs=obs, control=None, state=plain, traj=np.arange(B), start=np.zeros(B, int))
    rms = {}
    for roll in (False, True):
        fit = fit_states(engine, vec, win, 20, roll=roll)
        rms[roll] = float(np.sqrt(fit.history[-1]))
    assert rms[False] > 1e-3
    assert rms[True] < 1e-5


def test_rolls_and_spins_of_a_tumbling_structure_are_recovered() -> None:
    """Clean end caps of an icosahedron thrown tumbling at 3 rad/s (0.3 s, MuJoCo-sized
    drag), every rod rolled at random: end caps show the rods' angular velocity across
    their axes only. From the rolls of the nominal pose and no axial spin, a state fit
    with rolls and spins (the spins started from the structure's common angular
    velocity, the rolls searched) matches the end caps to below a micrometre; with the
    spins held it cannot get below 0.1 mm."""
    a, vec, engine = _quad_drag_engine()
    topo = a.topology
    rng = np.random.default_rng(11)
    B, R, W = 2, topo.n_rods, 300
    p = np.broadcast_to(a.pose_p, (B, R, 3)) + np.array([0.0, 0.0, 1.0])
    tumble = rng.normal(size=(B, 1, 3))
    tumble *= 3.0 / np.linalg.norm(tumble, axis=-1, keepdims=True)
    v = rng.normal(0, 1.0, (B, 1, 3)) + np.cross(tumble, p - p.mean(1, keepdims=True))
    q = np.broadcast_to(a.pose_q, (B, R, 4)).copy()
    omega = np.broadcast_to(tumble, (B, R, 3)).copy()
    axis = RodAxes.of(topo).axis
    angle = torch.as_tensor(rng.uniform(0, np.pi, (B, R)))
    true = State.from_numpy(p, v, q, omega)
    rolled = State(true.p, true.v, _rolled(true.q, angle, axis), true.omega)
    params = vec.params(vec.start)
    truth = engine.rollout(rolled, params, W)
    obs = end_caps(engine, truth.p, truth.q)
    # what end caps show: the nominal rolls, each rod's angular velocity across its axis
    rot = quat_to_matrix(true.q)
    along = torch.stack([rot[:, r, :, int(axis[r])] for r in range(R)], 1)
    across = true.omega - along * (along * true.omega).sum(-1, keepdim=True)
    seen = State(true.p, true.v, true.q, across)
    win = Windows(obs=obs, control=None, state=seen, traj=np.arange(B), start=np.zeros(B, int))
    rms = {}
    for spin in (False, True):
        fit = fit_states(engine, vec, win, 20, spin=spin, roll=True)
        rms[spin] = float(np.sqrt(fit.history[-1]))
    assert rms[False] > 1e-4
    assert rms[True] < 1e-6


def test_a_start_with_each_rods_own_spin_is_kept() -> None:
    """States fitted at a nearby model hold each rod's own axial spin (on the floor,
    friction spins each rod on its own, not as one body). From the true states of rods
    spinning at 4 rad/s each about their axes (0.3 s, MuJoCo-sized drag), a state fit with
    rolls and spins keeps them: the end caps match to round-off after one iteration
    (1e-16 m RMS measured). Started over from the structure's common angular velocity
    instead, the same iteration ended 0.47 mm off."""
    a, vec, engine = _quad_drag_engine()
    topo = a.topology
    rng = np.random.default_rng(5)
    B, R, W = 3, topo.n_rods, 300
    axis = RodAxes.of(topo).axis
    p = np.broadcast_to(a.pose_p, (B, R, 3)) + np.array([0.0, 0.0, 1.0])
    q = _rolled(torch.as_tensor(np.broadcast_to(a.pose_q, (B, R, 4)).copy()),
                torch.as_tensor(rng.uniform(0, np.pi, (B, R))), axis)  # fmt: skip
    rot = quat_to_matrix(q)
    along = torch.stack([rot[:, r, :, int(axis[r])] for r in range(R)], 1)
    spins = torch.as_tensor(rng.choice([-4.0, 4.0], (B, R, 1)))
    v = torch.as_tensor(rng.normal(0, 1.0, (B, R, 3)))
    true = State(torch.as_tensor(p.copy()), v, q, along * spins)
    truth = engine.rollout(true, vec.params(vec.start), W)
    obs = end_caps(engine, truth.p, truth.q)
    win = Windows(obs=obs, control=None, state=true, traj=np.arange(B), start=np.zeros(B, int))
    fit = fit_states(engine, vec, win, 1, spin=True, roll=True, grow=False)
    assert float(np.sqrt(fit.history[-1])) < 1e-9
