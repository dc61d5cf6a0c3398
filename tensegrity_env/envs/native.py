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

__all__ = ["CONTACT_LAW", "EFFECT_HEAD", "SOURCE", "NativeUnavailable", "load_kernel", "model_vector"]


#: entries of the kernel's effects block besides the per-spring ones: linear drag b, β,
#: quadratic drag k, κ (3 each, per rod axis), a force field (3) and the linear damping
#: integrated implicitly b, β (3 each)
EFFECT_HEAD = 21


def model_vector(
    topology: Topology,
    params: dict[str, np.ndarray],
    contact: dict[str, float] | None,
    radius: np.ndarray,
    effects: np.ndarray | None = None,
) -> np.ndarray:
    """The kernel's packed model (``native_step.c``'s layout) of ``topology`` with
    ``params`` (:meth:`~tensegrity_env.params.Params.numpy`) and the ground contact's
    ``contact`` values (:data:`CONTACT_LAW`; None: no contact); ``radius`` (R,) [m] the
    end caps' contact radii; ``effects`` the effects block (:data:`EFFECT_HEAD` + 3 S
    entries; None: no effect beside contact).

    ``params`` may carry a batch dimension (stiffness (G, S), mass (G, R), inertia
    (G, R, 3), control gain (G, ...)): one model per row, (G, L).
    """
    S = topology.n_springs
    c = np.zeros(8) if contact is None else np.array([1.0, *(contact[k] for k in CONTACT_LAW)])
    if effects is None:
        effects = np.zeros(EFFECT_HEAD + 3 * S)
    stiffness = np.asarray(params["stiffness"], dtype=np.float64)
    G = stiffness.shape[0] if stiffness.ndim == 2 else 0
    rows = max(G, 1)

    def per_model(x: np.ndarray, width: int) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        return x.reshape(rows, width) if G and x.size == G * width else np.broadcast_to(
            x.reshape(-1)[:width], (rows, width))  # fmt: skip

    R = topology.n_rods
    parts = [
        per_model(topology.end_offsets, 6 * R), per_model(topology.control_arms, 3 * R),
        per_model(topology.anchor_positions, 3 * topology.n_anchors),
        per_model(stiffness, S), per_model(params["damping"], S),
        per_model(params["rest_length"], S), per_model(params["mass"], R),
        per_model(params["inertia"], 3 * R), per_model(params["control_gain"], 1),
        per_model(params["gravity"], 3), per_model(c, 8), per_model(radius, R),
        per_model(topology.frame_origins, 3 * R),
        per_model(np.array([float(r.end_cap == "sphere") for r in topology.rods]), R),
        per_model(np.array([float(topology.n_points)]), 1),
        per_model(topology.point_rods.astype(float), topology.n_points),
        per_model(topology.point_offsets, 3 * topology.n_points),
        per_model(effects, EFFECT_HEAD + 3 * S),
    ]  # fmt: skip
    out = np.ascontiguousarray(np.concatenate(parts, axis=1), dtype=np.float64)
    return out if G else out[0]


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
    lib.tsr_step_groups.argtypes = [
        c_int, c_int, c_int, c_int, c_int, ctypes.c_double, c_int, dbl, dbl, dbl, c_int,
        ctypes.POINTER(ctypes.c_long), i32, c_int,
    ]  # fmt: skip
    lib.tsr_step_groups.restype = c_int
    lib.tsr_model_size.argtypes = [c_int, c_int, c_int, c_int]
    lib.tsr_model_size.restype = c_int
    ptr = ctypes.c_void_p
    lib.tsr_contact_forces.argtypes = [
        ctypes.c_long, c_int, *[ptr] * 7, c_int, *[ptr] * 7, c_int, ptr, ptr
    ]  # fmt: skip
    lib.tsr_contact_forces.restype = c_int
    lib.tsr_max_rods.restype = c_int
    lib.tsr_max_nodes.restype = c_int
    lib.tsr_max_points.restype = c_int
    return lib, openmp
