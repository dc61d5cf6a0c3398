"""Tipped starts: the generic robot envs starting episodes resting on another face."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import seeding

import tensegrity_env  # noqa: F401  (registers the envs)
from tensegrity_env.envs import TensegrityMJVectorEnv, TensegritySRVectorEnv
from tensegrity_env.envs.robot_faces import floor_caps, start_pose
from tensegrity_env.envs.robot_task import RobotSensors

#: the lab 3-bar's base face: end caps 0, 2, 4 on the floor (the file's resting pose)
BASE = frozenset({0, 2, 4})
#: the three sides (two rods' caps each) and the top face the 3-bar can rest on
OTHER_FACES = {(0, 1, 3, 4), (0, 2, 3, 5), (1, 2, 4, 5), (1, 3, 5)}
#: how far the lowest end cap of a resting pose may lie from the base pose's [m]: it rests
#: on the floor at the contact's own depth (the drop was 5 mm)
ON_FLOOR_ATOL = 1e-3


def lowest_cap(env: gym.Env, x: np.ndarray) -> float:
    return float(RobotSensors(env.unwrapped.sim.topology).end_caps(x[None])[0][:, 2].min())


@pytest.mark.parametrize("env_id", ["TensegritySR-v0", "TensegrityMJ-v0"])
def test_tipped_starts_rest_on_another_face(env_id: str) -> None:
    env = gym.make(env_id, tipped_starts=1.0)
    u = env.unwrapped
    topology = u.sim.topology
    assert floor_caps(topology, u.rest) == BASE
    faces = {tuple(sorted(floor_caps(topology, p))) for p in u.tipped}
    assert faces == OTHER_FACES
    # each settled pose lies on the floor and moves no faster than the base pose itself
    # (which still sways after its settling: the robot's own notion of rest)
    rest_speed = np.linalg.norm(u.rest[:, 3:6], axis=1).max()
    for p in u.tipped:
        assert abs(lowest_cap(env, p) - lowest_cap(env, u.rest)) < ON_FLOOR_ATOL
        assert np.linalg.norm(p[:, 3:6], axis=1).max() < rest_speed
    seen = set()
    for seed in range(8):
        env.reset(seed=seed)
        assert floor_caps(topology, u.state) != BASE
        # the reset's perturbation lifts a cap by up to 2-3 cm; after 1 s without a
        # command the robot lies on one of its other faces, not back on the base
        for _ in range(round(1.0 / u.sim.control_dt)):
            env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        face = tuple(sorted(floor_caps(topology, u.state)))
        assert face in OTHER_FACES
        seen.add(face)
    assert len(seen) > 1  # the faces are drawn, not one fixed
    env.close()


def test_identified_env_and_twin_tip_onto_the_same_faces() -> None:
    # the file's own parameters: the same physics in both, so the same settled poses
    sr = gym.make("TensegritySR-v0", tipped_starts=0.5).unwrapped
    mj = gym.make("TensegrityMJ-v0", tipped_starts=0.5).unwrapped
    assert sr.tipped.shape == mj.tipped.shape
    assert np.allclose(sr.tipped[:, :, 0:3], mj.tipped[:, :, 0:3], atol=1e-6)


@pytest.mark.parametrize("env_id", ["TensegritySR-v0", "TensegrityMJ-v0"])
def test_without_tipped_starts_resets_are_the_tasks_own(env_id: str) -> None:
    # bit for bit the task's draw from the resting pose, with no option or a share of 0
    for kw in ({}, {"tipped_starts": 0.0}):
        env = gym.make(env_id, **kw)
        u = env.unwrapped
        assert u.tipped is None  # nothing settled
        for seed in (0, 7):
            env.reset(seed=seed)
            state, target = u.state.copy(), u.target.copy()
            rng = seeding.np_random(seed)[0]
            x, goal = u.task.sample_reset(rng, u.rest, u.sim.get_winch())
            u.sim.set_state(x)  # as the simulator holds it (MuJoCo's own qpos)
            assert np.array_equal(state, u.sim.get_state()) and np.array_equal(target, goal)
        env.close()


@pytest.mark.parametrize("vector", [TensegritySRVectorEnv, TensegrityMJVectorEnv])
def test_vector_envs_take_the_same_option(vector: type) -> None:
    plain = vector(num_envs=4, threads=1)
    plain.reset(seed=3)
    states = plain.sim.x.copy()
    for i in range(4):
        rng = seeding.np_random(3 + i)[0]
        x, goal = plain.task.sample_reset(rng, plain.rest, plain.sim.rest_winch)
        plain.sim.set_state(x, None, i)  # as the simulator holds it (MuJoCo's own qpos)
        assert np.array_equal(states[i], plain.sim.x[i])
        assert np.array_equal(plain.targets[i], goal)
    tipped = vector(num_envs=4, threads=1, tipped_starts=1.0)
    tipped.reset(seed=3)
    for i in range(4):
        assert floor_caps(tipped.sim.topology, tipped.sim.x[i]) != BASE
    plain.close()
    tipped.close()


def test_share_picks_that_share_of_starts() -> None:
    rest, tipped = np.zeros((3, 13)), np.ones((4, 3, 13))
    rng = np.random.default_rng(0)
    picks = [start_pose(rng, 0.25, rest, tipped)[0, 0] for _ in range(4000)]
    assert abs(np.mean(picks) - 0.25) < 0.03  # binomial std 0.007
    with pytest.raises(ValueError, match="tipped_starts"):
        gym.make("TensegritySR-v0", tipped_starts=1.5)
