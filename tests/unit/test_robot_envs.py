"""The generic environments: any winch-driven robot, identified (TensegritySR-v0) and
in MuJoCo (TensegrityMJ-v0), with the shipped lab 3-bar as the default robot."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import tensegrity_env  # noqa: F401  (registers the envs)
from tensegrity_env.envs import (
    SB3VecEnv,
    TensegrityMJEnv,
    TensegrityMJVectorEnv,
    TensegritySREnv,
    TensegritySRVectorEnv,
)
from tensegrity_env.envs.rendering import RenderingUnavailable, record_side_by_side
from tensegrity_env.envs.robot_physics import DEFAULT_ROBOT, MJRobotBatch
from tensegrity_env.envs.robot_rollout import MJRobotRollout
from tensegrity_env.envs.robot_task import GoalTask, RobotSensors, ShapeTask, make_robot_task
from tensegrity_env.envs.sr_env import ASSETS, DEFAULT_PARAMS
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model

#: largest end-cap gap allowed between the identified env and its twin when the model is
#: the robot file's own parameters: the same physics, so round-off (measured 2e-14 m)
TWIN_ATOL = 1e-9
#: shipped prism: 3 rods, 9 cables, 6 winches
R, S, W = 3, 9, 6


@pytest.fixture(scope="module")
def envs() -> tuple[gym.Env, gym.Env]:
    sr, mj = gym.make("TensegritySR-v0"), gym.make("TensegrityMJ-v0")
    yield sr, mj
    sr.close()
    mj.close()


@pytest.mark.parametrize("env_id", ["TensegritySR-v0", "TensegrityMJ-v0"])
@pytest.mark.parametrize("task", ["goal", "shape"])
def test_env_checkers_pass(env_id: str, task: str) -> None:
    env = gym.make(env_id, task=task)
    check_env(env.unwrapped)
    sb3_check_env(env.unwrapped)
    env.close()


def test_spaces_are_the_motors_and_the_sensors(envs: tuple[gym.Env, gym.Env]) -> None:
    sr, mj = envs
    assert sr.action_space == mj.action_space == gym.spaces.Box(-1, 1, (W,), np.float32)
    assert sr.observation_space == mj.observation_space
    assert sr.observation_space.shape == (6 * R + 1 + S + W + 2,)
    shape = TensegrityMJEnv(task="shape")
    assert shape.observation_space.shape == (6 * R + 1 + S + W + W,)


def test_observation_is_what_the_sensors_read() -> None:
    """End caps, MuJoCo's own tendon lengths and the winches' rest lengths."""
    import mujoco

    env = TensegrityMJEnv()
    env.reset(seed=4)
    for _ in range(5):
        obs, *_ = env.step(np.ones(W, np.float32))
    sim = env.sim
    mujoco.mj_forward(sim.model, sim.data)
    caps = np.array([sim.data.site(f"r{r}_end{k}").xpos for r in range(R) for k in (0, 1)])
    centre = caps.mean(axis=0)
    np.testing.assert_allclose(obs[: 6 * R], (caps - centre).ravel(), atol=1e-6)
    assert obs[6 * R] == pytest.approx(centre[2], abs=1e-6)
    np.testing.assert_allclose(obs[6 * R + 1 : 6 * R + 1 + S], sim.data.ten_length, atol=1e-6)
    np.testing.assert_allclose(obs[6 * R + 1 + S : 6 * R + 1 + S + W],
                               sim.plant.rest_lengths, atol=1e-6)  # fmt: skip
    goal = env.target - env.state[:, 0:2].mean(axis=0)
    np.testing.assert_allclose(obs[-2:], goal, atol=1e-6)


def test_identified_env_and_twin_agree_under_random_winch_commands(
    envs: tuple[gym.Env, gym.Env],
) -> None:
    """The default model is the file's own parameters: the same physics as the twin."""
    sr, mj = envs
    sensors = RobotSensors(sr.unwrapped.sim.topology)
    obs_sr, _ = sr.reset(seed=3)
    u = sr.unwrapped
    start = {"state": u.state, "winch": u.winch, "target": u.target}
    obs_mj, _ = mj.reset(seed=99, options=start)
    np.testing.assert_array_equal(obs_sr, obs_mj)
    rng = np.random.default_rng(5)
    worst, moved = 0.0, 0.0
    caps0 = sensors.end_caps(sr.unwrapped.state[None])
    for _ in range(30):
        a = rng.uniform(-1, 1, W).astype(np.float32)
        _, r_sr, *_ = sr.step(a)
        _, r_mj, *_ = mj.step(a)
        caps_sr = sensors.end_caps(sr.unwrapped.state[None])
        caps_mj = sensors.end_caps(mj.unwrapped.state[None])
        worst = max(worst, float(np.abs(caps_sr - caps_mj).max()))
        moved = max(moved, float(np.abs(caps_sr - caps0).max()))
        assert r_sr == pytest.approx(r_mj, abs=1e-6)
    assert moved > 0.01  # the winches moved the robot
    assert np.ptp(sr.unwrapped.winch[:, 0]) > 0.01  # and wound the cables apart
    np.testing.assert_allclose(sr.unwrapped.winch, mj.unwrapped.winch, atol=1e-12)
    assert worst <= TWIN_ATOL, worst


