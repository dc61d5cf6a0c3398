"""N generic robots in one batch: ``TensegritySR-v0`` in one engine call, and its twins.

:class:`TensegritySRVectorEnv` holds N rod states (N, R, 13) and winch states (N, W, 2)
and advances them with one batched call of the C kernel per env step (:meth:`NativeStepper.wind
<tensegrity_env.envs.physics.NativeStepper.wind>`, threads over the batch; the PyTorch
engine where the kernel does not apply);
:class:`TensegrityMJVectorEnv` steps N MuJoCo twins in one ``mujoco.rollout`` call
over threads (:class:`~tensegrity_env.envs.robot_rollout.MJRobotRollout`; one after
another where a wound cable is tension-only). Both are
Gymnasium :class:`~gymnasium.vector.VectorEnv` s with the single env's task code::

    gym.make_vec("TensegritySR-v0", num_envs=64, vectorization_mode="vector_entry_point")
    gym.make_vec("TensegrityMJ-v0", num_envs=64, vectorization_mode="vector_entry_point")

and wraps into Stable-Baselines3 with :class:`~tensegrity_env.envs.sb3.SB3VecEnv`.
Autoreset, seeding (env ``i`` gets ``seed + i``), ``final_obs``/``final_info`` and the
handling of bad input are those of
:class:`~tensegrity_env.envs.vector.IcosahedronSRVectorEnv`; reward terms,
``task_error``, ``is_success`` and the positions are arrays (N,) in ``infos``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from tensegrity_env.envs.robot_env import ROBOT_REWARD_TERMS
from tensegrity_env.envs.robot_faces import check_share, start_pose
from tensegrity_env.envs.robot_motors import MotorTargets, check_flag
from tensegrity_env.envs.robot_physics import MJRobotBatch, SRRobotSimulator
from tensegrity_env.envs.robot_rollout import MJRobotRollout
from tensegrity_env.envs.robot_task import GoalTask, make_robot_task
from tensegrity_env.envs.task import check_action
from tensegrity_env.envs.vector import MAX_EPISODE_STEPS, env_seeds, record_final


class RobotVectorEnv(VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """A robot task on N copies of a batch simulator (:class:`SRRobotSimulator` or
    :class:`MJRobotBatch`); subclasses build it and call :meth:`_setup`."""

    metadata: dict[str, Any] = {  # noqa: RUF012
        "render_modes": [],
        "render_fps": 20,
        "autoreset_mode": AutoresetMode.SAME_STEP,
    }

    sim: SRRobotSimulator | MJRobotBatch | MJRobotRollout

    def _setup(
        self, num_envs: int, task: str, max_episode_steps: int | None, options: dict[str, Any]
    ) -> None:
        opts = dict(options)
        self.tipped_starts = check_share(opts.pop("tipped_starts", 0.0))
        # the robot's own motor controller where actions are targets (None: commands)
        self.motors = (MotorTargets.of(self.sim.asm.params, self.sim.control_dt)
                       if check_flag(opts.pop("motor_targets", False)) else None)  # fmt: skip
        self.task = make_robot_task(task, self.sim.topology, self.sim.control_dt, opts)
        self.num_envs, self.max_episode_steps = int(num_envs), max_episode_steps
        self.render_mode = None
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.sim.control_dt)}
        self.rest = self.sim.rest_pose()
        # the other faces' resting poses, settled once (only where episodes start on them)
        self.tipped = self.sim.tipped_poses() if self.tipped_starts > 0 else None
        W = self.sim.command_shape[0]
        self.single_action_space: spaces.Box = spaces.Box(-1.0, 1.0, (W,), np.float32)
        n_obs = self.task.observation_size()
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs = [seeding.np_random(None)[0] for _ in range(self.num_envs)]
        self.targets = np.zeros((self.num_envs, self.task.target_size()))
        self._error = np.zeros(self.num_envs)
        self._centre = np.zeros((self.num_envs, 3))
        self._elapsed = np.zeros(self.num_envs, dtype=np.int64)
        self._last_obs = np.zeros((self.num_envs, n_obs), dtype=np.float32)
        self._needs_reset = True

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every env; ``seed`` an int (env i gets ``seed + i``) or one per env."""
        for i, s in enumerate(env_seeds(seed, self.num_envs)):
            if s is not None:
                self._rngs[i] = seeding.np_random(s)[0]
        obs = self._reset_envs(np.arange(self.num_envs))
        self._last_obs, self._needs_reset = obs, False
        return obs, self._base_info()

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = check_action(actions, (self.num_envs, *self.single_action_space.shape),
                         "one command per motor")  # fmt: skip
        commands = np.clip(a, -1.0, 1.0)
        if self.motors is not None:  # targets: the speed commands that go there
            commands = self.motors.commands(commands, self.sim.winch[..., 0])
        self.sim.step_batch(commands)
        x = self.sim.x
        bad = ~np.isfinite(x).all(axis=(1, 2))
        obs, error, self._centre = self.task.sense(x, self.sim.winch, self.targets)
        error[bad] = self._error[bad]
        reward, success, terms = self.task.reward(self._error, error, commands)
        reward[bad] = 0.0
        infos: dict[str, Any] = {k: np.zeros(self.num_envs) for k in ROBOT_REWARD_TERMS}
        for k, v in terms.items():
            v[bad] = 0.0
            infos[k] = v
        self._error = error
        self._elapsed += 1
        terminated = (success & isinstance(self.task, GoalTask)) | bad
        truncated = np.zeros(self.num_envs, dtype=bool)
        if self.max_episode_steps is not None:
            truncated = (self._elapsed >= self.max_episode_steps) & ~terminated
        obs[bad] = self._last_obs[bad]
        infos.update(self._base_info())
        infos["is_success"], infos["physics_diverged"] = success & ~bad, bad
        done = terminated | truncated
        if done.any():
            ended = record_final(obs, infos, done)
            obs[ended] = self._reset_envs(ended)
        self._last_obs = obs
        return obs, reward, terminated, truncated, infos

    def set_goal_distance(self, low: float, high: float) -> None:
        """Draw the goals of episodes reset from now on ``low``-``high`` m away (the goal
        task's ``goal_distance``; a training curriculum widens it as the policy learns).

        Raises:
            ValueError: the task has no goal (``shape``), or not ``0 <= low <= high``.
        """
        if not isinstance(self.task, GoalTask):
            raise ValueError("the shape task has no goal distance")
        rolling = replace(self.task.rolling, goal_distance=(float(low), float(high)))
        self.task = replace(self.task, rolling=rolling)

    def _reset_envs(self, idx: np.ndarray) -> np.ndarray:
        """Reset the envs ``idx`` (seeded draws); their observations (len(idx), n_obs)."""
        for i in idx:
            rng = self._rngs[i]
            pose = start_pose(rng, self.tipped_starts, self.rest, self.tipped)
            x, self.targets[i] = self.task.sample_reset(rng, pose, self.sim.rest_winch)
            self.sim.set_state(x, None, int(i))
        self._elapsed[idx] = 0
        obs, self._error[idx], self._centre[idx] = self.task.sense(
            self.sim.x[idx], self.sim.winch[idx], self.targets[idx]
        )
        return obs

    def _base_info(self) -> dict[str, Any]:
        c = self._centre  # the rods' mean centre, as the single env's info (copies: a reset
        # rewrites the ended envs' rows)
        return {"task_error": self._error.copy(), "x_position": c[:, 0].copy(),
                "y_position": c[:, 1].copy()}  # fmt: skip


