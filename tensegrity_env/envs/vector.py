"""Natively batched vector environments: one physics call steps all N environments.

:class:`IcosahedronSRVectorEnv` holds the packed states of N assemblies (N, R, 13)
and advances them with one call of the identified model's stepper per env step
(the native kernel threads over the batch); :class:`IcosahedronMJVectorEnv` does
the same for the twin through MuJoCo's multi-threaded :mod:`mujoco.rollout`. Both
are Gymnasium :class:`~gymnasium.vector.VectorEnv` s with the single envs' task
code, reachable as::

    gym.make_vec("IcosahedronSR-v0", num_envs=4096, vectorization_mode="vector_entry_point")

Autoreset is Gymnasium's ``SAME_STEP`` mode: an environment that terminates or
truncates is reset inside the same ``step``; the returned observation is the new
episode's first, the last one is in ``infos["final_obs"]`` (an object array, None
for the others; ``infos["_final_obs"]`` is the mask) and the ending step's info in
``infos["final_info"]``. Reward terms, ``distance_to_goal``, ``is_success`` and the
positions are arrays (N,) in ``infos`` for every env. Environment ``i`` is seeded
with ``seed + i``, exactly as ``SyncVectorEnv`` seeds N single envs, so the batch
equals N single ``IcosahedronSR-v0`` envs stepped with the same actions, and bad
input is handled as by the single envs: ``step`` before ``reset`` raises
:class:`gymnasium.error.ResetNeeded`; actions of a shape other than ``(N, 3R)`` or
with NaN or infinite entries raise ValueError naming them, before any physics runs;
diverged physics ends that env's episode (``infos["physics_diverged"]``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Unpack

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from tensegrity_env.envs.mj_env import MJBatch, MJSimulator, twin_rest_pose
from tensegrity_env.envs.physics import Backend
from tensegrity_env.envs.rendering import SceneRenderer
from tensegrity_env.envs.sr_env import SRSimulator, rest_pose
from tensegrity_env.envs.task import RollingTask, TaskOptions, check_action, make_task
from tensegrity_env.mjcf import MjcfAssembly
from tensegrity_env.rotations import rod_axes
from tensegrity_env.topology import Topology

#: episode length of the registered envs: 300 steps of 50 ms = 15 s
MAX_EPISODE_STEPS = 300


def env_seeds(seed: int | list[int | None] | None, num_envs: int) -> list[int | None]:
    """One seed per env from ``reset``'s ``seed``: an int gives env i ``seed + i`` (as
    ``SyncVectorEnv`` seeds N single envs), a list is taken as it is, None seeds none."""
    if seed is None:
        return [None] * num_envs
    if isinstance(seed, int):
        return [seed + i for i in range(num_envs)]
    seeds = list(seed)
    if len(seeds) != num_envs:
        raise ValueError(f"{len(seeds)} seeds for {num_envs} envs")
    return seeds


def record_final(obs: np.ndarray, infos: dict[str, Any], done: np.ndarray) -> np.ndarray:
    """Put the ending envs' last observations and infos into ``infos`` (``SAME_STEP``
    autoreset: ``final_obs``, ``final_info`` and their masks) and return their indices."""
    ended = np.flatnonzero(done)
    final_obs = np.full(len(done), None, dtype=object)
    for i in ended:
        final_obs[i] = obs[i].copy()
    infos["final_info"] = {k: np.array(v, copy=True) for k, v in infos.items()}
    infos["_final_info"] = done.copy()
    infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
    return ended


class RollingVectorEnv(VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """The rolling task on N assemblies at once (subclasses supply the physics).

    Subclasses set ``self.topology``, ``self.rest`` (R, 13), ``self.control_dt`` and
    implement :meth:`_set_states`, :meth:`_get_states`, :meth:`_step_physics` and
    :meth:`_render_assembly`, then call :meth:`_setup`.
    """

    metadata: dict[str, Any] = {  # noqa: RUF012
        "render_modes": ["rgb_array"],
        "render_fps": 20,
        "autoreset_mode": AutoresetMode.SAME_STEP,
    }
    topology: Topology
    rest: np.ndarray
    control_dt: float

    def _setup(
        self,
        num_envs: int,
        task: RollingTask,
        max_episode_steps: int | None,
        render_mode: str | None,
        width: int,
        height: int,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError("vector envs render 'rgb_array' (env 0) or nothing")
        self.num_envs, self.task = int(num_envs), task
        self.max_episode_steps = max_episode_steps
        self.render_mode, self.width, self.height = render_mode, int(width), int(height)
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.control_dt)}
        R = self.n_rods = self.topology.n_rods
        self.single_action_space: spaces.Box = spaces.Box(-1.0, 1.0, (3 * R,), np.float32)
        n_obs = task.observation_size(R)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._axes = rod_axes(self.topology.end_offsets)
        self._rngs = [seeding.np_random(None)[0] for _ in range(self.num_envs)]
        self.goals = np.zeros((self.num_envs, 2))
        self._distance = np.zeros(self.num_envs)
        self._elapsed = np.zeros(self.num_envs, dtype=np.int64)
        self._last_obs = np.zeros((self.num_envs, n_obs), dtype=np.float32)
        self._renderer: SceneRenderer | None = None
        self._needs_reset = True

    # ------------------------------------------------------------------ physics hooks
    def _set_states(self, idx: np.ndarray, x: np.ndarray) -> None:
        raise NotImplementedError

    def _get_states(self) -> np.ndarray:
        """Packed states (N, R, 13); callers do not modify them."""
        raise NotImplementedError

    def _step_physics(self, commands: np.ndarray) -> None:
        raise NotImplementedError

    def _render_assembly(self) -> MjcfAssembly:
        raise NotImplementedError

    # ------------------------------------------------------------------ VectorEnv API
    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every env; ``seed`` an int (env i gets ``seed + i``) or one per env.

        ``options`` may give ``"state"`` (N, R, 13) and ``"goal"`` (N, 2).
        """
        for i, s in enumerate(env_seeds(seed, self.num_envs)):
            if s is not None:  # unseeded envs keep their generator, as single envs do
                self._rngs[i] = seeding.np_random(s)[0]
        idx = np.arange(self.num_envs)
        self._reset_envs(idx)
        options = options or {}
        if "state" in options or "goal" in options:
            x = np.array(options.get("state", self._get_states()), dtype=np.float64)
            self.goals[:] = np.array(options.get("goal", self.goals), dtype=np.float64)
            self._set_states(idx, x.reshape(self.num_envs, self.n_rods, 13))
            self._distance = self.task.distance(self._get_states(), self.goals)
        obs = self.task.observe(self._get_states(), self.goals, self._axes)
        self._last_obs = obs
        self._needs_reset = False
        return obs, self._base_info(self._get_states())

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = check_action(actions, (self.num_envs, *self.single_action_space.shape))
        commands = self.task.commands(a, self.n_rods)
        self._step_physics(commands)
        x = self._get_states()
        bad = ~np.all(np.isfinite(x), axis=(1, 2))
        dist = self.task.distance(x, self.goals)
        if bad.any():  # diverged physics ends those episodes on their last observation
            dist[bad] = self._distance[bad]
        reward, reached, terms = self.task.reward(self._distance, dist, commands)
        reward[bad] = 0.0
        for v in terms.values():
            v[bad] = 0.0
        self._distance = dist
        self._elapsed += 1
        terminated = reached | bad
        truncated = np.zeros(self.num_envs, dtype=bool)
        if self.max_episode_steps is not None:
            truncated = (self._elapsed >= self.max_episode_steps) & ~terminated
        obs = self.task.observe(x, self.goals, self._axes)
        if bad.any():
            obs[bad] = self._last_obs[bad]
        infos: dict[str, Any] = {**terms, **self._base_info(x)}
        infos["is_success"] = reached
        infos["physics_diverged"] = bad
        done = terminated | truncated
        if done.any():
            ended = record_final(obs, infos, done)
            self._reset_envs(ended)
            x = self._get_states()
            obs[ended] = self.task.observe(x[ended], self.goals[ended], self._axes)
        self._last_obs = obs
        return obs, reward, terminated, truncated, infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        """Env 0 as an RGB image, in a 1-tuple (None without ``render_mode``)."""
        if self.render_mode is None:
            return None
        if self._renderer is None:
            self._renderer = SceneRenderer(
                self._render_assembly(), self.width, self.height, self.task.goal_radius
            )
        return (self._renderer.rgb_array(self._get_states()[0], self.goals[0]),)

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ------------------------------------------------------------------ helpers
    def set_goal_distance(self, low: float, high: float) -> None:
        """Draw the goals of episodes reset from now on ``low``-``high`` m away (the task's
        ``goal_distance``; a training curriculum widens it as the policy learns).

        Raises:
            ValueError: not ``0 <= low <= high``.
        """
        self.task = replace(self.task, goal_distance=(float(low), float(high)))

    def _reset_envs(self, idx: np.ndarray) -> None:
        states = np.empty((len(idx), self.n_rods, 13))
        for k, i in enumerate(idx):
            states[k], self.goals[i] = self.task.sample_reset(self._rngs[i], self.rest)
        self._set_states(idx, states)
        self._elapsed[idx] = 0
        self._distance[idx] = self.task.distance(self._get_states()[idx], self.goals[idx])

    def _base_info(self, x: np.ndarray) -> dict[str, Any]:
        c = self.task.centre(x)
        return {
            "distance_to_goal": self._distance.copy(),
            "x_position": c[:, 0].copy(),
            "y_position": c[:, 1].copy(),
        }


