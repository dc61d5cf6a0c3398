"""Integration: MuJoCo's semi-implicit Euler for free bodies, and its exact inverse.

MuJoCo integrates a free joint in its body frame: the linear velocity of the body
frame's origin ``o`` and the angular velocity in the body frame. Rod states hold the
centre of mass and the principal frame; when the body origin is not the centre of
mass (``frame_origin`` of :class:`~tensegrity_env.topology.Rod`), the step moves the
origin with its own velocity ``v_o = v + ω × r`` (``r = R(q) o``) and places the
centre of mass back from it, which differs from ``p' = p + dt v'`` by O(dt²).
"""

from __future__ import annotations

import torch

from tensegrity_env.engine.state import State
from tensegrity_env.rotations import quat_integrate, quat_to_matrix
from tensegrity_env.vec3 import rotate, rotate_t


def semi_implicit_euler(
    state: State,
    accel: torch.Tensor,
    alpha_local: torch.Tensor,
    omega_local: torch.Tensor,
    dt: float | torch.Tensor,
    frame_origin: torch.Tensor | None = None,
) -> State:
    """Velocities first, then positions with the new velocities.

    ``v' = v + dt a``; ``ω_l' = ω_l + dt α_l`` (rod frame, as MuJoCo's free-joint
    qvel); ``p' = p + dt v'``; ``q' = q ⊗ exp(dt ω_l' / 2)``; ``ω' = R(q') ω_l'``.
    With ``frame_origin`` (R, 3) [m] in the principal frame, the same holds for the
    body origin ``p_o = p + R o``, whose acceleration is ``a + α × r + ω × (ω × r)``.
    """
    omega_l = omega_local + dt * alpha_local
    q = quat_integrate(state.q, omega_l, dt)
    rot1 = quat_to_matrix(q)
    omega = rotate(rot1, omega_l)
    if frame_origin is None:
        v = state.v + dt * accel
        return State(p=state.p + dt * v, v=v, q=q, omega=omega).remember_rotation(rot1)
    rot0 = state.rotation()
    r0 = rotate(rot0, frame_origin)
    alpha = rotate(rot0, alpha_local)
    w0 = state.omega
    a_o = (
        accel
        + torch.cross(alpha, r0, dim=-1)
        + torch.cross(w0, torch.cross(w0, r0, dim=-1), dim=-1)
    )
    v_o = state.v + torch.cross(w0, r0, dim=-1) + dt * a_o
    p_o = state.p + r0 + dt * v_o
    r1 = rotate(rot1, frame_origin)
    out = State(p=p_o - r1, v=v_o - torch.cross(omega, r1, dim=-1), q=q, omega=omega)
    return out.remember_rotation(rot1)


def step_accelerations(
    s0: State, s1: State, dt: float, frame_origin: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The accelerations that took ``s0`` to ``s1`` in one :func:`semi_implicit_euler` step.

    Exact (to round-off) for MuJoCo's Euler transitions, so that every equation of
    motion at ``s0`` is linear in the parameters.

    Args:
        s0, s1: consecutive rod states, batch n.
        dt: time step [s].
        frame_origin: body-frame origins in each rod's principal frame, (R, 3) [m].

    Returns:
        a (n, R, 3) [m/s^2] world, α_l (n, R, 3) [rad/s^2] rod frame, ω_l at ``s0``
        (n, R, 3) [rad/s] rod frame, and R(q_0) (n, R, 3, 3).
    """
    rot0, rot1 = quat_to_matrix(s0.q), quat_to_matrix(s1.q)
    omega_l0 = rotate_t(rot0, s0.omega)
    omega_l1 = rotate_t(rot1, s1.omega)
    alpha_l = (omega_l1 - omega_l0) / dt
    if frame_origin is None:
        return (s1.v - s0.v) / dt, alpha_l, omega_l0, rot0
    r0 = rotate(rot0, frame_origin.to(s0.p))
    r1 = rotate(rot1, frame_origin.to(s0.p))
    v_o0 = s0.v + torch.cross(s0.omega, r0, dim=-1)
    v_o1 = s1.v + torch.cross(s1.omega, r1, dim=-1)
    alpha = rotate(rot0, alpha_l)
    w0 = s0.omega
    accel = (
        (v_o1 - v_o0) / dt
        - torch.cross(alpha, r0, dim=-1)
        - torch.cross(w0, torch.cross(w0, r0, dim=-1), dim=-1)
    )
    return accel, alpha_l, omega_l0, rot0
