"""Integration: MuJoCo's semi-implicit Euler for free bodies."""

from __future__ import annotations

import torch

from tensegrity_env.engine.state import State
from tensegrity_env.rotations import quat_integrate, quat_to_matrix


def semi_implicit_euler(
    state: State,
    accel: torch.Tensor,
    alpha_local: torch.Tensor,
    omega_local: torch.Tensor,
    dt: float,
) -> State:
    """Velocities first, then positions with the new velocities.

    ``v' = v + dt a``; ``ω_l' = ω_l + dt α_l`` (rod frame, as MuJoCo's free-joint
    qvel); ``p' = p + dt v'``; ``q' = q ⊗ exp(dt ω_l' / 2)``; ``ω' = R(q') ω_l'``.
    """
    v = state.v + dt * accel
    omega_l = omega_local + dt * alpha_local
    p = state.p + dt * v
    q = quat_integrate(state.q, omega_l, dt)
    omega = torch.einsum("brij,brj->bri", quat_to_matrix(q), omega_l)
    return State(p=p, v=v, q=q, omega=omega)
