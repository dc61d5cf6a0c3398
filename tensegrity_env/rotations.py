"""Quaternions and rod axes, in PyTorch and numpy, batched over leading dimensions.

Quaternions are ``(w, x, y, z)`` (MuJoCo's order), unit norm, mapping the rod's
principal frame to the world frame: ``x_world = R(q) @ x_rod``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import torch

from tensegrity_env.vec3 import dot


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a ⊗ b``, shapes (..., 4)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def quat_conj(q: torch.Tensor) -> torch.Tensor:
    """Conjugate (the inverse of a unit quaternion), shapes (..., 4)."""
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrix of unit quaternion ``q`` (..., 4) -> (..., 3, 3), as MuJoCo's mju_quat2Mat."""
    w, x, y, z = q.unbind(-1)
    ww, xx, yy, zz = w * w, x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    rows = (
        torch.stack((ww + xx - yy - zz, 2 * (xy - wz), 2 * (xz + wy)), -1),
        torch.stack((2 * (xy + wz), ww - xx + yy - zz, 2 * (yz - wx)), -1),
        torch.stack((2 * (xz - wy), 2 * (yz + wx), ww - xx - yy + zz), -1),
    )
    return torch.stack(rows, dim=-2)


def quat_integrate(
    q: torch.Tensor, omega_local: torch.Tensor, dt: float | torch.Tensor
) -> torch.Tensor:
    """Rotate ``q`` by body-frame angular velocity ``omega_local`` for ``dt`` seconds
    (a float, or a tensor broadcasting against (..., 1)).

    MuJoCo's ``mju_quatIntegrate``: ``q ⊗ quat(axis=ω/|ω|, angle=|ω| dt)``, then
    normalised. Shapes (..., 4), (..., 3).
    """
    norm_sq = dot(omega_local, omega_local).unsqueeze(-1)
    safe = norm_sq > 0
    norm = torch.sqrt(torch.where(safe, norm_sq, torch.ones_like(norm_sq)))
    half = 0.5 * dt * norm
    axis = omega_local / norm
    s = torch.where(safe, torch.sin(half), torch.zeros_like(half))
    c = torch.where(safe, torch.cos(half), torch.ones_like(half))
    qrot = torch.cat((c, axis * s), dim=-1)
    out = quat_mul(q, qrot)
    result: torch.Tensor = out / torch.linalg.vector_norm(out, dim=-1, keepdim=True)
    return result


#: rotations taking a file's up axis to z (right-handed): Vicon and Qualisys record z-up,
#: OptiTrack Motive and NTRT models y-up
TO_Z_UP = {
    "z": np.eye(3),
    "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),  # +90 deg about x
    "x": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),  # x, y, z -> y, z, x
    "-z": np.diag([1.0, -1.0, -1.0]),  # 180 deg about x
    "-y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),  # -90 deg about x
    "-x": np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]]),  # x, y, z -> -y, z, -x
}


def axis_angle_to_quat(axis: npt.ArrayLike, angle: float) -> np.ndarray:
    """Numpy helper: unit quaternion (w, x, y, z) rotating ``angle`` [rad] about ``axis``."""
    a = np.asarray(axis, dtype=float)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * a / np.linalg.norm(a)])


def np_quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """:func:`quat_to_matrix` in numpy (the same arithmetic, so the same numbers, without
    a round trip through PyTorch): (..., 4) -> (..., 3, 3), float64."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    ww, xx, yy, zz = w * w, x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    out = np.empty((*q.shape[:-1], 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = ww + xx - yy - zz, 2 * (xy - wz), 2 * (xz + wy)
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = 2 * (xy + wz), ww - xx + yy - zz, 2 * (yz - wx)
    out[..., 2, 0], out[..., 2, 1], out[..., 2, 2] = 2 * (xz - wy), 2 * (yz + wx), ww - xx - yy + zz
    return out


def np_quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` in numpy (the same arithmetic as :func:`quat_mul`), (..., 4)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        axis=-1,
    )


def np_quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate in numpy (the inverse of a unit quaternion), shapes (..., 4)."""
    result: np.ndarray = q * np.array([1.0, -1.0, -1.0, -1.0])
    return result


def np_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4), in numpy."""
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, np.broadcast_to(v, u.shape))
    return v + w * t + np.cross(u, t)


def unit(x: np.ndarray) -> np.ndarray:
    """``x`` divided by its norm along the last axis."""
    result: np.ndarray = x / np.linalg.norm(x, axis=-1, keepdims=True)
    return result


def shortest_arc(a_from: np.ndarray, a_to: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) rotating unit vectors ``a_from`` onto ``a_to``.

    ``a_from`` broadcasts against ``a_to`` (..., 3); returns (..., 4). Of all rotations
    taking one onto the other this is the smallest (no turn about ``a_to``). Antiparallel
    pairs turn by π about an axis perpendicular to ``a_from``.
    """
    a_from = np.broadcast_to(a_from, a_to.shape)
    w = 1.0 + np.sum(a_from * a_to, axis=-1, keepdims=True)
    xyz = np.cross(a_from, a_to)
    q = np.concatenate([w, xyz], axis=-1)
    flip = w[..., 0] < 1e-12
    if np.any(flip):
        helper = np.where(np.abs(a_from[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        perp = unit(np.cross(a_from, helper))
        q[flip] = np.concatenate([np.zeros((*perp.shape[:-1], 1)), perp], axis=-1)[flip]
    return unit(q)


def rod_axes(end_offsets: np.ndarray) -> np.ndarray:
    """Unit vector from end cap 0 to end cap 1 in each rod's frame, (R, 3).

    ``end_offsets``: (R, 2, 3) [m], ``Topology.end_offsets``.
    """
    return unit(end_offsets[:, 1] - end_offsets[:, 0])


def random_quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` uniformly distributed unit quaternions (Shoemake), shape (n, 4)."""
    u1, u2, u3 = rng.random((3, n))
    q = np.stack(
        [
            np.sqrt(u1) * np.cos(2 * np.pi * u3),
            np.sqrt(1 - u1) * np.sin(2 * np.pi * u2),
            np.sqrt(1 - u1) * np.cos(2 * np.pi * u2),
            np.sqrt(u1) * np.sin(2 * np.pi * u3),
        ],
        axis=-1,
    )
    result: np.ndarray = q * np.sign(q[:, :1] + (q[:, :1] == 0))
    return result
