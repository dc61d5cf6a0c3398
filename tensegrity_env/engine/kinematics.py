"""Node kinematics: end-cap and attachment-point positions and velocities from rod states."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch

from tensegrity_env.engine.state import State
from tensegrity_env.topology import Topology
from tensegrity_env.vec3 import rotate


class AttachmentPoints(NamedTuple):
    """Spring attachment points on rods besides the end caps.

    Attributes:
        rod: rod owning each point, (P,) long.
        offset: each point in its rod's principal frame, (P, 3) [m].
    """

    rod: torch.Tensor
    offset: torch.Tensor

    @classmethod
    def of(
        cls,
        topology: Topology,
        dtype: torch.dtype = torch.float64,
        device: str | torch.device = "cpu",
    ) -> AttachmentPoints | None:
        """The topology's attachment points, None when springs use end caps only."""
        if topology.n_points == 0:
            return None
        return cls(
            torch.as_tensor(topology.point_rods, dtype=torch.long, device=device),
            torch.as_tensor(topology.point_offsets, dtype=dtype, device=device),
        )


@dataclass(frozen=True)
class Kinematics:
    """Quantities every force module reads, computed once per step.

    Attributes:
        rot: rotation matrices R(q), (B, R, 3, 3).
        arms: world-frame offsets from each rod's centre to its end caps, (B, R, 2, 3) [m].
        x: world positions of all nodes (end caps, anchors, attachment points), (B, N, 3) [m].
        xd: world velocities of all nodes, (B, N, 3) [m/s].
        points: the attachment points (their rods), None without any.
        point_arms: world offsets of the attachment points from their rods' centres,
            (B, P, 3) [m]; None without any.
    """

    rot: torch.Tensor
    arms: torch.Tensor
    x: torch.Tensor
    xd: torch.Tensor
    points: AttachmentPoints | None = None
    point_arms: torch.Tensor | None = None

    @property
    def node_arms(self) -> torch.Tensor:
        """World offset of every node from its rod's centre, zero at anchors, (B, N, 3) [m]."""
        B, R = self.arms.shape[:2]
        parts = [self.arms.reshape(B, 2 * R, 3)]
        n_points = 0 if self.point_arms is None else self.point_arms.shape[1]
        parts.append(self.arms.new_zeros(B, self.x.shape[1] - 2 * R - n_points, 3))
        if self.point_arms is not None:
            parts.append(self.point_arms)
        return torch.cat(parts, dim=1)


def node_kinematics(
    state: State,
    end_offsets: torch.Tensor,
    anchors: torch.Tensor,
    points: AttachmentPoints | None = None,
) -> Kinematics:
    """Nodes from rod poses: ``x = p + R r``, ``ẋ = v + ω × (R r)``.

    Args:
        state: rod states with batch size B.
        end_offsets: end caps in each rod's principal frame, (R, 2, 3) [m].
        anchors: fixed world anchors, (A, 3) [m].
        points: attachment points on rods besides the end caps (nodes after the anchors).
    """
    B = state.p.shape[0]
    rot = state.rotation()  # (B, R, 3, 3)
    arms = torch.einsum("brij,rkj->brki", rot, end_offsets)  # (B, R, 2, 3)
    x_end = state.p.unsqueeze(2) + arms
    xd_end = state.v.unsqueeze(2) + torch.cross(
        state.omega.unsqueeze(2).expand_as(arms), arms, dim=-1
    )
    n_end = 2 * state.p.shape[1]
    anc = anchors.unsqueeze(0).expand(B, -1, -1)
    xs = [x_end.reshape(B, n_end, 3), anc]
    xds = [xd_end.reshape(B, n_end, 3), torch.zeros_like(anc)]
    point_arms = None
    if points is not None:
        point_arms = rotate(rot[:, points.rod], points.offset)
        xs.append(state.p[:, points.rod] + point_arms)
        xds.append(
            state.v[:, points.rod] + torch.cross(state.omega[:, points.rod], point_arms, dim=-1)
        )
    return Kinematics(
        rot=rot,
        arms=arms,
        x=torch.cat(xs, dim=1),
        xd=torch.cat(xds, dim=1),
        points=points,
        point_arms=point_arms,
    )
