"""The single-environment base shared by the identified env and its MuJoCo twin.

A :class:`RollingEnv` is a :class:`RollingTask` on a :class:`Simulator`: something
that holds one assembly's packed rod state (R, 13), steps it ``frame_skip`` physics
steps under a command (R, 3), and knows the MuJoCo model to draw it with. The two
environments differ only in their simulator, so their spaces, observations,
rewards, terminations, resets and their handling of bad input are the same code:
``step`` before the first ``reset`` raises :class:`gymnasium.error.ResetNeeded`, and
actions follow :data:`~tensegrity_env.envs.task.ACTION_POLICY`.
"""

from __future__ import annotations

from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from tensegrity_env.envs.rendering import SceneRenderer
from tensegrity_env.envs.task import RollingTask, check_action
from tensegrity_env.mjcf import MjcfAssembly
from tensegrity_env.rotations import rod_axes
from tensegrity_env.topology import Topology

#: how long the resting pose is settled from the face-down nominal pose [s]
SETTLE_SECONDS = 10.0


class Simulator(Protocol):
    """One assembly's physics, stepped a control step at a time."""

    topology: Topology
    control_dt: float

    def set_state(self, x: np.ndarray) -> None: ...

    def get_state(self) -> np.ndarray: ...

    def step(self, command: np.ndarray) -> None: ...

    def render_assembly(self) -> MjcfAssembly: ...


def settle(
    sim: Simulator,
    x0: np.ndarray,
    seconds: float = SETTLE_SECONDS,
    zero: np.ndarray | None = None,
) -> np.ndarray:
    """The state after ``seconds`` without control from ``x0`` (R, 13): the resting pose.

    ``zero`` is the simulator's command for "no control" (default: no force, (R, 3)).
    """
    sim.set_state(x0)
    zero = np.zeros((sim.topology.n_rods, 3)) if zero is None else zero
    for _ in range(max(1, round(seconds / sim.control_dt))):
        sim.step(zero)
    rest = sim.get_state()
    if not np.all(np.isfinite(rest)):
        raise RuntimeError("the model diverged while settling on the floor")
    return rest


class SceneEnv(gym.Env[np.ndarray, np.ndarray]):
    """A single environment drawn by MuJoCo's renderer: render modes and the renderer.

    Subclasses call :meth:`_init_scene`, keep the packed rod states (R, 13) in ``state``
    and say where the goal disc goes (:meth:`_marker`) and how large it is.
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array"], "render_fps": 20}  # noqa: RUF012
    state: np.ndarray

    def _init_scene(
        self, sim: Simulator, render_mode: str | None, width: int, height: int, radius: float
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None")
        self.metadata = {**self.metadata, "render_fps": round(1.0 / sim.control_dt)}
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)
        self._scene_sim, self._marker_radius = sim, float(radius)
        self._renderer: SceneRenderer | None = None

    def _marker(self) -> np.ndarray:
        """Where the goal disc is drawn, (2,) [m]."""
        raise NotImplementedError

    def start_options(self) -> dict[str, np.ndarray]:
        """``reset`` options that start an env (this one or its twin) where this one is."""
        raise NotImplementedError

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode (pass render_mode=...)")
            return None
        if self._renderer is None:
            self._renderer = SceneRenderer(
                self._scene_sim.render_assembly(), self.width, self.height, self._marker_radius
            )
        if self.render_mode == "rgb_array":
            return self._renderer.rgb_array(self.state, self._marker())
        self._renderer.human(self.state, self._marker())
        return None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class RollingEnv(SceneEnv):
    """A :class:`RollingTask` on one :class:`Simulator` (see the concrete envs' docs).

    ``step`` before the first ``reset`` raises :class:`gymnasium.error.ResetNeeded`.
    An action of the wrong shape, or with a NaN or infinite entry, raises ValueError
    naming the expected shape or the bad entries, before any physics runs; physics
    that diverges under finite actions ends the episode (terminated, reward 0,
    ``info["physics_diverged"]``).

    Args:
        sim: the physics.
        rest: the resting pose (R, 13) resets start from.
        task: the task definition.
        render_mode: ``"rgb_array"``, ``"human"`` or None.
        width, height: rendered image size [px].
    """

    def __init__(
        self,
        sim: Simulator,
        rest: np.ndarray,
        task: RollingTask,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
    ) -> None:
        self._init_scene(sim, render_mode, width, height, task.goal_radius)
        self.sim, self.task, self.rest = sim, task, np.array(rest, dtype=np.float64)
        self.n_rods = sim.topology.n_rods
        self.action_space: spaces.Box = spaces.Box(-1.0, 1.0, (3 * self.n_rods,), np.float32)
        n_obs = task.observation_size(self.n_rods)
        self.observation_space = spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
        self._axes = rod_axes(sim.topology.end_offsets)
        self.state = self.rest.copy()
        self.goal = np.zeros(2)
        self._distance = 0.0
        self._needs_reset = True

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Seeded reset; ``options`` may give ``"state"`` (R, 13) and ``"goal"`` (2,) [m].

        The random draws are made even when both are given, so the generator advances
        the same way whatever the options.
        """
        super().reset(seed=seed)
        x, goal = self.task.sample_reset(self.np_random, self.rest)
        options = options or {}
        if "state" in options:
            x = np.array(options["state"], dtype=np.float64).reshape(self.n_rods, 13)
        if "goal" in options:
            goal = np.array(options["goal"], dtype=np.float64).reshape(2)
        self.sim.set_state(x)
        self.state, self.goal = self.sim.get_state(), goal
        self._distance = float(self.task.distance(self.state[None], self.goal[None])[0])
        self._needs_reset = False
        return self._obs(), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = check_action(action, self.action_space.shape)
        command = self.task.commands(a[None], self.n_rods)
        self.sim.step(command[0])
        x = self.sim.get_state()
        if not np.all(np.isfinite(x)):
            # the physics blew up: end the episode on the last finite state
            info = {**self._info(), "physics_diverged": True}
            info.update({k: 0.0 for k in ("reward_progress", "reward_control", "reward_goal")})
            return self._obs(), 0.0, True, False, info
        self.state = x
        prev = np.array([self._distance])
        dist = self.task.distance(x[None], self.goal[None])
        reward, reached, terms = self.task.reward(prev, dist, command)
        self._distance = float(dist[0])
        info = {**self._info(), **{k: float(v[0]) for k, v in terms.items()}}
        info["is_success"] = bool(reached[0])
        if self.render_mode == "human":
            self.render()
        return self._obs(), float(reward[0]), bool(reached[0]), False, info

    def _marker(self) -> np.ndarray:
        return self.goal

    def start_options(self) -> dict[str, np.ndarray]:
        return {"state": self.state.copy(), "goal": self.goal.copy()}

    @property
    def distance_to_goal(self) -> float:
        """Horizontal distance from the structure's centre to the goal [m]."""
        return self._distance

    # ------------------------------------------------------------------ helpers
    def _obs(self) -> np.ndarray:
        result: np.ndarray = self.task.observe(self.state[None], self.goal[None], self._axes)[0]
        return result

    def _info(self) -> dict[str, Any]:
        c = self.task.centre(self.state[None])[0]
        return {
            "distance_to_goal": self._distance,
            "x_position": float(c[0]),
            "y_position": float(c[1]),
            "goal": self.goal.copy(),
        }
