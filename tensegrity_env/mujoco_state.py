"""Convert between MuJoCo's (qpos, qvel) and rod states in each rod's principal frame.

A free joint's qpos is (body origin [m], body quaternion), its qvel is (origin velocity
[m/s] world frame, angular velocity [rad/s] **body** frame). Rod states use the centre
of mass and the principal (inertial) frame, and world-frame angular velocity.
"""

from __future__ import annotations

import numpy as np

from tensegrity_env.mjcf import MjcfAssembly
from tensegrity_env.rotations import np_quat_conj, np_quat_mul, np_quat_to_matrix


def mj_to_rod_state(asm: MjcfAssembly, qpos: np.ndarray, qvel: np.ndarray) -> dict[str, np.ndarray]:
    """Rod states from qpos (..., nq) and qvel (..., nv): p, v, omega (..., R, 3), q (..., R, 4)."""
    qa = asm.rod_qpos[:, None] + np.arange(7)
    va = asm.rod_qvel[:, None] + np.arange(6)
    pos, quat = qpos[..., qa[:, :3]], qpos[..., qa[:, 3:]]
    vel, omega_body = qvel[..., va[:, :3]], qvel[..., va[:, 3:]]
    rot = np_quat_to_matrix(quat)
    ipos_w = np.einsum("...ij,...j->...i", rot, np.broadcast_to(asm.body_ipos, pos.shape))
    omega = np.einsum("...ij,...j->...i", rot, omega_body)
    return {
        "p": pos + ipos_w,
        "v": vel + np.cross(omega, ipos_w),
        "q": np_quat_mul(quat, np.broadcast_to(asm.body_iquat, quat.shape)),
        "omega": omega,
    }


def rod_state_to_mj(
    asm: MjcfAssembly, p: np.ndarray, v: np.ndarray, q: np.ndarray, omega: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`mj_to_rod_state`: (qpos (..., nq), qvel (..., nv)); other dofs 0."""
    lead = p.shape[:-2]
    quat = np_quat_mul(q, np_quat_conj(np.broadcast_to(asm.body_iquat, q.shape)))
    rot = np_quat_to_matrix(quat)
    ipos_w = np.einsum("...ij,...j->...i", rot, np.broadcast_to(asm.body_ipos, p.shape))
    qpos = np.zeros((*lead, asm.model.nq))
    qvel = np.zeros((*lead, asm.model.nv))
    qa = asm.rod_qpos[:, None] + np.arange(7)
    va = asm.rod_qvel[:, None] + np.arange(6)
    qpos[..., qa[:, :3]] = p - ipos_w
    qpos[..., qa[:, 3:]] = quat
    qvel[..., va[:, :3]] = v - np.cross(omega, ipos_w)
    qvel[..., va[:, 3:]] = np.einsum("...ji,...j->...i", rot, omega)
    return qpos, qvel
