"""Training environments: a registered env id as one SB3 ``VecEnv`` of N environments.

Environments with a natively batched ``vector_entry_point`` (``IcosahedronSR-v0``,
``IcosahedronMJ-v0``) become one batched env behind
:class:`~tensegrity_env.envs.sb3.SB3VecEnv`; any other Gymnasium id falls back to
SB3's ``DummyVecEnv`` of single envs. Episode returns and lengths are recorded
(``VecMonitor``/``Monitor``) for the logs; environment ``i`` is seeded ``seed + i``.
"""

from __future__ import annotations

import inspect
from typing import Any

import gymnasium as gym
from gymnasium.envs.registration import load_env_creator
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

import tensegrity_env  # noqa: F401  (registers the environments)
from tensegrity_env.io_utils import InputError


def env_spec(env_id: str) -> gym.envs.registration.EnvSpec:
    """The registered spec of ``env_id``; :class:`InputError` if it is not registered."""
    try:
        return gym.spec(env_id)
    except gym.error.Error:
        raise InputError(f"unknown environment id {env_id!r}") from None


def make_training_env(
    env_id: str,
    n_envs: int,
    seed: int,
    threads: int | None = 1,
    env_kwargs: dict[str, Any] | None = None,
) -> VecEnv:
    """``n_envs`` environments of ``env_id`` as one SB3 ``VecEnv``, seeded ``seed + i``.

    Args:
        env_id: a registered Gymnasium id.
        n_envs: N.
        seed: environment ``i`` is reset with ``seed + i`` first.
        threads: CPU threads of a batched env's physics (None: every core), where the
            env takes a ``threads`` argument.
        env_kwargs: the environment's own arguments (``TensegritySR-v0``: ``model``,
            ``robot``, ``task`` and task options).
    """
    spec = env_spec(env_id)
    if spec.vector_entry_point is None:
        venv = make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs)
        return venv
    from tensegrity_env.envs.robot_vector import TensegritySRVectorEnv
    from tensegrity_env.envs.sb3 import SB3VecEnv
    from tensegrity_env.envs.vector import RollingVectorEnv

    entry = spec.vector_entry_point
    creator = entry if callable(entry) else load_env_creator(entry)
    kwargs: dict[str, Any] = {"num_envs": n_envs, **spec.kwargs, **(env_kwargs or {})}
    if spec.max_episode_steps is not None:
        kwargs.setdefault("max_episode_steps", spec.max_episode_steps)
    if "threads" in inspect.signature(creator).parameters:
        kwargs["threads"] = threads
    vector = creator(**kwargs)
    if not isinstance(vector, RollingVectorEnv | TensegritySRVectorEnv):
        raise InputError(f"{env_id}: its vector entry point makes a {type(vector).__name__}, "
                         "not one of this package's batched environments")  # fmt: skip
    venv = VecMonitor(SB3VecEnv(vector))  # episode returns for the logs
    venv.seed(seed)
    return venv