class IcosahedronSRVectorEnv(RollingVectorEnv):
    """N ``IcosahedronSR-v0`` envs in one batch (see the module docstring).

    Args:
        num_envs: N.
        params_path, frame_skip, backend, device, **task: as
            :class:`~tensegrity_env.envs.sr_env.IcosahedronSREnv`.
        max_episode_steps: time limit (truncation) per episode, None for none.
        threads: CPU threads of the native kernel (None: every available core).
        render_mode: ``"rgb_array"`` (env 0) or None. width, height: image size [px].
    """

    def __init__(
        self,
        num_envs: int = 1,
        params_path: str | Path | None = None,
        frame_skip: int = 50,
        backend: Backend = "auto",
        device: str | torch.device = "cpu",
        max_episode_steps: int | None = MAX_EPISODE_STEPS,
        threads: int | None = None,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        **task: Unpack[TaskOptions],
    ) -> None:
        self.sim = SRSimulator(params_path, frame_skip, backend, device, num_envs, threads)
        self.topology, self.control_dt = self.sim.topology, self.sim.control_dt
        self.rest = rest_pose(self.sim)
        task_ = make_task(self.control_dt, task)
        self._setup(num_envs, task_, max_episode_steps, render_mode, width, height)

    def _set_states(self, idx: np.ndarray, x: np.ndarray) -> None:
        self.sim.x[idx] = x

    def _get_states(self) -> np.ndarray:
        return self.sim.x  # a view: read only

    def _step_physics(self, commands: np.ndarray) -> None:
        self.sim.step_batch(commands)

    def _render_assembly(self) -> MjcfAssembly:
        return self.sim.render_assembly()


