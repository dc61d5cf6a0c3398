"""``TensegritySR-v0`` and ``TensegrityMJ-v0``: any winch-driven robot, identified and in MuJoCo.

:class:`RobotEnv` is a :mod:`~tensegrity_env.envs.robot_task` task on one simulator of
:mod:`~tensegrity_env.envs.robot_physics`; the two registered environments differ only
in their simulator, so their spaces, observations, rewards, resets and handling of bad
input are the same code (bad actions as :data:`~tensegrity_env.envs.task.ACTION_POLICY`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from tensegrity_env.envs.base import SceneEnv
from tensegrity_env.envs.robot_faces import check_share, start_pose
from tensegrity_env.envs.robot_motors import MotorTargets, check_flag
from tensegrity_env.envs.robot_physics import MJRobotSimulator, SRRobotSimulator
from tensegrity_env.envs.robot_task import GoalTask, ShapeTask, make_robot_task
from tensegrity_env.envs.task import REWARD_TERMS, check_action
from tensegrity_env.mjcf import MjcfAssembly
from tensegrity_env.topology import Topology

#: reward terms of either task, each in ``info`` (0 where the task has none)
ROBOT_REWARD_TERMS = (*REWARD_TERMS, "reward_shape")


class RobotSimulator(Protocol):
    """One robot's physics, stepped a control step at a time under motor commands."""

    topology: Topology
    control_dt: float
    command_shape: tuple[int]
    asm: MjcfAssembly

    def set_state(self, x: np.ndarray, winch: np.ndarray | None = None) -> None: ...

    def get_state(self) -> np.ndarray: ...

    def get_winch(self) -> np.ndarray: ...

    def step(self, command: np.ndarray) -> None: ...

    def rest_pose(self) -> np.ndarray: ...

    def tipped_poses(self) -> np.ndarray: ...

    def render_assembly(self) -> MjcfAssembly: ...


