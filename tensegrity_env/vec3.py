"""Batched 3-vector algebra written out component by component.

The engine and :mod:`tensegrity_env.rotations` work on many small vectors and 3x3
matrices at once ((B, R, 3), (B, R, 3, 3)). PyTorch's reductions over a trailing dimension of 2 or 3
(``x.sum(-1)``, ``einsum``) cost several times more on the CPU than the same sum
spelled out as slices (float64, one thread: about 20x for ``sum`` over a
dimension of 2, 6x for a dot product, 1.5x for a rotation), and the physics step
is made of little else. The functions here broadcast like the expressions they
replace and are differentiable.
"""

from __future__ import annotations

import torch


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``Σ_k a_k b_k`` over the last dimension (3): (..., 3), (..., 3) -> (...)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def rotate(rot: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``R v``: rot (..., 3, 3), v (..., 3) -> (..., 3) (leading dims broadcast)."""
    return (
        rot[..., :, 0] * v[..., 0:1] + rot[..., :, 1] * v[..., 1:2] + rot[..., :, 2] * v[..., 2:3]
    )


def rotate_t(rot: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``Rᵀ v``: rot (..., 3, 3), v (..., 3) -> (..., 3) (world to body for a rotation)."""
    return (
        rot[..., 0, :] * v[..., 0:1] + rot[..., 1, :] * v[..., 1:2] + rot[..., 2, :] * v[..., 2:3]
    )


def sum_small(x: torch.Tensor, dim: int) -> torch.Tensor:
    """``x.sum(dim)`` for a short dimension ``dim`` (2 to 8 entries), as slices added up."""
    parts = x.unbind(dim)
    out = parts[0]
    for p in parts[1:]:
        out = out + p
    return out