class IcosahedronMJVectorEnv(RollingVectorEnv):
    """N ``IcosahedronMJ-v0`` twins stepped by :mod:`mujoco.rollout` (one call per step).

    MuJoCo's solver warm start is not carried between control steps (``rollout``
    starts each call cold), a difference from the single twin at solver tolerance.

    Args:
        num_envs: N. xml_path, frame_skip, **task: as ``IcosahedronMJ-v0``.
        max_episode_steps: time limit per episode. threads: rollout threads (None: all
        cores). render_mode, width, height: as :class:`IcosahedronSRVectorEnv`.
    """

    def __init__(
        self,
        num_envs: int = 1,
        xml_path: str | Path | None = None,
        frame_skip: int = 50,
        max_episode_steps: int | None = MAX_EPISODE_STEPS,
        threads: int | None = None,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        **task: Unpack[TaskOptions],
    ) -> None:
        sim = MJSimulator(frame_skip, xml_path)
        self.topology, self.control_dt = sim.topology, sim.control_dt
        self.rest = twin_rest_pose(sim)
        self.batch = MJBatch(sim, num_envs, threads)
        task_ = make_task(self.control_dt, task)
        self._setup(num_envs, task_, max_episode_steps, render_mode, width, height)

    def _set_states(self, idx: np.ndarray, x: np.ndarray) -> None:
        self.batch.set_states(idx, x)

    def _get_states(self) -> np.ndarray:
        return self.batch.get_states()

    def _step_physics(self, commands: np.ndarray) -> None:
        self.batch.step(commands)

    def _render_assembly(self) -> MjcfAssembly:
        return self.batch.asm

    def close_extras(self, **kwargs: Any) -> None:
        super().close_extras(**kwargs)
        self.batch.close()
