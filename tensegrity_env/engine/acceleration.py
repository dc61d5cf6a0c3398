"""Acceleration generation: Newton-Euler for each rod, through M, I and the rotation R."""

from __future__ import annotations

import torch

from tensegrity_env.vec3 import rotate_t


def linear_acceleration(
    force: torch.Tensor, mass: torch.Tensor, gravity: torch.Tensor
) -> torch.Tensor:
    """``a = F / M + g``, shapes (B, R, 3), (R,), (3,) -> (B, R, 3) [m/s^2]."""
    return force / mass.unsqueeze(-1) + gravity


def angular_acceleration_local(
    torque: torch.Tensor, omega: torch.Tensor, rot: torch.Tensor, inertia: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Euler's equations in each rod's principal frame.

    ``α_l = I^{-1} (R^T τ - ω_l × (I ω_l))`` with the gyroscopic term, as MuJoCo's
    bias force for a free body whose inertial frame is its body frame.

    Args:
        torque: world torques about the COM, (B, R, 3) [N*m].
        omega: world angular velocities, (B, R, 3) [rad/s].
        rot: R(q), (B, R, 3, 3).
        inertia: principal inertia, (R, 3) [kg*m^2].

    Returns:
        α_l (B, R, 3) [rad/s^2] and ω_l (B, R, 3) [rad/s], both in the rod frame.
    """
    omega_l = rotate_t(rot, omega)
    torque_l = rotate_t(rot, torque)
    gyro = torch.cross(omega_l, inertia * omega_l, dim=-1)
    return (torque_l - gyro) / inertia, omega_l
