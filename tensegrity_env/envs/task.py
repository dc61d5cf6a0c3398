"""The rolling task, shared by the identified env, its MuJoCo twin and the vector env.

Everything here works on packed rod states ``x`` (B, R, 13) float64 (rows ``p``,
``v``, ``q`` (w x y z), ``omega``, world frame; see
:mod:`tensegrity_env.envs.physics`) and goals ``(B, 2)`` [m], so one definition of
the reset distribution, action scaling, observation, reward and termination serves
every environment and any batch size.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np

from tensegrity_env.rotations import np_quat_mul, np_rotate

#: entries of ``info`` and of each vector-env info array, per step
REWARD_TERMS = ("reward_progress", "reward_control", "reward_goal")

#: what every environment (single, twin, vector) does with an action, stated once
ACTION_POLICY = (
    "An action of the wrong shape, or with a NaN or infinite entry, raises ValueError "
    "(naming the expected shape or the bad entries) before any physics runs; finite "
    "actions outside [-1, 1] are clipped. Physics that diverges under finite actions "
    "ends the episode (terminated, reward 0, info['physics_diverged'])."
)


def check_action(
    action: Any, shape: tuple[int, ...], what: str = "3 force commands per rod"
) -> np.ndarray:
    """``action`` as float64 of ``shape``, else ValueError (see :data:`ACTION_POLICY`).

    Args:
        action: the action(s) given to ``step``.
        shape: the expected shape: ``(3R,)`` for one env, ``(N, 3R)`` for N envs.
        what: what the action's entries are, for the message.
    """
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"action must be numbers of shape {shape}") from None
    if a.shape != shape:
        raise ValueError(f"action has shape {a.shape}, expected {shape} ({what})")
    if np.isfinite(a).all():  # the common case, checked in one call
        return a
    bad = np.argwhere(~np.isfinite(a))
    if bad.size:
        entries = [int(i[0]) if a.ndim == 1 else tuple(int(j) for j in i) for i in bad[:6]]
        more = f" and {len(bad) - 6} more" if len(bad) > 6 else ""
        raise ValueError(f"action entries {entries}{more} are NaN or infinite")
    return a


class TaskOptions(TypedDict, total=False):
    """The task's keyword arguments every environment takes (see :class:`RollingTask`)."""

    goal_distance: tuple[float, float]
    goal_radius: float
    max_command: float
    progress_weight: float
    control_weight: float
    goal_bonus: float
    reset_noise_scale: float


def make_task(control_dt: float, options: Mapping[str, Any]) -> RollingTask:
    """The :class:`RollingTask` of an environment: its ``control_dt`` and task options.

    Raises:
        TypeError: an option that is not a :class:`TaskOptions` key (as for a wrong keyword).
    """
    unknown = sorted(set(options) - set(TaskOptions.__annotations__))
    if unknown:
        names = ", ".join(TaskOptions.__annotations__)
        raise TypeError(f"unknown task option(s) {unknown}; the task takes {names}")
    opts = dict(options)
    if "goal_distance" in opts:
        opts["goal_distance"] = tuple(float(d) for d in opts["goal_distance"])
    return RollingTask(control_dt=control_dt, **opts)


