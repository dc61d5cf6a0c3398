"""The normal matrix ``AᵀA`` of the regression in one C pass over the rod states.

:func:`identification.linear.design.rod_blocks` + :func:`~identification.linear.design.accumulate_normal`
build every rod's 6 x L design block in PyTorch, which at paper scale (736,000
transitions x 6 rods) moves gigabytes through memory. ``native_normal.c`` computes the
same features and blocks per transition in registers and adds only their Gram matrices,
exploiting that every spring column is a 6-vector times a scalar (see the C file). It is
built once per machine (:mod:`tensegrity_env.native.build`) and runs on ``threads``
OpenMP threads; :class:`~tensegrity_env.native.build.NativeUnavailable` is raised where
no C compiler works, and the identifier then uses the PyTorch path. Both paths agree to
round-off (``tests/unit/test_identification.py``).
"""

from __future__ import annotations

import ctypes
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from identification.data.dataset import Split
from identification.linear.design import RodSlots
from tensegrity_env.native.build import NativeUnavailable, build_and_load
from tensegrity_env.topology import Topology

SOURCE = Path(__file__).with_name("native_normal.c")

__all__ = ["NativeUnavailable", "local_gram_native"]


@lru_cache(maxsize=1)
def _library() -> tuple[ctypes.CDLL, bool]:
    lib, openmp = build_and_load(SOURCE)
    ptr = ctypes.c_void_p
    c_int, c_i64, c_dbl = ctypes.c_int, ctypes.c_int64, ctypes.c_double
    lib.tsr_normal.argtypes = [c_int] * 6 + [ptr] * 6 + [c_i64] + [ptr] * 10 + [c_dbl, c_int, ptr]
    lib.tsr_normal.restype = c_int
    for name in ("rods", "slots", "springs", "nodes"):
        getattr(lib, f"tsr_normal_max_{name}").restype = c_int
    return lib, openmp


def _c(arr: np.ndarray, dtype: type) -> np.ndarray:
    return np.ascontiguousarray(arr, dtype=dtype)


def local_gram_native(
    topology: Topology,
    split: Split,
    index: np.ndarray,
    slots: RodSlots,
    gravity: torch.Tensor,
    dt: float,
    rest_length: torch.Tensor | None = None,
    threads: int | None = None,
) -> torch.Tensor:
    """Per-rod Gram matrices of the local design blocks, (R, L, L) float64.

    Equal to ``Σ_transitions A_rᵀ A_r`` of :func:`~identification.linear.design.rod_blocks` for
    the flat transition indices ``index`` (``traj * T + t``) of ``split``.

    Args:
        topology: the assembly.
        split: the trajectories, with rod states.
        index: flat transition indices, (n,) int.
        slots: the local-column bookkeeping of :func:`~identification.linear.design.rod_slots`.
        gravity: (3,) [m/s^2].
        dt: time step [s].
        rest_length: known rest lengths (S,) [m], or None when they are identified.
        threads: OpenMP threads (default: ``torch.get_num_threads()``).

    Raises:
        NativeUnavailable: the kernel cannot be built, or the assembly is beyond its limits.
    """
    lib, _ = _library()
    R, S, N = topology.n_rods, topology.n_springs, topology.n_nodes
    J = int(slots.spring.shape[1])
    limits = {
        "rods": R,
        "slots": J,
        "springs": S,
        "nodes": N,
    }
    for name, value in limits.items():
        if value > getattr(lib, f"tsr_normal_max_{name}")():
            raise NativeUnavailable(f"{value} {name} is beyond the C kernel's limit")
    p, v, q, w = (_c(getattr(split, k), np.float64) for k in ("p", "v", "q", "omega"))
    control = _c(split.control, np.float64)
    T1 = p.shape[1]
    args = {
        "index": _c(index, np.int64),
        "node_rod": _c(topology.node_rod, np.int32),
        "node_offsets": _c(topology.node_offsets, np.float64),
        "spring_nodes": _c(topology.spring_nodes, np.int32),
        "control_arms": _c(topology.control_arms, np.float64),
        "slot_spring": _c(slots.spring.numpy(), np.int32),
        "slot_node": _c(slots.node.numpy(), np.int32),
        "slot_sign": _c(slots.sign.numpy(), np.float64),
        "gravity": _c(gravity.detach().cpu().numpy(), np.float64),
    }
    rest = None if rest_length is None else _c(rest_length.detach().cpu().numpy(), np.float64)
    origins = _c(topology.frame_origins, np.float64) if topology.frame_origins.any() else None
    L = slots.n_local
    out = np.zeros((R, L, L))
    status = lib.tsr_normal(
        p.shape[0], T1 - 1, R, N, S, J,
        p.ctypes.data, v.ctypes.data, q.ctypes.data, w.ctypes.data, control.ctypes.data,
        args["index"].ctypes.data, len(args["index"]),
        args["node_rod"].ctypes.data, args["node_offsets"].ctypes.data,
        args["spring_nodes"].ctypes.data, args["control_arms"].ctypes.data,
        args["slot_spring"].ctypes.data, args["slot_node"].ctypes.data,
        args["slot_sign"].ctypes.data, args["gravity"].ctypes.data,
        None if rest is None else rest.ctypes.data,
        None if origins is None else origins.ctypes.data,
        float(dt), int(threads or torch.get_num_threads()), out.ctypes.data,
    )  # fmt: skip
    if status != 0:
        raise NativeUnavailable("assembly beyond the C kernel's limits")
    strict_upper = np.triu(out, 1)  # the kernel fills the upper triangles
    return torch.from_numpy(np.triu(out) + strict_upper.transpose(0, 2, 1))
