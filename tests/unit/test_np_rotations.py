"""The numpy rotation matrix of a quaternion is the PyTorch one, to the bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tensegrity_env.rotations import np_quat_to_matrix, quat_to_matrix


@pytest.mark.parametrize("shape", [(4,), (3, 4), (7, 5, 4)])
def test_np_quat_to_matrix_is_quat_to_matrix(shape: tuple[int, ...]) -> None:
    q = np.random.default_rng(len(shape)).normal(size=shape)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    rot = np_quat_to_matrix(q)
    assert rot.shape == (*shape[:-1], 3, 3) and rot.dtype == np.float64
    np.testing.assert_array_equal(rot, quat_to_matrix(torch.as_tensor(q)).numpy())
    # a rotation: orthonormal with determinant 1
    np.testing.assert_allclose(rot @ np.swapaxes(rot, -1, -2), np.broadcast_to(np.eye(3), rot.shape),
                               atol=1e-14)  # fmt: skip
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-14)
