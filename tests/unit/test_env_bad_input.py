"""The identified env, its MuJoCo twin and both vector envs treat bad input alike.

One policy (``tensegrity_env.envs.task.ACTION_POLICY``): ``step`` before ``reset``
raises ``ResetNeeded``; a misshapen action or one with NaN/inf entries raises
ValueError naming the expected shape or the entries, before any physics runs, so the
state is unchanged and the env goes on after a good action.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from gymnasium.error import ResetNeeded

from tensegrity_env.envs import (
    IcosahedronMJEnv,
    IcosahedronMJVectorEnv,
    IcosahedronSREnv,
    IcosahedronSRVectorEnv,
)
from tensegrity_env.envs.task import ACTION_POLICY

N = 2
FACTORIES: dict[str, Callable[[], Any]] = {
    "IcosahedronSR-v0": IcosahedronSREnv,
    "IcosahedronMJ-v0": IcosahedronMJEnv,
    "SR vector": lambda: IcosahedronSRVectorEnv(num_envs=N),
    "MJ vector": lambda: IcosahedronMJVectorEnv(num_envs=N),
}


def states(env: Any) -> np.ndarray:
    return np.array(env.state if hasattr(env, "state") else env._get_states(), copy=True)


@pytest.fixture(params=list(FACTORIES), scope="module")
def env(request: pytest.FixtureRequest) -> Any:
    e = FACTORIES[request.param]()
    yield e
    e.close()


def test_step_before_reset_raises(env: Any) -> None:
    fresh = type(env)(num_envs=N) if hasattr(env, "num_envs") else type(env)()
    with pytest.raises(ResetNeeded, match=r"reset\(\) before step\(\)"):
        fresh.step(np.zeros(fresh.action_space.shape, np.float32))
    fresh.close()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_actions_raise_naming_the_entries_and_change_nothing(
    env: Any, bad: float
) -> None:
    env.reset(seed=3)
    before = states(env)
    action = np.zeros(env.action_space.shape, np.float32)
    action.flat[[4, 7]] = bad
    entries = "[4, 7]" if action.ndim == 1 else "[(0, 4), (0, 7)]"
    with pytest.raises(ValueError) as e:
        env.step(action)
    assert str(e.value) == f"action entries {entries} are NaN or infinite"
    np.testing.assert_array_equal(states(env), before)
    obs, reward, *_ = env.step(np.zeros(env.action_space.shape, np.float32))  # still usable
    assert np.all(np.isfinite(obs)) and np.all(np.isfinite(reward))


def test_a_wrong_action_shape_says_the_expected_one(env: Any) -> None:
    env.reset(seed=3)
    expected = env.action_space.shape
    wrong = (*expected[:-1], expected[-1] - 1)
    with pytest.raises(ValueError) as e:
        env.step(np.zeros(wrong, np.float32))
    assert str(e.value).startswith(f"action has shape {wrong}, expected {expected}")
    with pytest.raises(ValueError, match="must be numbers"):
        env.step(np.array(["a"] * int(np.prod(expected))).reshape(expected))


def test_both_envs_give_the_same_first_step_from_the_same_start() -> None:
    """The same policy covers the same cases; a good action is a finite step in both."""
    sr, mj = IcosahedronSREnv(), IcosahedronMJEnv()
    sr.reset(seed=5)
    mj.reset(options={"state": sr.state.copy(), "goal": sr.goal.copy()})
    a = np.full(18, 2.0, np.float32)  # out of [-1, 1]: clipped in both, not refused
    (o1, r1, t1, *_), (o2, r2, t2, *_) = sr.step(a), mj.step(a)
    assert t1 == t2 is False and np.isfinite(r1) and np.isfinite(r2)
    np.testing.assert_allclose(o1[:18], o2[:18], atol=5e-3)  # rod positions about c agree
    assert "NaN or infinite" in ACTION_POLICY and "ValueError" in ACTION_POLICY
