"""Evaluate a policy over fixed, seeded episodes in a registered environment.

The episodes are defined once, by a *source* environment: episode ``k`` starts from
the state and goal that ``source.reset(seed=seed + k)`` draws. Every environment
evaluated is then reset to exactly that start
(``reset(seed=seed + k, options=source.start_options())``: the rod state and goal, and
for a generic robot its winch state and target), so the identified env and the
MuJoCo twin see the same starts, and a policy's numbers differ only by the physics.
Environment arguments (``env_kwargs``: a generic robot's ``model``, ``robot``,
``task``) go to ``gym.make``.
Episodes run in the registered single environment (``gym.make``, with its time limit)
under the policy's deterministic action.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

import tensegrity_env  # noqa: F401  (registers the environments)
from policies.vec import env_spec
from tensegrity_env.io_utils import InputError

Policy = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class EpisodeStart:
    """Where an episode begins: packed rod state (R, 13) and goal (2,) [m]; its seed.

    ``options``: every ``reset`` option of the start (the source env's
    ``start_options()``; a generic robot's ``winch`` (W, 2) and ``target`` too).
    """

    seed: int
    state: np.ndarray
    goal: np.ndarray
    options: dict[str, Any] = field(default_factory=dict)

    def reset_options(self) -> dict[str, Any]:
        """The options that reset an env to this start."""
        return self.options or {"state": self.state, "goal": self.goal}


@dataclass(frozen=True)
class EvalResult:
    """Per-episode outcomes in one environment.

    Attributes:
        env_id: the environment.
        returns: undiscounted return per episode, (n,).
        success: goal reached (terminated with ``is_success``), (n,) bool.
        steps: env steps per episode, (n,) int.
        control_dt: seconds per env step [s].
    """

    env_id: str
    returns: np.ndarray
    success: np.ndarray
    steps: np.ndarray
    control_dt: float

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns))

    @property
    def std_return(self) -> float:
        return float(np.std(self.returns))

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.success))

    @property
    def time_to_goal(self) -> float:
        """Mean time to reach the goal over the successful episodes [s] (NaN if none)."""
        if not self.success.any():
            return float("nan")
        return float(np.mean(self.steps[self.success]) * self.control_dt)


def episode_starts(
    source_id: str, n: int, seed: int, env_kwargs: dict[str, Any] | None = None
) -> list[EpisodeStart]:
    """``n`` starts drawn by ``source_id``'s seeded resets (seeds ``seed .. seed + n - 1``)."""
    env_spec(source_id)
    env = gym.make(source_id, **(env_kwargs or {}))
    try:
        base = env.unwrapped
        if not hasattr(base, "state") or not hasattr(base, "start_options"):
            raise InputError(f"{source_id}: not a task env (no start state to begin from)")
        starts = []
        for k in range(n):
            env.reset(seed=seed + k)
            opts = base.start_options()
            goal = opts.get("goal", opts.get("target"))
            starts.append(EpisodeStart(seed + k, opts["state"], np.asarray(goal), opts))
    finally:
        env.close()
    return starts


def run_episode(env: gym.Env, policy: Policy, start: EpisodeStart) -> tuple[float, bool, int]:
    """One episode from ``start``: (return, goal reached, steps)."""
    obs, _ = env.reset(seed=start.seed, options=start.reset_options())
    total, steps = 0.0, 0
    while True:
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        total += float(reward)
        steps += 1
        if terminated or truncated:
            return total, bool(info.get("is_success", False)), steps


def evaluate(
    policy: Policy,
    env_id: str,
    starts: list[EpisodeStart],
    env_kwargs: dict[str, Any] | None = None,
) -> EvalResult:
    """``policy`` over ``starts`` in ``env_id`` (see the module docstring)."""
    env_spec(env_id)
    env = gym.make(env_id, **(env_kwargs or {}))
    try:
        space = getattr(getattr(policy, "model", None), "observation_space", None)
        if space is not None and space.shape != env.observation_space.shape:
            raise InputError(
                f"{env_id}: observations of shape {env.observation_space.shape} do not fit "
                f"the policy's {space.shape}"
            )
        out = [run_episode(env, policy, s) for s in starts]
        dt = float(env.unwrapped.task.control_dt)  # type: ignore[attr-defined]  # a rolling-task env
    finally:
        env.close()
    r, s, n = zip(*out, strict=True) if out else ((), (), ())
    return EvalResult(env_id, np.array(r), np.array(s, dtype=bool), np.array(n, dtype=int), dt)
