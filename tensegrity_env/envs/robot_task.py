"""Tasks of the generic robot environments: what the robot senses, and what it is asked.

A cable-driven robot senses its end caps (a camera or motion capture), the lengths of
its cables (length sensors) and its motors' rest lengths (encoders); it never sees its
rods' velocities or orientations. :class:`RobotSensors` turns packed rod states ``x``
(B, R, 13) (rows ``p``, ``v``, ``q`` (w x y z), ``omega``, world frame) and winch states
(B, W, 2) into those readings. Two tasks share them:

* :class:`GoalTask`: move the structure's centre to a goal on the floor; it reuses
  :class:`~tensegrity_env.envs.task.RollingTask`'s reset distribution, distance, reward
  and success test, with motor commands in place of force commands.
* :class:`ShapeTask`: hold target lengths of the wound cables.

Both take motor commands in [-1, 1] (one per winch, or per cable actuator) and work on
any batch size, so the single envs and their twins run the same code. ``observe`` and
``error`` state the readings in NumPy; ``sense`` gives both (and the rods' centre) in one
call of the C kernel where it builds (:mod:`~tensegrity_env.envs.robot_sense`: the same
numbers), which is what the environments call every step.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from tensegrity_env.envs.robot_sense import NativeSense, native_sense
from tensegrity_env.envs.task import RollingTask, TaskOptions
from tensegrity_env.topology import Topology

#: the task names the generic environments take
TASKS = ("goal", "shape")
#: the goal task's defaults for a robot that crawls by winding its cables (a prism
#: winding at 0.1 m/s moves its centre a few cm/s: goals within reach of a 15 s episode)
GOAL_DEFAULTS: dict[str, Any] = {"goal_distance": (0.5, 1.0), "goal_radius": 0.2}


def _rotation_forms() -> np.ndarray:
    """The rotation matrix of a unit quaternion q (w x y z) as quadratic forms,
    ``R_ij = q' A_ij q``: A (3, 3, 4, 4), MuJoCo's mju_quat2Mat."""
    A = np.zeros((3, 3, 4, 4))
    A[0, 0] = A[1, 1] = A[2, 2] = np.eye(4)
    for i, (a, b) in enumerate(((1, 1), (2, 2), (3, 3))):  # diagonal: w^2 + x_i^2 - others
        for k in (1, 2, 3):
            A[i, i, k, k] = 1.0 if k == a == b else -1.0
    # off the diagonal: 2 (x_i x_j -/+ w x_k), written symmetrically
    for i, j, k, sign in ((0, 1, 3, -1), (1, 0, 3, 1), (0, 2, 2, 1), (2, 0, 2, -1),
                          (1, 2, 1, -1), (2, 1, 1, 1)):  # fmt: skip
        A[i, j, i + 1, j + 1] = A[i, j, j + 1, i + 1] = 1.0
        A[i, j, 0, k] = A[i, j, k, 0] = sign
    return A


@dataclass(frozen=True)
class RobotSensors:
    """What the robot measures, from packed rod states (B, R, 13) and winch states (B, W, 2).

    Attributes:
        topology: the robot's graph (end caps, cables, winches).
    """

    topology: Topology
    #: the topology's arrays a reading needs, taken once (a reading runs every env step)
    _rod: np.ndarray = field(init=False, repr=False, compare=False)
    _node_rod: np.ndarray = field(init=False, repr=False, compare=False)
    _lever: np.ndarray = field(init=False, repr=False, compare=False)
    _slot: np.ndarray = field(init=False, repr=False, compare=False)
    _fixed: np.ndarray = field(init=False, repr=False, compare=False)
    _ends: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        t = self.topology
        rod = t.node_rod
        on = rod >= 0
        offsets = t.node_offsets
        object.__setattr__(self, "_rod", np.flatnonzero(on))
        # a node's offset R(q) o in the world is linear in its rod's products q_a q_b: per
        # rod, its nodes' (16, 3) levers side by side (slot j of rod r: its j-th node)
        node_rod = rod[on]
        slot = np.array([np.sum(node_rod[:k] == r) for k, r in enumerate(node_rod)], dtype=int)
        lever = np.zeros((t.n_rods, 16, max(slot.max(initial=-1) + 1, 1), 3))
        forms = np.einsum("ijab,kj->kabi", _rotation_forms(), offsets[on]).reshape(-1, 16, 3)
        lever[node_rod, :, slot, :] = forms
        object.__setattr__(self, "_lever", lever.reshape(t.n_rods, 16, -1))
        object.__setattr__(self, "_slot", slot)
        object.__setattr__(self, "_fixed", offsets.copy())
        ends = (t.spring_nodes[:, 0].copy(), t.spring_nodes[:, 1].copy())
        object.__setattr__(self, "_ends", ends)
        object.__setattr__(self, "_node_rod", rod[on])

    def nodes(self, x: np.ndarray) -> np.ndarray:
        """Every node (end caps, anchors, attachment points), (B, N, 3) [m], world frame:
        :func:`~tensegrity_env.assemblies.node_positions` of the rod poses in ``x``."""
        rod, lead, R = self._node_rod, x.shape[:-2], x.shape[-2]
        q = x[..., 6:10].reshape(-1, R, 4)
        qq = (q[..., :, None] * q[..., None, :]).reshape(q.shape[0], R, 16)
        # one (B, 16) x (16, 3 slots) product per rod: its nodes' world offsets R(q) o
        turned = np.matmul(qq.swapaxes(0, 1), self._lever).reshape(R, q.shape[0], -1, 3)
        offsets = turned[rod, :, self._slot, :].swapaxes(0, 1)  # (B, K, 3)
        out = np.broadcast_to(self._fixed, (*lead, *self._fixed.shape)).copy()
        out[..., self._rod, :] = x[..., rod, 0:3] + offsets.reshape(*lead, -1, 3)
        return out

    def end_caps(self, x: np.ndarray) -> np.ndarray:
        """End-cap positions, (B, 2R, 3) [m], rod r's caps at 2r and 2r + 1."""
        return self.nodes(x)[..., : 2 * self.topology.n_rods, :]

    def cable_lengths(self, x: np.ndarray, nodes: np.ndarray | None = None) -> np.ndarray:
        """Every cable's length between its attachment points, (B, S) [m] (``nodes``:
        :meth:`nodes` of ``x`` where already computed)."""
        nodes = self.nodes(x) if nodes is None else nodes
        a, b = self._ends
        d = nodes[..., a, :] - nodes[..., b, :]
        lengths: np.ndarray = np.sqrt(np.einsum("...i,...i->...", d, d))
        return lengths

    def size(self) -> int:
        """Length of :meth:`read`'s output per robot."""
        t = self.topology
        return 6 * t.n_rods + 1 + t.n_springs + t.n_winches

    def read(self, x: np.ndarray, winch: np.ndarray) -> np.ndarray:
        """Sensor readings (B, 6R + 1 + S + W) [m]: end caps minus the centre (mean of the
        end caps), the centre's height, the cable lengths, the motors' rest lengths."""
        nodes = self.nodes(x)
        caps = nodes[..., : 2 * self.topology.n_rods, :]
        c = caps.sum(axis=-2, keepdims=True) / caps.shape[-2]  # their mean
        B = x.shape[0]
        parts = [(caps - c).reshape(B, -1), c[:, 0, 2:3], self.cable_lengths(x, nodes),
                 winch[..., 0]]  # fmt: skip
        return np.concatenate(parts, axis=1)


