"""Motor position targets (``motor_targets``) on the generic robot environments."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import tensegrity_env  # noqa: F401  (registers the envs)
from tensegrity_env.envs import (
    TensegrityMJEnv,
    TensegrityMJVectorEnv,
    TensegritySREnv,
    TensegritySRVectorEnv,
)
from tensegrity_env.envs.robot_motors import MotorTargets

#: shipped prism: 6 winches, 0.1 m/s, rest lengths 0.6-1.2 m, 30 ms lag, 50 ms control step
W = 6
#: a held target is overshot by the motor lag's carried speed, then approached again:
#: 2.1 mm measured on the shipped prism (1.5 control steps' lag of 30 ms at 0.1 m/s is 3 mm)
OVERSHOOT = 3e-3
#: a held target, once reached, is held to this [m] (measured 2e-8 m after 1 s)
HELD = 1e-6
#: a target action: every winch to a different place in its range
HOLD = np.array([-1.0, -0.5, 0.0, 0.3, 0.7, 1.0], np.float32)


def test_controller_maps_actions_into_the_range_and_commands_toward_them() -> None:
    m = MotorTargets(np.full(2, 0.6), np.full(2, 1.2), np.full(2, 0.1), 0.05)
    np.testing.assert_allclose(m.targets(np.array([-1.0, 1.0])), [0.6, 1.2])
    np.testing.assert_allclose(m.targets(np.array([0.0, 2.0])), [0.9, 1.2])  # clipped
    # far: full speed toward the target; within one step's winding: the step that gets there
    np.testing.assert_allclose(m.commands(np.array([-1.0, 1.0]), np.array([0.9, 0.9])), [-1, 1])
    u = m.commands(np.array([0.0, 0.0]), np.array([0.898, 0.9025]))
    np.testing.assert_allclose(u, [0.4, -0.5])  # 2 mm and -2.5 mm of 5 mm a step


@pytest.mark.parametrize("env_id", ["TensegritySR-v0", "TensegrityMJ-v0"])
def test_a_held_target_drives_each_winch_there(env_id: str) -> None:
    env = gym.make(env_id, motor_targets=True).unwrapped
    env.reset(seed=3)
    target = env.motors.targets(HOLD)
    start = env.winch[:, 0].copy()
    step = 0.1 * env.sim.control_dt  # the most a winch winds in a control step [m]
    reach = np.ceil(np.abs(target - start) / step).astype(int)  # at full speed
    rest = []
    for _ in range(reach.max() + 20):  # and 1 s
        env.step(HOLD)
        rest.append(env.winch[:, 0].copy())
    rest = np.array(rest)
    ahead = np.sign(target - start)
    for w in range(W):
        # at full speed while far (within the lag's first step), never more than the
        # lag's overshoot past the target, and there within a few steps of full speed
        wound = (rest[reach[w] // 2, w] - start[w]) * ahead[w]
        assert wound > (reach[w] // 2) * step - step, w
        assert ((rest[:, w] - target[w]) * ahead[w]).max() <= OVERSHOOT, w
        assert abs(rest[reach[w] + 4, w] - target[w]) < OVERSHOOT, w
    np.testing.assert_allclose(rest[-1], target, atol=HELD)
    assert np.ptp(target - start) > 0.5  # the winches went both ways, 0.6 m apart


def test_identified_env_and_twin_agree_with_targets() -> None:
    """The default model is the robot file's own parameters: the same motors and rods,
    so the same commands and states (to round-off) under the same random targets."""
    sr, mj = (
        gym.make("TensegritySR-v0", motor_targets=True),
        gym.make("TensegrityMJ-v0", motor_targets=True),
    )
    sr.reset(seed=5)
    u = sr.unwrapped
    mj.reset(options={"state": u.state, "winch": u.winch, "target": u.target})
    rng = np.random.default_rng(2)
    for _ in range(40):
        a = rng.uniform(-1, 1, W).astype(np.float32)
        _, r_sr, *_ = sr.step(a)
        _, r_mj, *_ = mj.step(a)
        assert r_sr == pytest.approx(r_mj, abs=1e-6)
    np.testing.assert_allclose(u.winch, mj.unwrapped.winch, atol=1e-12)
    # round-off grown over 2 s of floor contact (3e-9 m measured)
    np.testing.assert_allclose(u.state[:, 0:3], mj.unwrapped.state[:, 0:3], atol=1e-7)
    assert np.abs(u.state[:, 0:3] - u.rest[:, 0:3]).max() > 0.01  # the robot moved


@pytest.mark.parametrize("cls", [TensegritySREnv, TensegrityMJEnv])
def test_without_targets_actions_are_the_motor_commands_bit_for_bit(cls: type) -> None:
    """Off (the default, or False): each step is the simulator stepped under the clipped
    action itself, and rewarded on it."""
    for kw in ({}, {"motor_targets": False}):
        env, bare = cls(**kw), cls()
        assert env.motors is None
        env.reset(seed=1)
        bare.reset(seed=1)
        rng = np.random.default_rng(0)
        for _ in range(5):
            a = rng.uniform(-1.2, 1.2, W).astype(np.float32)
            prev = env._error
            _, r, *_ = env.step(a)
            u = np.clip(a.astype(np.float64), -1.0, 1.0)
            bare.sim.step(u)
            assert np.array_equal(env.state, bare.sim.get_state())
            assert np.array_equal(env.winch, bare.sim.get_winch())
            assert r == env.task.reward_one(prev, env._error, u)[0]


@pytest.mark.parametrize("vector", [TensegritySRVectorEnv, TensegrityMJVectorEnv])
def test_vector_envs_take_the_option(vector: type) -> None:
    """Off: the batch simulator under the clipped actions, bit for bit; on: the same
    commands and states as the single envs with targets."""
    plain, bare = vector(num_envs=2, threads=1), vector(num_envs=2, threads=1)
    plain.reset(seed=4)
    bare.reset(seed=4)
    rng = np.random.default_rng(1)
    for _ in range(3):
        a = rng.uniform(-1.2, 1.2, (2, W)).astype(np.float32)
        plain.step(a)
        bare.sim.step_batch(np.clip(a.astype(np.float64), -1.0, 1.0))
        assert np.array_equal(plain.sim.x, bare.sim.x)
        assert np.array_equal(plain.sim.winch, bare.sim.winch)
    single = TensegritySREnv if vector is TensegritySRVectorEnv else TensegrityMJEnv
    venv = vector(num_envs=2, threads=1, motor_targets=True)
    singles = [single(motor_targets=True) for _ in range(2)]
    venv.reset(seed=10)
    for i, e in enumerate(singles):
        e.reset(seed=10 + i)
    for _ in range(10):
        a = rng.uniform(-1, 1, (2, W)).astype(np.float32)
        obs, reward, *_ = venv.step(a)
        for i, e in enumerate(singles):
            o, r, *_ = e.step(a[i])
            np.testing.assert_allclose(venv.sim.winch[i], e.winch, atol=1e-12)
            np.testing.assert_allclose(obs[i], o, atol=1e-5)
            assert reward[i] == pytest.approx(r, abs=1e-9)
    for e in (plain, bare, venv):
        e.close()


def test_bad_option_is_refused() -> None:
    with pytest.raises(ValueError, match="motor_targets"):
        gym.make("TensegritySR-v0", motor_targets="yes")
