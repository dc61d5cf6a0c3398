"""The C kernel (``native_step.h`` and the ``native_*.c`` files it lists), loaded: the
identified model's step, the ground contact's forces and a robot's sensor readings.

Built once per machine by :mod:`tensegrity_env.native.build` (about a second). Its
callers: the environments' stepper (:class:`~tensegrity_env.envs.physics.NativeStepper`),
the engine's no-gradient step (:mod:`tensegrity_env.native.engine_step`) and the ground
contact's law where no gradient is wanted
(:meth:`~tensegrity_env.effects.ground_contact.GroundContact.contact_forces`) and the
generic environments' observation (:mod:`tensegrity_env.envs.robot_sense`). When no
compiler works, :func:`load_kernel` raises :class:`NativeUnavailable` and
:func:`usable_kernel` returns None: the callers step PyTorch instead.
"""

from __future__ import annotations

import ctypes
from functools import lru_cache
from pathlib import Path

import torch

from tensegrity_env.native.build import NativeUnavailable, build_and_load

#: the kernel's files, compiled together (what each holds: ``native_step.h``)
SOURCES = tuple(
    Path(__file__).with_name(f"native_{part}")
    for part in ("step.h", "step.c", "model.c", "forces.c", "contact.c", "winch.c", "sense.c")
)
#: assemblies per SIMD block of the kernel's two builds: the wide one for batches, the
#: narrow one for a few assemblies (one environment), whose shorter vectors cost less
#: latency; both give the same numbers bit for bit (native_step.h)
LANES = 8
NARROW_LANES = 4

#: whether the kernel may stand in for PyTorch where no gradient is wanted (the ground
#: contact's law and ``Engine(native=True)``); tests and benchmarks switch it off to
#: compare with PyTorch
USE_NATIVE = True

#: the contact law's parameters in the order the kernel takes them (``tsr_contact_forces``
#: and the packed model's contact block)
CONTACT_LAW = ("stiffness", "damping", "impedance", "impedance_min", "width", "friction",
               "height")  # fmt: skip

#: the reason given where a gradient is wanted through a tensor (the kernel has none)
GRADIENT_WANTED = "a gradient is wanted"
#: the reason given where :data:`USE_NATIVE` is off
SWITCHED_OFF = "the C kernel is switched off (tensegrity_env.native.kernel.USE_NATIVE)"

__all__ = ["CONTACT_LAW", "GRADIENT_WANTED", "LANES", "NARROW_LANES", "SOURCES", "SWITCHED_OFF",
           "USE_NATIVE", "NativeUnavailable", "load_kernel", "unusable_reason",
           "usable_kernel"]  # fmt: skip


@lru_cache(maxsize=2)
def load_kernel(lanes: int = LANES) -> tuple[ctypes.CDLL, bool]:
    """The loaded library with ``lanes`` assemblies per SIMD block (:data:`LANES` or
    :data:`NARROW_LANES`) and whether it has OpenMP. Raises :class:`NativeUnavailable`."""
    if lanes not in (LANES, NARROW_LANES):
        raise ValueError(f"the kernel is built with {LANES} or {NARROW_LANES} lanes, not {lanes}")
    lib, openmp = build_and_load(SOURCES, () if lanes == LANES else (f"TSR_W={lanes}",))
    c_int = ctypes.c_int
    # the last two: the winch states (B, W, 2) in/out and their commands (B, W) (None: no
    # winding / motors at 0)
    ptr = ctypes.c_void_p  # array addresses (ints, ctypes pointers or None for NULL)
    lib.tsr_step.argtypes = [
        c_int, c_int, c_int, c_int, c_int, ctypes.c_double, c_int, ptr, ptr, ptr, ptr, c_int,
        ptr, ptr,
    ]  # fmt: skip
    lib.tsr_step.restype = c_int
    lib.tsr_step_groups.argtypes = [
        c_int, c_int, c_int, c_int, c_int, ctypes.c_double, c_int, ptr, ptr, ptr, c_int,
        ptr, ptr, c_int, ptr, ptr,
    ]  # fmt: skip
    lib.tsr_step_groups.restype = c_int
    lib.tsr_model_size.argtypes = [c_int, c_int, c_int, c_int, c_int]
    lib.tsr_model_size.restype = c_int
    lib.tsr_contact_forces.argtypes = [
        ctypes.c_long, c_int, *[ptr] * 7, c_int, *[ptr] * 7, c_int, ptr, ptr
    ]  # fmt: skip
    lib.tsr_contact_forces.restype = c_int
    lib.tsr_max_rods.restype = c_int
    lib.tsr_max_nodes.restype = c_int
    lib.tsr_max_points.restype = c_int
    lib.tsr_max_winches.restype = c_int
    lib.tsr_lanes.restype = c_int
    lib.tsr_sense.argtypes = [ctypes.c_long, c_int, c_int, c_int, c_int, c_int, *[ptr] * 10]
    lib.tsr_sense.restype = c_int
    return lib, openmp


@lru_cache(maxsize=1)
def _loaded() -> ctypes.CDLL | None:
    """The loaded library, or None where no C compiler works."""
    try:
        return load_kernel()[0]
    except NativeUnavailable:
        return None


def unusable_reason(*tensors: torch.Tensor) -> str | None:
    """Why the kernel may not take ``tensors`` (None: it may): it is switched off
    (:data:`USE_NATIVE`), a tensor is not float64 on the CPU, a gradient is wanted
    through one, or no C compiler works here."""
    if not USE_NATIVE:
        return SWITCHED_OFF
    grad = torch.is_grad_enabled()
    for t in tensors:
        if t.device.type != "cpu" or t.dtype != torch.float64:
            return f"the kernel takes float64 on the CPU, got {t.dtype} on {t.device.type}"
        if grad and t.requires_grad:
            return GRADIENT_WANTED
    if _loaded() is None:
        return "no C compiler builds the kernel here"
    return None


def usable_kernel(*tensors: torch.Tensor) -> ctypes.CDLL | None:
    """The loaded kernel where it may take ``tensors`` (:func:`unusable_reason`), else None."""
    return None if unusable_reason(*tensors) is not None else _loaded()