class RobotTask(Protocol):
    """What a generic environment asks of its task (batched over B)."""

    sensors: RobotSensors
    control_dt: float
    goal_radius: float

    def observation_size(self) -> int: ...

    def target_size(self) -> int: ...

    def sample_reset(
        self, rng: np.random.Generator, rest: np.ndarray, winch: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def observe(self, x: np.ndarray, winch: np.ndarray, target: np.ndarray) -> np.ndarray: ...

    def error(self, x: np.ndarray, target: np.ndarray) -> np.ndarray: ...

    def sense(
        self, x: np.ndarray, winch: np.ndarray, target: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def reward(
        self, prev: np.ndarray, error: np.ndarray, commands: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]: ...

    def reward_one(
        self, prev: float, error: float, command: np.ndarray
    ) -> tuple[float, bool, dict[str, float]]: ...


def _sense(
    task: GoalTask | ShapeTask, x: np.ndarray, winch: np.ndarray, target: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(observe, error, centre)`` of robots (B, ...): the kernel's where it builds."""
    if task.native is not None:
        return task.native(x, winch, target)
    return task.observe(x, winch, target), task.error(x, target), RollingTask.centre(x)


def _mean_square(command: np.ndarray) -> float:
    """The mean squared motor command of one robot (W,), summed as the batched rewards
    sum their (1, W) rows (NumPy's pairwise order), so both give the same bits."""
    return float(np.add.reduce(command * command) / command.shape[-1])


@dataclass(frozen=True)
class GoalTask:
    """Move the centre (mean of the rod centres) to a goal on the floor.

    The reset distribution, distance, reward terms (``reward_progress``,
    ``reward_control``, ``reward_goal``) and success test are
    :class:`~tensegrity_env.envs.task.RollingTask`'s with ``max_command = 1``: the
    commands are the motors' own, in [-1, 1]. The target is the goal (B, 2) [m].
    """

    sensors: RobotSensors
    rolling: RollingTask
    #: the readings in C (None: NumPy's, where the kernel does not build)
    native: NativeSense | None = field(default=None, repr=False, compare=False)

    @property
    def control_dt(self) -> float:
        return self.rolling.control_dt

    @property
    def goal_radius(self) -> float:
        return self.rolling.goal_radius

    def observation_size(self) -> int:
        return self.sensors.size() + 2

    def target_size(self) -> int:
        return 2

    def sample_reset(
        self, rng: np.random.Generator, rest: np.ndarray, winch: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Initial rod state (R, 13) and goal (2,) [m] (``RollingTask.sample_reset``)."""
        return self.rolling.sample_reset(rng, rest)

    def observe(self, x: np.ndarray, winch: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Sensor readings and the goal minus the centre (x, y) [m], (B, n_obs) float32."""
        c = self.rolling.centre(x)
        return np.concatenate([self.sensors.read(x, winch), target - c[:, :2]], 1).astype(
            np.float32
        )

    def error(self, x: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Horizontal distance from the centre to the goal, (B,) [m]."""
        return self.rolling.distance(x, target)

    def sense(
        self, x: np.ndarray, winch: np.ndarray, target: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`observe` (B, n_obs), :meth:`error` (B,) and the centre (B, 3) [m]."""
        return _sense(self, x, winch, target)

    def reward(
        self, prev: np.ndarray, error: np.ndarray, commands: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Reward (B,), success (B,) and terms from distances before/after and commands (B, W)."""
        return self.rolling.reward(prev, error, commands[..., None])

    def reward_one(
        self, prev: float, error: float, command: np.ndarray
    ) -> tuple[float, bool, dict[str, float]]:
        """:meth:`reward` of one robot (command (W,)), in floats: the same numbers."""
        r = self.rolling
        reached = error < r.goal_radius
        terms = {
            "reward_progress": r.progress_weight * (prev - error) / r.control_dt,
            "reward_control": -r.control_weight * _mean_square(command) / r.max_command**2,
            "reward_goal": r.goal_bonus * float(reached),
        }
        total = terms["reward_progress"] + terms["reward_control"] + terms["reward_goal"]
        return total, reached, terms


@dataclass(frozen=True)
class ShapeTask:
    """Hold target lengths of the wound cables (a shape).

    At reset each wound cable's target is its length in the resting pose times a factor
    drawn uniformly in ``1 ± shape_range``. The observation ends with the targets minus
    the wound cables' lengths (W,) [m]. Reward terms: ``reward_shape`` = -``shape_weight``
    x the largest absolute length error [m]; ``reward_control`` = -``control_weight`` x the
    mean squared command. ``info["is_success"]`` while every error is within
    ``shape_tolerance``; the episode does not end on success (the shape is to be held).

    Attributes:
        shape_range: relative spread of the targets around the resting lengths.
        shape_tolerance: largest length error that counts as holding the shape [m].
        shape_weight: penalty per m of the largest length error.
        control_weight: penalty for using the whole command range on every motor.
        reset_noise_scale: perturbation of the resting pose at reset (as
            :class:`~tensegrity_env.envs.task.RollingTask`).
        control_dt: seconds per env step.
    """

    sensors: RobotSensors
    shape_range: float = 0.1
    shape_tolerance: float = 0.01
    shape_weight: float = 10.0
    control_weight: float = 0.1
    reset_noise_scale: float = 5e-3
    control_dt: float = 0.05
    goal_radius: float = field(default=0.0, init=False)
    #: the readings in C (None: NumPy's, where the kernel does not build)
    native: NativeSense | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (0 <= self.shape_range < 1 and self.shape_tolerance > 0 and self.control_dt > 0):
            raise ValueError(
                "shape_range must be in [0, 1), shape_tolerance and control_dt positive"
            )

    def _wound(self, x: np.ndarray) -> np.ndarray:
        return self.sensors.cable_lengths(x)[..., list(self.sensors.topology.winches)]

    def observation_size(self) -> int:
        return self.sensors.size() + self.sensors.topology.n_winches

    def target_size(self) -> int:
        return self.sensors.topology.n_winches

    def sample_reset(
        self, rng: np.random.Generator, rest: np.ndarray, winch: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Initial rod state (R, 13) (the resting pose, perturbed) and targets (W,) [m]."""
        still = RollingTask(goal_distance=(0.0, 0.0), reset_noise_scale=self.reset_noise_scale)
        x, _ = still.sample_reset(rng, rest)
        factor = rng.uniform(1 - self.shape_range, 1 + self.shape_range, winch.shape[0])
        return x, self._wound(rest[None])[0] * factor

    def observe(self, x: np.ndarray, winch: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Sensor readings and the targets minus the wound lengths, (B, n_obs) float32."""
        gap = target - self._wound(x)
        return np.concatenate([self.sensors.read(x, winch), gap], 1).astype(np.float32)

    def error(self, x: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Largest absolute length error of the wound cables, (B,) [m]."""
        result: np.ndarray = np.abs(target - self._wound(x)).max(axis=-1)
        return result

    def sense(
        self, x: np.ndarray, winch: np.ndarray, target: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`observe` (B, n_obs), :meth:`error` (B,) and the rods' centre (B, 3) [m]."""
        return _sense(self, x, winch, target)

    def reward(
        self, prev: np.ndarray, error: np.ndarray, commands: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Reward (B,), success (B,) and terms; ``error`` is :meth:`error`'s (B,)."""
        held = error <= self.shape_tolerance
        terms = {
            "reward_shape": -self.shape_weight * error,
            "reward_control": -self.control_weight
            * ((commands**2).sum(axis=-1) / commands.shape[-1]),
        }
        return terms["reward_shape"] + terms["reward_control"], held, terms

    def reward_one(
        self, prev: float, error: float, command: np.ndarray
    ) -> tuple[float, bool, dict[str, float]]:
        """:meth:`reward` of one robot (command (W,)), in floats: the same numbers."""
        terms = {
            "reward_shape": -self.shape_weight * error,
            "reward_control": -self.control_weight * _mean_square(command),
        }
        return terms["reward_shape"] + terms["reward_control"], error <= self.shape_tolerance, terms


#: the options each task takes, besides ``control_dt``
SHAPE_OPTIONS = ("shape_range", "shape_tolerance", "shape_weight", "control_weight",
                 "reset_noise_scale")  # fmt: skip


def make_robot_task(
    name: str, topology: Topology, control_dt: float, options: Mapping[str, Any]
) -> GoalTask | ShapeTask:
    """The task ``name`` (``"goal"`` or ``"shape"``) for a robot, with its options (the
    goal task's defaults: :data:`GOAL_DEFAULTS`).

    Raises:
        ValueError: an unknown task name. TypeError: an option the task does not take.
    """
    sensors = RobotSensors(topology)
    if name == "goal":
        known = set(TaskOptions.__annotations__) - {"max_command"}
        unknown = sorted(set(options) - known)
        if unknown:
            raise TypeError(f"unknown goal-task option(s) {unknown}; it takes {sorted(known)}")
        opts = {**GOAL_DEFAULTS, **options}
        if "goal_distance" in opts:
            opts["goal_distance"] = tuple(float(d) for d in opts["goal_distance"])
        rolling = RollingTask(control_dt=control_dt, max_command=1.0, **opts)
        return GoalTask(sensors, rolling, native_sense(topology, "goal"))
    if name == "shape":
        unknown = sorted(set(options) - set(SHAPE_OPTIONS))
        if unknown:
            raise TypeError(
                f"unknown shape-task option(s) {unknown}; it takes {list(SHAPE_OPTIONS)}"
            )
        return ShapeTask(sensors, control_dt=control_dt, native=native_sense(topology, "shape"),
                         **options)  # fmt: skip
    raise ValueError(f"task must be one of {TASKS}, got {name!r}")
