"""The generic environments' readings in C (``native_sense.c``) against the tasks' NumPy
statement of them, and the single environment's step (the C readings, the narrow kernel
build, the rewards in floats) against the batched path it replaced: the same bits."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from tensegrity_env.envs import TensegritySREnv
from tensegrity_env.envs.physics import NativeStepper
from tensegrity_env.envs.robot_physics import DEFAULT_ROBOT
from tensegrity_env.envs.robot_task import RobotSensors, make_robot_task
from tensegrity_env.envs.sr_env import ASSETS
from tensegrity_env.envs.task import RollingTask
from tensegrity_env.mjcf import from_mjcf
from tensegrity_env.native.kernel import usable_kernel
from tensegrity_env.topology import Topology

pytestmark = pytest.mark.skipif(
    usable_kernel(torch.zeros(1, dtype=torch.float64)) is None, reason="no C compiler"
)

#: the shape task's error through C's cable lengths, not NumPy's (their node positions
#: sum their rotation terms in another order) [m]
LENGTH_ROUND_OFF = 1e-15
#: robots with winches: the lab 3-bar (attachment points besides its end caps) and the
#: cable-driven icosahedron (twelve winches: the command sums go past NumPy's 8-term unroll)
ROBOTS = [DEFAULT_ROBOT, ASSETS / "icosahedron_winches.xml"]


def _states(topology: Topology, B: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random rod poses over a square metre and winch states (B, ...)."""
    rng = np.random.default_rng(seed)
    R, W = topology.n_rods, topology.n_winches
    x = np.zeros((B, R, 13))
    x[..., 0:2] = rng.uniform(-0.5, 0.5, (B, R, 2))
    x[..., 2] = rng.uniform(0.0, 0.3, (B, R))
    q = rng.normal(size=(B, R, 4))
    x[..., 6:10] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x[..., 3:6], x[..., 10:13] = rng.normal(size=(B, R, 3)), rng.normal(size=(B, R, 3))
    winch = np.stack([rng.uniform(0.05, 0.4, (B, W)), rng.normal(0, 0.05, (B, W))], -1)
    return x, winch


@pytest.mark.parametrize("robot", ROBOTS, ids=lambda p: p.stem)
@pytest.mark.parametrize("task", ["goal", "shape"])
def test_c_readings_are_numpys(robot: Path, task: str) -> None:
    topology = from_mjcf(robot).topology
    t = make_robot_task(task, topology, 0.05, {})
    assert t.native is not None
    B = 500
    x, winch = _states(topology, B, seed=1)
    rng = np.random.default_rng(2)
    target = rng.uniform(-1, 1, (B, 2) if task == "goal" else (B, topology.n_winches))
    obs, error, centre = t.sense(x, winch, target)
    assert obs.dtype == np.float32 and obs.shape == (B, t.observation_size())
    np.testing.assert_array_equal(obs, t.observe(x, winch, target))
    np.testing.assert_array_equal(centre, RollingTask.centre(x))
    if task == "goal":
        np.testing.assert_array_equal(error, t.error(x, target))
    else:
        np.testing.assert_allclose(error, t.error(x, target), rtol=0, atol=LENGTH_ROUND_OFF)
    # one robot alone reads as in the batch; a state that blew up reads NaN, not garbage
    np.testing.assert_array_equal(t.sense(x[3:4], winch[3:4], target[3:4])[0], obs[3:4])
    x[0, 0, 0] = np.nan
    assert np.isnan(t.sense(x[:1], winch[:1], target[:1])[1][0])
    assert RobotSensors(topology).size() + t.target_size() == obs.shape[1]


@pytest.mark.parametrize("task", ["goal", "shape"])
def test_single_env_step_is_the_batched_path_bit_for_bit(task: str) -> None:
    """Six episodes of random commands (some beyond [-1, 1]): the env's observations,
    rewards, infos and states are those of the batched task code on a batch of one
    stepped by the wide kernel build with its per-call checks."""
    env = TensegritySREnv(task=task)
    t = env.task
    stepper = getattr(env.sim, "stepper", None)
    assert isinstance(stepper, NativeStepper)
    rng = np.random.default_rng(11)
    W = env.action_space.shape[0]
    for episode in range(6):
        obs, info = env.reset(seed=episode)
        x, winch, target = env.state[None].copy(), env.winch[None].copy(), env.target[None]
        np.testing.assert_array_equal(obs, t.observe(x, winch, target)[0])
        prev = t.error(x, target)
        for _ in range(40):
            a = rng.uniform(-1.3, 1.3, W).astype(np.float32)
            obs, reward, terminated, _, info = env.step(a)
            command = np.clip(a.astype(np.float64), -1.0, 1.0)[None]
            stepper._lib.tsr_step(  # the wide build, as before the narrow one stepped one env
                *stepper._args(x, None, winch, np.ascontiguousarray(command))
            )
            np.testing.assert_array_equal(env.state, x[0])
            np.testing.assert_array_equal(env.winch, winch[0])
            np.testing.assert_array_equal(obs, t.observe(x, winch, target)[0])
            error = t.error(x, target)
            r, success, terms = t.reward(prev, error, command)
            if task == "goal":
                assert (reward, info["task_error"]) == (float(r[0]), float(error[0]))
                assert all(info[k] == float(v[0]) for k, v in terms.items())
            else:
                assert reward == pytest.approx(float(r[0]), rel=0, abs=20 * LENGTH_ROUND_OFF)
            assert info["is_success"] == bool(success[0])
            c = x[0, :, 0:3].sum(axis=0) / x.shape[1]
            assert (info["x_position"], info["y_position"]) == (c[0], c[1])
            prev = error
            if terminated:
                break