class RobotEnv(SceneEnv):
    """A robot task on one simulator (tables: :class:`TensegritySREnv`).

    Args:
        sim: the physics. task: ``"goal"`` or ``"shape"``.
        render_mode: ``"rgb_array"``, ``"human"`` or None. width, height: image size [px].
        tipped_starts: share of episodes starting on another face
            (:func:`~tensegrity_env.envs.robot_faces.start_pose`; 0: none).
        motor_targets: actions are target rest lengths, turned into motor commands by
            :class:`~tensegrity_env.envs.robot_motors.MotorTargets` (False: commands).
        **options: the task's options (:func:`~tensegrity_env.envs.robot_task.make_robot_task`).
    """

    def __init__(
        self,
        sim: RobotSimulator,
        task: str = "goal",
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        tipped_starts: float = 0.0,
        motor_targets: bool = False,
        **options: Any,
    ) -> None:
        self.sim = sim
        # the robot's own motor controller where actions are targets (None: commands)
        self.motors = (MotorTargets.of(sim.asm.params, sim.control_dt)
                       if check_flag(motor_targets) else None)  # fmt: skip
        self.tipped_starts = check_share(tipped_starts)
        # the other faces' resting poses, settled once (only where episodes start on them)
        self.tipped = sim.tipped_poses() if self.tipped_starts > 0 else None
        self.task: GoalTask | ShapeTask = make_robot_task(task, sim.topology, sim.control_dt,
                                                          options)  # fmt: skip
        self.rest = sim.rest_pose()
        self._init_scene(sim, render_mode, width, height, max(self.task.goal_radius, 1e-3))
        n_motors = sim.command_shape[0]
        self.action_space: spaces.Box = spaces.Box(-1.0, 1.0, (n_motors,), np.float32)
        n_obs = self.task.observation_size()
        self.observation_space = spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
        self.state = self.rest.copy()
        sim.set_state(self.rest)
        self.winch = sim.get_winch()
        self.target = np.zeros(self.task.target_size())
        self._error = 0.0
        self._centre = self.state[:, 0:3].sum(axis=0) / self.state.shape[0]
        self._no_terms = dict.fromkeys(ROBOT_REWARD_TERMS, 0.0)
        # the readings of this one robot in C where the kernel builds (the batch's numbers)
        self._read_one = None if self.task.native is None else self.task.native.one()
        self._needs_reset = True

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Seeded reset; ``options`` may give ``"state"`` (R, 13), ``"winch"`` (W, 2)
        [m, m/s] and ``"target"`` (the goal (2,) [m], or the target lengths (W,) [m])."""
        super().reset(seed=seed)
        self.sim.set_state(self.rest)
        pose = start_pose(self.np_random, self.tipped_starts, self.rest, self.tipped)
        x, target = self.task.sample_reset(self.np_random, pose, self.sim.get_winch())
        options = options or {}
        R, size = self.sim.topology.n_rods, self.task.target_size()
        if "state" in options:
            x = np.array(options["state"], dtype=np.float64).reshape(R, 13)
        if "target" in options:
            target = np.array(options["target"], dtype=np.float64).reshape(size)
        winch = options.get("winch")
        self.sim.set_state(x, None if winch is None else np.asarray(winch, float).reshape(-1, 2))
        self.state, self.winch, self.target = self.sim.get_state(), self.sim.get_winch(), target
        obs = self._sense()
        self._needs_reset = False
        return obs, self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One control step: the task's batched code on one robot, read in one call
        (:meth:`~tensegrity_env.envs.robot_task.GoalTask.sense`) and rewarded in floats
        (``reward_one``): the same numbers as the batch of one."""
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = check_action(action, self.action_space.shape, "one command per motor")
        command = np.minimum(np.maximum(a, -1.0), 1.0)  # np.clip's values, in fewer calls
        if self.motors is not None:  # a target: the speed command that goes there
            command = self.motors.commands(command, self.winch[:, 0])
        self.sim.step(command)
        x = self.sim.get_state()
        if not np.isfinite(x).all():
            # the physics blew up: end the episode on the last finite state
            obs = self._sense()  # of the last finite state
            info = {**self._info(), "physics_diverged": True, **self._no_terms}
            return obs, 0.0, True, False, info
        self.state, self.winch = x, self.sim.get_winch()
        prev = self._error
        obs = self._sense()
        reward, success, terms = self.task.reward_one(prev, self._error, command)
        info = self._info()
        info.update(self._no_terms)
        info.update(terms)
        info["is_success"] = success
        terminated = success and isinstance(self.task, GoalTask)
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, False, info

    def start_options(self) -> dict[str, np.ndarray]:
        return {
            "state": self.state.copy(),
            "winch": self.winch.copy(),
            "target": self.target.copy(),
        }

    # ------------------------------------------------------------------ helpers
    def _marker(self) -> np.ndarray:
        """Where the renderer draws the goal disc: the goal, or under the centre (shape)."""
        if isinstance(self.task, GoalTask):
            return self.target
        result: np.ndarray = self.state[:, 0:2].mean(axis=0)
        return result

    def _sense(self) -> np.ndarray:
        """Read the robot now: its observation; the task error and the rods' centre kept."""
        if self._read_one is not None:
            obs, self._error, self._centre = self._read_one(self.state, self.winch, self.target)
            return obs
        batch = self.task.sense(self.state[None], self.winch[None], self.target[None])
        self._error, self._centre = float(batch[1][0]), batch[2][0]
        result: np.ndarray = batch[0][0]
        return result

    def _info(self) -> dict[str, Any]:
        return {
            "task_error": self._error,
            "x_position": float(self._centre[0]),  # the rods' mean centre
            "y_position": float(self._centre[1]),
            "target": self.target.copy(),
        }


