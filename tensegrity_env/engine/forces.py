"""Force generation: the paper's 3-D to 1-D reduction of every spring.

Each spring is reduced to its length ``l``, its unit axis ``e`` (from node a to node
b) and its elongation rate ``l̇``; Hooke's law with damping is a scalar law along
the axis, ``T = K (l - l0) + c l̇`` (positive when stretched), and the force is
``+T e`` on node a and ``-T e`` on node b. This matches MuJoCo's spatial tendon
spring and damper.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.vec3 import dot, sum_small


@dataclass(frozen=True)
class SpringFrame:
    """Each spring in its own 1-D frame.

    Attributes:
        length: current length l, (B, S) [m].
        axis: unit vector from node a to node b, (B, S, 3).
        rate: elongation rate l̇, (B, S) [m/s].
    """

    length: torch.Tensor
    axis: torch.Tensor
    rate: torch.Tensor


def spring_frames(kin: Kinematics, node_a: torch.Tensor, node_b: torch.Tensor) -> SpringFrame:
    """Reduce springs (node index tensors (S,)) to length, axis and elongation rate."""
    d = kin.x[:, node_b] - kin.x[:, node_a]
    length = torch.linalg.vector_norm(d, dim=-1)
    axis = d / length.unsqueeze(-1)
    rate = dot(kin.xd[:, node_b] - kin.xd[:, node_a], axis)
    return SpringFrame(length=length, axis=axis, rate=rate)


def hooke_tension(
    frame: SpringFrame, stiffness: torch.Tensor, damping: torch.Tensor, rest_length: torch.Tensor
) -> torch.Tensor:
    """The linear 1-D spring law ``T = K (l - l0) + c l̇``, (B, S) [N]."""
    return stiffness * (frame.length - rest_length) + damping * frame.rate


def tension_to_node_forces(
    tension: torch.Tensor, frame: SpringFrame, incidence: torch.Tensor
) -> torch.Tensor:
    """Node forces (B, N, 3) [N] from tensions (B, S) through the signed incidence (N, S)."""
    return torch.einsum("ns,bsk->bnk", incidence, tension.unsqueeze(-1) * frame.axis)


def node_forces_to_wrench(
    node_forces: torch.Tensor,
    arms: torch.Tensor,
    point_arms: torch.Tensor | None = None,
    point_rod: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Force and torque about the centre of mass on each rod from its node forces.

    Args:
        node_forces: forces on all nodes, (B, N, 3) [N]; anchors are ignored.
        arms: world offsets of the end caps, (B, R, 2, 3) [m].
        point_arms: world offsets of the attachment points (the last P nodes), (B, P, 3)
            [m], with ``point_rod`` (P,) their rods; None without attachment points.

    Returns:
        force (B, R, 3) [N] and torque (B, R, 3) [N*m], world frame.
    """
    B, R = arms.shape[:2]
    f_end = node_forces[:, : 2 * R].reshape(B, R, 2, 3)
    force, torque = sum_small(f_end, 2), sum_small(torch.cross(arms, f_end, dim=-1), 2)
    if point_arms is not None and point_rod is not None:
        f_pt = node_forces[:, node_forces.shape[1] - point_arms.shape[1] :]
        force = force.index_add(1, point_rod, f_pt)
        torque = torque.index_add(1, point_rod, torch.cross(point_arms, f_pt, dim=-1))
    return force, torque


def kinematics_wrench(
    node_forces: torch.Tensor, kin: Kinematics
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`node_forces_to_wrench` with the end caps and attachment points of ``kin``."""
    rods = None if kin.points is None else kin.points.rod
    return node_forces_to_wrench(node_forces, kin.arms, kin.point_arms, rods)


def point_force_wrench(force: torch.Tensor, arm: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Wrench of forces (B, R, 3) applied at world offsets ``arm`` (B, R, 3) from the COM."""
    return force, torch.cross(arm, force, dim=-1)