@dataclass(frozen=True)
class RollingTask:
    """Roll the structure's centre to a goal on the floor.

    Attributes:
        goal_distance: range of the goal's initial distance from the centre [m].
        goal_radius: the goal is reached when the centre (mean of the rod centres)
            is within this horizontal distance [m]: the episode terminates.
        max_command: largest command norm per rod [command units]; the applied force
            is ``h * f_u``, so with the twin's ``h = 2.5`` and six rods the control can
            push with at most ``6 * 2.5 * max_command`` N (30 N, a quarter of the
            117 N weight): never enough to lift the structure.
        progress_weight: reward per m/s of approach to the goal.
        control_weight: penalty for using the whole command range on every rod.
        goal_bonus: reward on reaching the goal.
        reset_noise_scale: size of the uniform perturbation of the resting pose at
            reset: positions [m] and quaternion components, and the std of velocity
            noise [m/s, rad/s].
        control_dt: seconds per env step (``frame_skip * dt``).
    """

    goal_distance: tuple[float, float] = (2.0, 4.0)
    goal_radius: float = 0.3
    max_command: float = 2.0
    progress_weight: float = 1.0
    control_weight: float = 0.1
    goal_bonus: float = 10.0
    reset_noise_scale: float = 5e-3
    control_dt: float = 0.05

    def __post_init__(self) -> None:
        lo, hi = self.goal_distance
        if not 0 <= lo <= hi:
            raise ValueError(f"goal_distance must be 0 <= low <= high, got {self.goal_distance}")
        if self.goal_radius <= 0 or self.max_command <= 0 or self.control_dt <= 0:
            raise ValueError("goal_radius, max_command and control_dt must be positive")
        if self.reset_noise_scale < 0:
            raise ValueError("reset_noise_scale must be >= 0")

    # ------------------------------------------------------------------ actions
    def commands(self, action: np.ndarray, n_rods: int) -> np.ndarray:
        """Commands f_u (B, R, 3) from actions (B, 3R) in [-1, 1].

        Each rod's 3-vector is clipped to the unit ball, then scaled by ``max_command``.
        """
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0).reshape(-1, n_rods, 3)
        norm = np.linalg.norm(a, axis=-1, keepdims=True)
        result: np.ndarray = self.max_command * a / np.maximum(norm, 1.0)
        return result

    # ------------------------------------------------------------------ observation
    @staticmethod
    def centre(x: np.ndarray) -> np.ndarray:
        """Mean of the rod centres, (B, 3) [m] (parameter-free, so equal in both envs)."""
        result: np.ndarray = x[..., 0:3].sum(axis=1) / x.shape[1]  # the mean, without np.mean's overhead
        return result

    @staticmethod
    def observation_size(n_rods: int) -> int:
        return 12 * n_rods + 3

    def observe(self, x: np.ndarray, goal: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """Observations (B, 12R + 3) float32; ``axes`` (R, 3): each rod's axis in its frame."""
        B = x.shape[0]
        c = self.centre(x)
        rel = x[..., 0:3] - c[:, None]
        axis = np_rotate(x[..., 6:10], axes)
        parts = [
            rel.reshape(B, -1),
            axis.reshape(B, -1),
            x[..., 3:6].reshape(B, -1),
            x[..., 10:13].reshape(B, -1),
            c[:, 2:3],
            goal - c[:, :2],
        ]
        return np.concatenate(parts, axis=1).astype(np.float32)

    def distance(self, x: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Horizontal distance from the centre to the goal, (B,) [m]."""
        result: np.ndarray = np.linalg.norm(goal - self.centre(x)[:, :2], axis=-1)
        return result

    # ------------------------------------------------------------------ reward
    def reward(
        self, prev_distance: np.ndarray, distance: np.ndarray, commands: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Reward (B,), success flags (B,) and each reward term (B,)."""
        reached = distance < self.goal_radius
        terms = {
            "reward_progress": self.progress_weight * (prev_distance - distance) / self.control_dt,
            "reward_control": -self.control_weight
            * (np.sum(commands**2, axis=-1).sum(axis=-1) / commands.shape[-2])
            / self.max_command**2,
            "reward_goal": self.goal_bonus * reached.astype(np.float64),
        }
        total = terms["reward_progress"] + terms["reward_control"] + terms["reward_goal"]
        return total, reached, terms

    # ------------------------------------------------------------------ reset
    def sample_reset(
        self, rng: np.random.Generator, rest: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """One initial state (R, 13) and goal (2,) drawn with ``rng``.

        The resting pose ``rest`` (R, 13) is turned by a uniform random yaw about its
        centre, centred at the origin and perturbed by ``reset_noise_scale``; the goal
        lies in a uniform random direction at a distance in ``goal_distance``. The
        draws are made in a fixed order from ``rng`` alone, so a seed fixes both.
        """
        R = rest.shape[0]
        eps = self.reset_noise_scale
        yaw = rng.uniform(0.0, 2.0 * np.pi)
        d_p = rng.uniform(-eps, eps, (R, 3))
        d_q = rng.uniform(-eps, eps, (R, 4))
        d_v = eps * rng.standard_normal((R, 3))
        d_w = eps * rng.standard_normal((R, 3))
        heading = rng.uniform(0.0, 2.0 * np.pi)
        dist = rng.uniform(*self.goal_distance)

        c, s = np.cos(yaw), np.sin(yaw)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        q_yaw = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
        centre = rest[:, 0:3].mean(axis=0) * np.array([1.0, 1.0, 0.0])
        x = np.empty_like(rest)
        x[:, 0:3] = (rest[:, 0:3] - centre) @ rz.T + d_p
        x[:, 3:6] = rest[:, 3:6] @ rz.T + d_v
        q = np_quat_mul(np.broadcast_to(q_yaw, (R, 4)), rest[:, 6:10]) + d_q
        x[:, 6:10] = q / np.linalg.norm(q, axis=-1, keepdims=True)
        x[:, 10:13] = rest[:, 10:13] @ rz.T + d_w
        goal = dist * np.array([np.cos(heading), np.sin(heading)])
        return x, goal