class TensegritySREnv(RobotEnv):
    """A winch-driven tensegrity robot on its identified model.

    The robot is an MJCF file whose cables are wound by winches (the shipped default:
    the lab 3-bar prism ``tensegrity_env/assets/lab_prism.xml``, three rods, nine
    cables, six of them wound at up to 0.1 m/s with a 30 ms motor lag, standing on a
    floor). The physics is the identified model of a params file (``model``; default:
    the robot file's own parameters and floor contact), stepped by the C kernel (the
    engine's physics and winding, to round-off; the PyTorch engine where the kernel does
    not apply) in float64 at the file's physics step (1 ms), ``frame_skip`` steps per
    action (20 Hz by default), on one CPU thread. ``TensegrityMJ-v0`` is the same robot and task in MuJoCo.

    **Action space** ``Box(-1, 1, (W,), float32)``: the motor command of each winch, in
    the file's winch order: the cable's rest length changes at ``u * v_max`` [m/s]
    (through the motor lag), within its range. With ``motor_targets=True`` each action
    is instead a target rest length within the winch's range (-1: ``l_min``, +1:
    ``l_max``), and the env's motor controller sends the motor the speed command
    ``u = clip((target - l0) / (v_max * dt), -1, 1)`` each control step ``dt``
    (:mod:`~tensegrity_env.envs.robot_motors`; the robot file's declared ``v_max`` and
    range, in both envs); rewards charge ``u``.

    **Observation space** ``Box(-inf, inf, (6R + 1 + S + W + k,), float32)``: what the
    robot's sensors and a camera give (never rod velocities or orientations):

    ===================  ===================================================  =====
    index                observation                                          unit
    ===================  ===================================================  =====
    0 .. 6R-1            end cap minus the centre c (mean of the end caps)    m
    6R                   height of c above the floor                          m
    6R+1 .. 6R+S         every cable's length                                 m
    6R+S+1 .. 6R+S+W     each winch's rest length (motor encoder)             m
    the last k           goal: goal minus the rods' centre (mean of their     m
                         centres of mass; x, y), k = 2; shape: target
                         minus length of each wound cable, k = W
    ===================  ===================================================  =====

    (27 + 6 + k entries for the shipped prism.)

    **Tasks** (``task=``): ``"goal"``: move the centre of the rods into a disc
    (``goal_radius``, default 0.2 m) around a goal drawn 0.5-1 m away; rewards as
    ``IcosahedronSR-v0`` (``reward_progress``, ``reward_control``, ``reward_goal``);
    ``terminated`` on reaching it. ``"shape"``: hold target lengths of the wound cables
    (each its resting length x ``1 ± shape_range``); ``reward_shape`` = -``shape_weight``
    x the largest length error [m], ``reward_control``; ``info["is_success"]`` while every
    error is within ``shape_tolerance``; no termination. Truncated at 300 steps
    (``gym.make``'s ``TimeLimit``). Each reward term in ``info``, and ``task_error``
    (distance to the goal, or largest cable-length error [m]).

    **Reset**: the model's resting pose, settled once from the file's pose with the
    winches at rest, turned by a random yaw and perturbed; winches at their declared
    rest lengths. ``reset(options={"state": x, "winch": w, "target": g})`` sets them
    explicitly (e.g. to start the twin in the same state). ``tipped_starts=p`` (a
    training option; default 0): a share ``p`` of the episodes start instead resting on
    one of the robot's other faces, drawn uniformly (each settled once by this env's
    own physics: :mod:`~tensegrity_env.envs.robot_faces`), turned, perturbed and given
    a goal around it in the same way; with 0 the resets are the task's own, bit for bit.

    **Bad input**: ``step`` before ``reset`` raises ``gymnasium.error.ResetNeeded``; an
    action of another shape or with NaN/infinite entries raises ``ValueError`` before
    any physics runs; a robot file without winches, or a model of another topology or
    without floor contact, raises ``InputError`` naming the file.

    Args:
        model: identified params file (None: the robot file's own parameters).
        robot: the robot's MJCF (None: the shipped lab 3-bar).
        task: ``"goal"`` or ``"shape"``.
        frame_skip: physics steps per action.
        render_mode, width, height: as ``IcosahedronSR-v0``.
        tipped_starts: share of episodes starting on another face (see Reset; 0-1).
        motor_targets: actions are target rest lengths (see Action space; default
            False: motor commands).
        **options: task options: goal: ``goal_distance``, ``goal_radius``,
            ``progress_weight``, ``control_weight``, ``goal_bonus``,
            ``reset_noise_scale``; shape: ``shape_range``, ``shape_tolerance``,
            ``shape_weight``, ``control_weight``, ``reset_noise_scale``.
    """

    #: what videos call this env
    label = "identified model (TensegritySR-v0)"

    def __init__(
        self,
        model: str | Path | None = None,
        robot: str | Path | None = None,
        task: str = "goal",
        frame_skip: int = 50,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        **options: Any,
    ) -> None:
        sim = SRRobotSimulator(model, robot, frame_skip, threads=1)
        super().__init__(sim, task, render_mode, width, height, **options)


class TensegrityMJEnv(RobotEnv):
    """The MuJoCo twin of :class:`TensegritySREnv`: the robot file itself in MuJoCo.

    The same spaces, tasks, rewards, resets and handling of bad input; the winches are
    wound by :class:`~tensegrity_env.mjcf.winches.MjWinches` (the tendons'
    ``springlength`` set from the winch state before every ``mj_step``).

    Args:
        robot: the robot's MJCF (None: the shipped lab 3-bar).
        task, frame_skip, render_mode, width, height, **options: as ``TensegritySR-v0``
            (``tipped_starts`` too: its other faces settled in MuJoCo).
    """

    #: what videos call this env
    label = "MuJoCo (TensegrityMJ-v0)"

    def __init__(
        self,
        robot: str | Path | None = None,
        task: str = "goal",
        frame_skip: int = 50,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        **options: Any,
    ) -> None:
        sim = MJRobotSimulator(robot, frame_skip)
        super().__init__(sim, task, render_mode, width, height, **options)
