"""Load the C kernel of the identified model's control step (``native_step.c``).

The same library computes the ground contact's forces for the PyTorch engine where no
gradient is wanted (:func:`~tensegrity_env.effects.ground_contact.native_kernel`).

Built once per machine by :mod:`tensegrity_env.native_build` (about a second); when
no compiler works, :func:`load_kernel` raises :class:`NativeUnavailable` and the
environments step the PyTorch engine instead.
"""

from __future__ import annotations

import ctypes
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tensegrity_env.native_build import NativeUnavailable, build_and_load

if TYPE_CHECKING:
    from tensegrity_env.topology import Topology

SOURCE = Path(__file__).with_name("native_step.c")
#: the contact law's parameters in the order the kernel's model takes them
CONTACT_LAW = ("stiffness", "damping", "impedance", "impedance_min", "width", "friction",
               "height")  # fmt: skip

__all__ = ["CONTACT_LAW", "SOURCE", "NativeUnavailable", "load_kernel", "model_vector"]


def model_vector(
    topology: Topology,
    params: dict[str, np.ndarray],
    contact: dict[str, float] | None,
    radius: np.ndarray,
) -> np.ndarray:
    """The kernel's packed model (``native_step.c``'s layout) of ``topology`` with
    ``params`` (:meth:`~tensegrity_env.params.Params.numpy`) and the ground contact's
    ``contact`` values (:data:`CONTACT_LAW`; None: no contact); ``radius`` (R,) [m] the
    end caps' contact radii."""
    c = np.zeros(8) if contact is None else np.array([1.0, *(contact[k] for k in CONTACT_LAW)])
    parts = [
        topology.end_offsets.ravel(), topology.control_arms.ravel(),
        topology.anchor_positions.ravel(), params["stiffness"], params["damping"],
        params["rest_length"], params["mass"], params["inertia"].ravel(),
        np.reshape(params["control_gain"], -1)[:1], np.reshape(params["gravity"], 3), c, radius,
        topology.frame_origins.ravel(), [float(r.end_cap == "sphere") for r in topology.rods],
        [float(topology.n_points)], topology.point_rods.astype(float),
        topology.point_offsets.ravel(),
    ]  # fmt: skip
    return np.ascontiguousarray(np.concatenate(parts), dtype=np.float64)


@lru_cache(maxsize=1)
def load_kernel() -> tuple[ctypes.CDLL, bool]:
    """The loaded library and whether it has OpenMP. Raises :class:`NativeUnavailable`."""
    lib, openmp = build_and_load(SOURCE)
    dbl, i32 = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int)
    c_int = ctypes.c_int
    lib.tsr_step.argtypes = [
        c_int, c_int, c_int, c_int, c_int, ctypes.c_double, c_int, dbl, dbl, dbl, i32, c_int
    ]  # fmt: skip
    lib.tsr_step.restype = c_int
    ptr = ctypes.c_void_p
    lib.tsr_contact_forces.argtypes = [
        ctypes.c_long, c_int, *[ptr] * 7, c_int, *[ptr] * 7, c_int, ptr, ptr
    ]  # fmt: skip
    lib.tsr_contact_forces.restype = c_int
    lib.tsr_max_rods.restype = c_int
    lib.tsr_max_nodes.restype = c_int
    lib.tsr_max_points.restype = c_int
    return lib, openmp