def test_goal_task_reward_and_termination_on_constructed_states() -> None:
    env = TensegrityMJEnv()
    task = env.task
    assert isinstance(task, GoalTask)
    x = env.rest.copy()
    c = x[:, 0:2].mean(axis=0)
    # a goal 1 m away along x: moving the rods 0.1 m towards it is progress
    goal = c + np.array([1.0, 0.0])
    closer = x.copy()
    closer[:, 0] += 0.1
    prev, now = task.error(x[None], goal[None]), task.error(closer[None], goal[None])
    np.testing.assert_allclose([prev[0], now[0]], [1.0, 0.9])
    reward, reached, terms = task.reward(prev, now, np.full((1, W), 0.5))
    assert not reached[0]
    assert terms["reward_progress"][0] == pytest.approx(0.1 / task.control_dt)
    assert terms["reward_control"][0] == pytest.approx(-task.rolling.control_weight * 0.25)
    assert terms["reward_goal"][0] == 0.0
    assert reward[0] == pytest.approx(terms["reward_progress"][0] + terms["reward_control"][0])
    # the episode ends with the bonus once the centre is inside the goal disc
    _, _ = env.reset(seed=0, options={"state": x, "target": c + np.array([0.05, 0.0])})
    _, reward, terminated, truncated, info = env.step(np.zeros(W, np.float32))
    assert terminated and not truncated and info["is_success"]
    assert info["reward_goal"] == task.rolling.goal_bonus
    _, _ = env.reset(seed=0, options={"state": x, "target": c + np.array([0.5, 0.0])})
    _, _, terminated, _, info = env.step(np.zeros(W, np.float32))
    assert not terminated and not info["is_success"]


def test_shape_task_is_held_not_ended() -> None:
    env = TensegrityMJEnv(task="shape", shape_tolerance=0.005)
    task = env.task
    assert isinstance(task, ShapeTask)
    x = env.rest.copy()
    lengths = RobotSensors(env.sim.topology).cable_lengths(x[None])[0]
    wound = lengths[list(env.sim.topology.winches)]
    assert task.error(x[None], wound[None])[0] == pytest.approx(0.0, abs=1e-12)
    off = wound + np.array([0.02, 0, 0, 0, 0, 0])
    _, held, terms = task.reward(np.zeros(1), task.error(x[None], off[None]), np.zeros((1, W)))
    assert not held[0] and terms["reward_shape"][0] == pytest.approx(-task.shape_weight * 0.02)
    env.reset(seed=0, options={"state": x, "target": wound})
    obs, _, terminated, _, info = env.step(np.zeros(W, np.float32))
    assert info["is_success"] and not terminated  # held: the episode goes on
    assert np.abs(obs[-W:]).max() <= 0.005
    # winding one cable in moves it off its target
    for _ in range(10):
        _, _, _, _, info = env.step(np.array([-1, 0, 0, 0, 0, 0], np.float32))
    assert not info["is_success"] and info["task_error"] > 0.01


def test_seeded_resets_are_deterministic() -> None:
    env = TensegrityMJEnv(task="shape")
    a, _ = env.reset(seed=7)
    b, _ = env.reset(seed=7)
    c, _ = env.reset(seed=8)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-4


def test_model_file_is_the_physics(tmp_path: Path) -> None:
    base = Model.read(DEFAULT_ROBOT, dt=1e-3)
    stiff = base.replace(params=base.params.replace(stiffness=base.params.stiffness * 1.5))
    path = stiff.save(tmp_path / "stiff.json")
    env = TensegritySREnv(model=path)
    assert torch.allclose(env.sim.params.stiffness, base.params.stiffness * 1.5)
    Model(base.topology, base.params).save(tmp_path / "no_contact.json")
    with pytest.raises(InputError, match="ground_contact"):
        TensegritySREnv(model=tmp_path / "no_contact.json")
    with pytest.raises(InputError, match="topology"):
        TensegritySREnv(model=DEFAULT_PARAMS)
    with pytest.raises(InputError, match="no winch"):
        TensegrityMJEnv(robot=ASSETS / "icosahedron_rolling.xml")
    with pytest.raises(InputError, match="force cable"):
        TensegrityMJEnv(robot=ASSETS / "lab_prism_force_actuators.xml")
    with pytest.raises(ValueError, match="task must be one of"):
        make_robot_task("roll", base.topology, 0.05, {})
    with pytest.raises(TypeError, match="shape_range"):
        TensegrityMJEnv(task="goal", shape_range=0.1)