def _batch_size(num_envs: int) -> int:
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    return int(num_envs)


class TensegritySRVectorEnv(RobotVectorEnv):
    """N :class:`~tensegrity_env.envs.robot_env.TensegritySREnv` in one kernel call.

    Args:
        num_envs: N.
        model, robot, task, frame_skip, **options: as ``TensegritySR-v0``.
        max_episode_steps: time limit (truncation) per episode, None for none.
        threads: the C kernel's threads over the batch (None: every available core);
            where PyTorch steps instead, its CPU threads (None: PyTorch's setting).
    """

    def __init__(
        self,
        num_envs: int = 1,
        model: str | Path | None = None,
        robot: str | Path | None = None,
        task: str = "goal",
        frame_skip: int = 50,
        max_episode_steps: int | None = MAX_EPISODE_STEPS,
        threads: int | None = None,
        **options: Any,
    ) -> None:
        n = _batch_size(num_envs)
        self.sim = SRRobotSimulator(model, robot, frame_skip, n, threads)
        self._setup(n, task, max_episode_steps, options)


class TensegrityMJVectorEnv(RobotVectorEnv):
    """N :class:`~tensegrity_env.envs.robot_env.TensegrityMJEnv` twins through
    ``mujoco.rollout`` (:class:`~tensegrity_env.envs.robot_rollout.MJRobotRollout`), or
    stepped one after another where a wound cable is tension-only
    (:class:`~tensegrity_env.envs.robot_physics.MJRobotBatch`).

    Args:
        num_envs: N. robot, task, frame_skip, **options: as ``TensegrityMJ-v0``.
        max_episode_steps: time limit (truncation) per episode, None for none.
        threads: rollout threads (None: every available core).
    """

    def __init__(
        self,
        num_envs: int = 1,
        robot: str | Path | None = None,
        task: str = "goal",
        frame_skip: int = 50,
        max_episode_steps: int | None = MAX_EPISODE_STEPS,
        threads: int | None = None,
        **options: Any,
    ) -> None:
        n = _batch_size(num_envs)
        try:
            self.sim = MJRobotRollout(robot, frame_skip, n, threads)
        except ValueError:  # a tension-only wound cable: not linear in its rest length
            self.sim = MJRobotBatch(robot, frame_skip, n)
        self._setup(n, task, max_episode_steps, options)

    def close_extras(self, **kwargs: Any) -> None:
        if isinstance(self.sim, MJRobotRollout):
            self.sim.close()
