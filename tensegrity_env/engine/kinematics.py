"""Node kinematics: end-cap positions and velocities from rod states."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from tensegrity_env.engine.state import State
from tensegrity_env.rotations import quat_to_matrix


@dataclass(frozen=True)
class Kinematics:
    """Quantities every force module reads, computed once per step.

    Attributes:
        rot: rotation matrices R(q), (B, R, 3, 3).
        arms: world-frame offsets from each rod's centre to its end caps, (B, R, 2, 3) [m].
        x: world positions of all nodes (end caps, then anchors), (B, N, 3) [m].
        xd: world velocities of all nodes, (B, N, 3) [m/s].
    """

    rot: torch.Tensor
    arms: torch.Tensor
    x: torch.Tensor
    xd: torch.Tensor


def node_kinematics(state: State, end_offsets: torch.Tensor, anchors: torch.Tensor) -> Kinematics:
    """End caps from rod poses: ``x = p + R r``, ``ẋ = v + ω × (R r)``.

    Args:
        state: rod states with batch size B.
        end_offsets: end caps in each rod's principal frame, (R, 2, 3) [m].
        anchors: fixed world anchors, (A, 3) [m].
    """
    B = state.p.shape[0]
    rot = quat_to_matrix(state.q)  # (B, R, 3, 3)
    arms = torch.einsum("brij,rkj->brki", rot, end_offsets)  # (B, R, 2, 3)
    x_end = state.p.unsqueeze(2) + arms
    xd_end = state.v.unsqueeze(2) + torch.cross(
        state.omega.unsqueeze(2).expand_as(arms), arms, dim=-1
    )
    n_end = 2 * state.p.shape[1]
    anc = anchors.unsqueeze(0).expand(B, -1, -1)
    x = torch.cat([x_end.reshape(B, n_end, 3), anc], dim=1)
    xd = torch.cat([xd_end.reshape(B, n_end, 3), torch.zeros_like(anc)], dim=1)
    return Kinematics(rot=rot, arms=arms, x=x, xd=xd)