def test_bad_actions_are_refused_before_physics() -> None:
    env = TensegrityMJEnv()
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(W))
    env.reset(seed=0)
    before = env.sim.get_state()
    with pytest.raises(ValueError, match="one command per motor"):
        env.step(np.zeros(W + 1))
    with pytest.raises(ValueError, match=r"\[2\]"):
        env.step(np.array([0, 0, np.nan, 0, 0, 0]))
    np.testing.assert_array_equal(env.sim.get_state(), before)


@pytest.mark.parametrize(
    ("env_id", "vector", "single"),
    [
        ("TensegritySR-v0", TensegritySRVectorEnv, TensegritySREnv),
        ("TensegrityMJ-v0", TensegrityMJVectorEnv, TensegrityMJEnv),
    ],
)
def test_vector_env_equals_single_envs(env_id: str, vector: type, single: type) -> None:
    venv = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point",
                        task="shape")  # fmt: skip
    assert isinstance(venv.unwrapped, vector)
    singles = [single(task="shape") for _ in range(2)]
    obs, _ = venv.reset(seed=10)
    for i, e in enumerate(singles):
        np.testing.assert_allclose(obs[i], e.reset(seed=10 + i)[0], atol=1e-6)
    rng = np.random.default_rng(1)
    for _ in range(3):
        a = rng.uniform(-1, 1, (2, W)).astype(np.float32)
        obs, reward, *_ = venv.step(a)
        for i, e in enumerate(singles):
            o, r, *_ = e.step(a[i])
            np.testing.assert_allclose(obs[i], o, atol=1e-5)
            assert reward[i] == pytest.approx(r, abs=1e-9)


def test_twins_through_a_rollout_equal_twins_stepped_one_at_a_time() -> None:
    """The vector twin's rollout (the winding as tendon forces K (l0 - l_ref)) and the
    twin's own steps (``springlength`` written before every ``mj_step``): the same rod
    and winch states to round-off over 1 s of random commands."""
    B = 3
    fast, slow = MJRobotRollout(batch=B, threads=1), MJRobotBatch(batch=B)
    rng = np.random.default_rng(4)
    for i in range(B):
        x = fast.rest_pose()
        x[:, 3:6] += rng.normal(0, 0.05, (R, 3))
        fast.set_state(x, None, i)
        slow.set_state(x, None, i)
    moved = fast.x.copy()
    for _ in range(20):
        u = rng.uniform(-1.3, 1.3, (B, W))
        fast.step_batch(u)
        slow.step_batch(u)
    fast.close()
    assert np.abs(fast.x - slow.x).max() < TWIN_ATOL
    assert np.abs(fast.winch - slow.winch).max() < TWIN_ATOL
    assert np.abs(fast.x - moved)[..., :3].max() > 1e-3  # the robots moved


def test_sb3_adapter_on_the_batched_robot() -> None:
    sb3 = SB3VecEnv(TensegritySRVectorEnv(num_envs=2, max_episode_steps=2))
    sb3.reset()
    for _ in range(2):
        obs, reward, done, infos = sb3.step(np.zeros((2, W), np.float32))
    assert obs.shape == (2, 6 * R + 1 + S + W + 2) and done.all()
    assert reward.dtype == np.float32
    np.testing.assert_allclose(reward, [i["reward_progress"] + i["reward_control"] for i in infos],
                               rtol=1e-5, atol=1e-6)  # fmt: skip
    assert all(i["TimeLimit.truncated"] and "terminal_observation" in i for i in infos)


@pytest.mark.parametrize("cls", [TensegritySREnv, TensegrityMJEnv])
def test_rendered_frame_shows_the_robot(cls: type) -> None:
    env = cls(render_mode="rgb_array", width=320, height=240)
    env.reset(seed=0)
    try:
        frame = env.render()
    except RenderingUnavailable as e:
        pytest.skip(f"no headless OpenGL here: {e}")
    assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8
    hidden = env.state.copy()
    hidden[:, 2] -= 10.0  # the same view with the robot sunk far below the floor
    env.reset(seed=0, options={"state": hidden})
    empty = env.render()
    changed = np.abs(frame.astype(int) - empty.astype(int)).max(axis=-1) > 10
    assert changed.sum() > 2000, "the robot does not show in the frame"
    env.close()


def test_side_by_side_clip_of_the_identified_robot_and_its_twin(tmp_path: Path) -> None:
    sr = TensegritySREnv(render_mode="rgb_array", width=160, height=120)
    mj = TensegrityMJEnv(render_mode="rgb_array", width=160, height=120)
    try:
        path = record_side_by_side(sr, mj, tmp_path / "both.gif", max_steps=3)
    except RenderingUnavailable as e:
        pytest.skip(f"no headless OpenGL here: {e}")
    assert path.stat().st_size > 0
    np.testing.assert_allclose(sr.state, mj.state, atol=TWIN_ATOL)  # started together
