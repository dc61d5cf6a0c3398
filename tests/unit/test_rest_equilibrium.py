"""Rest lengths balanced where the robot rests (``benchmarks/rest_balance.py``): a
MuJoCo plant at rest and a model whose rest lengths are off.

The plant is :mod:`test_cap_radii`'s icosahedron (sphere end caps of different radii)
settled on MuJoCo's floor after drops turned to land on different faces; the model has
the plant's values but every rest length moved by a few millimetres.
"""

from __future__ import annotations

import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from test_cap_radii import DT, RADII, caps_of, plant

from identification.trajectory.cap_radius_fit import rest_states
from tensegrity_env.engine import Engine

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from rest_balance import SHORTEST, fit_rest_equilibrium

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: the rest lengths' perturbation [m] (standard deviation)
OFF = 0.003
#: the drops' turns [rad]: each rest a different face on the floor
ANGLES = (0.0, 2.0, 4.0)


def turned(asm, angle: float) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The plant turned by ``angle`` [rad] about the x axis through its centre, dropped
    from 5 cm above its floor and left for 10 s."""
    m = asm.model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    turn = np.zeros(4)
    mujoco.mju_axisAngle2Quat(turn, np.array([1.0, 0.0, 0.0]), angle)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, turn)
    joints = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    adr = [int(m.jnt_qposadr[j]) for j in joints]
    centre = np.mean([d.qpos[a : a + 3] for a in adr], 0)
    for a in adr:
        d.qpos[a : a + 3] = rot.reshape(3, 3) @ (d.qpos[a : a + 3] - centre) + centre
        q = np.zeros(4)
        mujoco.mju_mulQuat(q, turn, d.qpos[a + 3 : a + 7].copy())
        d.qpos[a + 3 : a + 7] = q
    mujoco.mj_forward(m, d)
    low = caps_of(asm, d)[:, 2].min() - max(max(r) for r in RADII)
    for a in adr:
        d.qpos[a + 2] += 0.05 - low
    mujoco.mj_forward(m, d)
    for _ in range(round(10.0 / m.opt.timestep)):
        mujoco.mj_step(m, d)
    return m, d


def resting(asm, angle: float = 0.0) -> np.ndarray:
    """One second of the plant's end caps (T, 2R, 3) [m] at rest, every :data:`DT`,
    after a drop turned by ``angle`` (:func:`turned`)."""
    m, d = turned(asm, angle)
    rest = []
    for _ in range(round(1.0 / DT) + 1):
        rest.append(caps_of(asm, d))
        for _ in range(round(DT / m.opt.timestep)):
            mujoco.mj_step(m, d)
    return np.array(rest)


def test_balancing_lowers_the_rods_net_force_within_the_springs_range() -> None:
    asm = plant()
    rests = [resting(asm, a) for a in ANGLES]
    for rest in rests:  # at rest: the caps move less than 1 cm in a second (soft friction creeps)
        assert np.abs(rest - rest[0]).max() < 1e-2
    contact, drag = asm.declared_effects()
    engine = Engine(asm.topology, dt=DT, substeps=round(DT / asm.model.opt.timestep), native=True)
    truth = asm.params.rest_length.numpy()
    given = truth + np.random.default_rng(0).normal(0.0, OFF, truth.shape)
    model = asm.params.replace(rest_length=torch.as_tensor(given))
    found = fit_rest_equilibrium(engine, model, [drag, contact], rests, noise=1e-5)
    assert found is not None and found.kept and found.states == 2 * len(ANGLES)
    assert found.after < 0.5 * found.before, found.lines()
    # every rest length within its range: no shorter than SHORTEST of it, none slack at rest
    state = rest_states(rests, engine)[0]
    x = engine.kinematics(state).x
    length = (
        torch.linalg.vector_norm(x[:, engine.node_b] - x[:, engine.node_a], dim=-1).min(0).values
    )
    assert (found.rest_length >= SHORTEST * given - 1e-12).all()
    taut = given < length.numpy()
    assert (found.rest_length[taut] <= length.numpy()[taut] + 1e-9).all()


def test_nothing_changes_without_a_rest() -> None:
    asm = plant()
    contact, drag = asm.declared_effects()
    engine = Engine(asm.topology, dt=DT)
    assert fit_rest_equilibrium(engine, asm.params, [drag, contact], [], noise=1e-4) is None
    # no ground contact: no floor to rest on
    assert (
        fit_rest_equilibrium(engine, asm.params, [drag], [np.zeros((200, 12, 3))], noise=1e-4)
        is None
    )
