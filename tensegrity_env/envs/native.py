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

from tensegrity_env.native_build import NativeUnavailable, build_and_load

SOURCE = Path(__file__).with_name("native_step.c")

__all__ = ["SOURCE", "NativeUnavailable", "load_kernel"]


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
