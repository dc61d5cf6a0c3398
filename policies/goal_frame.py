"""The goal frame: observations and actions turned about z so that the goal lies on +x.

The rolling task is the same problem under any yaw: turning the whole scene about the
vertical turns the right action with it. A policy that sees the scene in a frame
whose x axis points at the goal (and whose actions are turned back into the world
frame) gets this symmetry by construction instead of having to learn it from data
in every direction. It is a property of the policy, equally applied in every env it
is trained or evaluated in (``goal_frame: true`` in the hyperparameters; recorded
with the model and applied again by :class:`~policies.artifacts.LoadedPolicy`).

Observation layout (:meth:`tensegrity_env.envs.task.RollingTask.observe`, R rods):
4R world 3-vectors (rod centre offsets, axes, velocities, angular velocities), the
centre height, then the goal vector (x, y) [m]. Each 3-vector and the goal vector are
turned by ``-yaw``, ``yaw = atan2(goal_y, goal_x)``; the height is unchanged. Actions
(R, 3) per rod are clipped to the unit ball (as the task does) and turned by ``+yaw``,
so the task's own clipping then changes nothing.

A generic robot (``TensegritySR-v0``'s goal task) observes ``caps`` end caps minus the
centre (``caps`` world 3-vectors) first and the goal vector (x, y) last; those are
turned, the rest (height, cable and motor lengths) is left as it is. Its actions are
motor commands, which do not depend on the frame: they are only clipped to [-1, 1].
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn


def _rods(n_obs: int) -> int:
    n_rods, rest = divmod(n_obs - 3, 12)
    if rest or n_rods < 1:
        raise ValueError(f"{n_obs} observations are not the rolling task's 12 R + 3")
    return n_rods


def goal_yaw(obs: np.ndarray) -> np.ndarray:
    """Heading of the goal from the centre, (B,) [rad], from observations (B, 12R + 3)."""
    return np.arctan2(obs[:, -1], obs[:, -2])


def _turn(v: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Turn x, y of vectors (B, K, 2 or 3) by ``yaw`` (B,) about z."""
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    out = v.copy()
    out[..., 0] = c * v[..., 0] - s * v[..., 1]
    out[..., 1] = s * v[..., 0] + c * v[..., 1]
    return out


def _vectors(n_obs: int, caps: int | None) -> int:
    """How many world 3-vectors an observation of ``n_obs`` entries starts with."""
    if caps is None:
        return 4 * _rods(n_obs)
    if caps < 1 or 3 * caps + 2 > n_obs:
        raise ValueError(f"{n_obs} observations cannot hold {caps} end caps and a goal")
    return int(caps)


def to_goal_frame(obs: np.ndarray, caps: int | None = None) -> np.ndarray:
    """Observations (B, n) (or one (n,)) seen from the goal frame.

    ``caps``: None for the rolling task's layout (n = 12R + 3); the number of end caps
    for a generic robot's goal task (its first 3 ``caps`` entries are turned).
    """
    single = obs.ndim == 1
    o = np.atleast_2d(np.asarray(obs, dtype=np.float64))
    B, n = o.shape
    V = _vectors(n, caps)
    yaw = -goal_yaw(o)
    out = o.copy()
    out[:, : 3 * V] = _turn(o[:, : 3 * V].reshape(B, V, 3), yaw).reshape(B, 3 * V)
    out[:, -2:] = _turn(o[:, None, -2:], yaw)[:, 0]
    out = out.astype(np.float32)
    return out[0] if single else out


def to_world_actions(actions: np.ndarray, obs: np.ndarray, caps: int | None = None) -> np.ndarray:
    """Goal-frame actions (B, 3R) for world observations ``obs`` as world actions (B, 3R).

    With ``caps`` (a generic robot) the actions are motor commands (B, W): clipped to
    [-1, 1] and otherwise unchanged.
    """
    if caps is not None:
        return np.clip(np.asarray(actions, dtype=np.float32), -1.0, 1.0)
    single = actions.ndim == 1
    a = np.atleast_2d(np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0))
    o = np.atleast_2d(obs)
    B = a.shape[0]
    a = a.reshape(B, -1, 3)
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1.0)
    out = _turn(a, goal_yaw(o)).reshape(B, -1).astype(np.float32)
    return out[0] if single else out


class VecGoalFrame(VecEnvWrapper):
    """A goal-task ``VecEnv`` seen from the goal frame (terminal observations too);
    ``caps`` as :func:`to_goal_frame`."""

    def __init__(self, venv: VecEnv, caps: int | None = None) -> None:
        super().__init__(venv)
        assert venv.observation_space.shape is not None  # a Box
        _vectors(int(np.prod(venv.observation_space.shape)), caps)
        self.caps = caps
        self._world_obs: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        obs = self.venv.reset()
        self._world_obs = np.asarray(obs)
        return to_goal_frame(self._world_obs, self.caps)

    def step_async(self, actions: np.ndarray) -> None:
        assert self._world_obs is not None, "reset first"
        self.venv.step_async(to_world_actions(actions, self._world_obs, self.caps))

    def step_wait(self) -> VecEnvStepReturn:
        obs, reward, done, infos = self.venv.step_wait()
        infos_out: list[dict[str, Any]] = []
        for info in infos:
            if "terminal_observation" in info:
                info = {
                    **info,
                    "terminal_observation": to_goal_frame(info["terminal_observation"], self.caps),
                }
            infos_out.append(info)
        self._world_obs = np.asarray(obs)
        return to_goal_frame(self._world_obs, self.caps), reward, done, infos_out
