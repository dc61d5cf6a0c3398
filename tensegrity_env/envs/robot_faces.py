"""Resting poses of a robot on faces other than its base: tipped starts for training.

A robot that crawls by leaning tips over onto another face now and then; a policy
trained only from its resting pose on the base face rarely sees such a state. This
module finds the other faces it can rest on, physically: for every face of the convex
hull of the end caps in the resting pose, the pose is turned so that the face's outward
normal points down, lifted so that its lowest end cap is :data:`DROP` above where the
base pose's lowest end cap rests, and let settle on the floor for
:data:`~tensegrity_env.envs.robot_physics.ROBOT_SETTLE_SECONDS` with the winches at rest
and no command, by the simulator's own physics (the identified model or MuJoCo). Where a
face is not stable the robot rolls on to a stable one, so faces are told apart by the
set of end caps that touch the floor once settled (:func:`floor_caps`); one pose is kept
per set, the base's own set left out.

:func:`start_pose` picks an episode's starting pose from them (the ``tipped_starts``
option of the generic robot environments); with a share of 0 it draws nothing and
returns the base pose, so the environments' resets are unchanged.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import ConvexHull

from tensegrity_env.envs.robot_task import RobotSensors
from tensegrity_env.rotations import np_quat_mul, np_rotate
from tensegrity_env.topology import Topology

#: an end cap within this height of the lowest one touches the floor [m] (caps of one
#: face lie level to well under a cm on the lab 3-bar; the next cap is tens of cm up)
ON_FLOOR = 0.02
#: how far above its resting height a turned pose is dropped [m] (clear of the floor,
#: so it lands instead of starting inside it)
DROP = 5e-3


def floor_caps(topology: Topology, x: np.ndarray) -> frozenset[int]:
    """The end caps touching the floor in pose ``x`` (R, 13): the lowest one and those
    within :data:`ON_FLOOR` of it (indices as ``RobotSensors.end_caps``)."""
    z = RobotSensors(topology).end_caps(x[None])[0][:, 2]
    return frozenset(np.flatnonzero(z < z.min() + ON_FLOOR).tolist())


def _turn_to_down(normal: np.ndarray) -> np.ndarray:
    """The unit quaternion (w x y z) of the shortest turn taking ``normal`` (3,) to -z."""
    n = normal / np.linalg.norm(normal)
    down = np.array([0.0, 0.0, -1.0])
    axis = np.cross(n, down)
    s = np.linalg.norm(axis)
    if s < 1e-12:  # already down, or straight up (half a turn about x)
        return np.array([1.0, 0.0, 0.0, 0.0]) if n[2] < 0 else np.array([0.0, 1.0, 0.0, 0.0])
    angle = np.arctan2(s, float(n @ down))
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis / s])


def turned_pose(topology: Topology, rest: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """``rest`` (R, 13) turned about its centre so that ``normal`` (3,) points down, at
    rest (zero velocities), its lowest end cap :data:`DROP` above the rest's lowest."""
    sensors = RobotSensors(topology)
    R = rest.shape[0]
    q = np.broadcast_to(_turn_to_down(normal), (R, 4))
    centre = rest[:, 0:3].mean(axis=0)
    x = np.zeros_like(rest)
    x[:, 0:3] = np_rotate(q, rest[:, 0:3] - centre) + centre
    turned = np_quat_mul(q, rest[:, 6:10])
    x[:, 6:10] = turned / np.linalg.norm(turned, axis=-1, keepdims=True)
    lowest = sensors.end_caps(rest[None])[0][:, 2].min()
    x[:, 2] += lowest + DROP - sensors.end_caps(x[None])[0][:, 2].min()
    return x


def tipped_poses(
    topology: Topology, rest: np.ndarray, settle: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """The robot settled on each face other than its base, (F, R, 13) (see the module
    docstring), ordered by their sets of floor end caps; ``settle`` maps a dropped pose
    (R, 13) to the pose after settling.

    Raises:
        RuntimeError: the physics diverged while settling a pose.
    """
    caps = RobotSensors(topology).end_caps(rest[None])[0]
    base = floor_caps(topology, rest)
    found: dict[tuple[int, ...], np.ndarray] = {}
    for equation in ConvexHull(caps).equations:
        x = settle(turned_pose(topology, rest, equation[:3]))
        if not np.isfinite(x).all():
            raise RuntimeError("the model diverged while settling on another face")
        face = floor_caps(topology, x)
        if face != base:
            found.setdefault(tuple(sorted(face)), x)
    return np.array([found[k] for k in sorted(found)]).reshape(-1, *rest.shape)


def check_share(share: float) -> float:
    """``tipped_starts`` as a float in [0, 1]; ValueError otherwise."""
    share = float(share)
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"tipped_starts is a share of episodes in [0, 1], got {share}")
    return share


def start_pose(
    rng: np.random.Generator, share: float, rest: np.ndarray, tipped: np.ndarray | None
) -> np.ndarray:
    """The pose (R, 13) an episode starts from before the task's yaw, noise and goal: one
    of ``tipped`` (F, R, 13), uniformly, with probability ``share``, else ``rest``.
    A share of 0 draws nothing from ``rng`` (the reset is the task's own, bit for bit)."""
    if share <= 0.0 or tipped is None:
        return rest
    if rng.uniform() < share:
        pose: np.ndarray = tipped[rng.integers(tipped.shape[0])]
        return pose
    return rest
