"""Stable-Baselines3 on the batched environments: a :class:`VecEnv` adapter.

SB3 steps a ``VecEnv`` and expects, for every env that finished, its last
observation in ``infos[i]["terminal_observation"]`` (the returned observation is
already the next episode's first) and ``infos[i]["TimeLimit.truncated"]`` when the
episode was cut by the time limit rather than ended by the task, so that it
bootstraps from the last value. :class:`SB3VecEnv` gives exactly that on top of a
:class:`~tensegrity_env.envs.vector.RollingVectorEnv` or
:class:`~tensegrity_env.envs.robot_vector.TensegritySRVectorEnv` (whose ``SAME_STEP``
autoreset matches SB3's)::

    from stable_baselines3 import PPO
    from tensegrity_env.envs import IcosahedronSRVectorEnv, SB3VecEnv

    venv = SB3VecEnv(IcosahedronSRVectorEnv(num_envs=64))
    PPO("MlpPolicy", venv).learn(100_000)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvStepReturn

from tensegrity_env.envs.robot_vector import TensegritySRVectorEnv
from tensegrity_env.envs.vector import RollingVectorEnv

#: per-env info entries copied from the vector env's info arrays
INFO_KEYS = (
    "reward_progress",
    "reward_control",
    "reward_goal",
    "distance_to_goal",
    "x_position",
    "y_position",
    "is_success",
    "reward_shape",
    "task_error",
)


class SB3VecEnv(VecEnv):
    """A natively batched rolling env as an SB3 ``VecEnv`` (see the module docstring).

    Args:
        venv: the batched environment (``IcosahedronSRVectorEnv``, the MuJoCo one, or
            ``TensegritySRVectorEnv``).
    """

    def __init__(self, venv: RollingVectorEnv | TensegritySRVectorEnv) -> None:
        self.venv = venv
        self.render_mode = venv.render_mode
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        seeds = self._seeds if any(s is not None for s in self._seeds) else None
        options = self._options[0] if self._options and self._options[0] else None
        obs, _ = self.venv.reset(seed=seeds, options=options)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        assert self._actions is not None, "step_async first"
        obs, reward, terminated, truncated, info = self.venv.step(self._actions)
        self._actions = None
        done = terminated | truncated
        infos: list[dict[str, Any]] = [
            {k: info[k][i].item() for k in INFO_KEYS if k in info} for i in range(self.num_envs)
        ]
        for i in np.flatnonzero(done):
            infos[i]["terminal_observation"] = info["final_obs"][i]
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        return obs, reward.astype(np.float32), done, infos

    def close(self) -> None:
        self.venv.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        frames = self.venv.render()  # RGB arrays of the first envs, or None
        images: list[np.ndarray | None] = [None] * self.num_envs
        if frames is not None:
            images[: len(frames)] = [np.asarray(f) for f in frames]
        return images

    # ------------------------------------------------------------------ attributes
    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self.venv, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        return [False for _ in self._get_indices(indices)]
