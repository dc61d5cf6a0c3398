"""Engine steps by the C kernel where no gradient is wanted.

An :class:`~tensegrity_env.engine.Engine` built with ``native=True`` hands a step to the
environments' C kernel (``tensegrity_env/envs/native_step.c``, the engine's physics
with springs, control and ground contact written out per assembly) when the kernel
computes the same thing: no gradient wanted through the state or the parameters,
float64 on the CPU, parameters shared by the whole batch (no batch dimension), no
effect but a ground contact whose parameters are single numbers, no cable commands,
and a kernel that builds. Otherwise the step runs in PyTorch as always. The two agree
to round-off (``tests/unit/test_native_engine_path.py``).

Why: a trajectory fit steps small batches (a few windows) thousands of times, where
PyTorch spends its time dispatching its ~150 operations per physics step, not on
arithmetic; the kernel fuses the substeps of a step into one call.
"""

from __future__ import annotations

import ctypes
from typing import TYPE_CHECKING

import numpy as np
import torch

from tensegrity_env.engine.state import State

if TYPE_CHECKING:
    from tensegrity_env.engine.step import Engine
    from tensegrity_env.params import Params


def native_step(
    engine: Engine,
    state: State,
    params: Params,
    control: torch.Tensor | None,
    cables: torch.Tensor | None,
) -> State | None:
    """``engine.step(state, params, control, cables)`` by the C kernel, or None where the
    kernel does not compute the same (see the module docstring)."""
    from tensegrity_env.effects.ground_contact import (
        ACTIVE_SET_ITERATIONS,
        GroundContact,
        native_kernel,
    )
    from tensegrity_env.envs.native import model_vector

    if cables is not None and engine.cable_springs.numel():
        return None
    contacts = [e for e in engine.effects if isinstance(e, GroundContact)]
    if len(contacts) != len(engine.effects) or len(contacts) > 1:
        return None
    if params.stiffness.dim() != 1 or params.mass.dim() != 1 or params.inertia.dim() != 2:
        return None
    law = {}
    if contacts:
        law_t = contacts[0].values
        if not all(v.numel() == 1 for v in law_t.values()):
            return None
        law = {k: float(v.detach()) for k, v in law_t.items()}
    B, R = state.p.shape[:2]
    tensors = [*state.tensors(), *(getattr(params, f) for f in ("stiffness", "damping",
               "rest_length", "mass", "inertia", "control_gain", "gravity"))]  # fmt: skip
    if control is not None:
        tensors.append(control)
    lib = native_kernel(*tensors)
    if lib is None:
        return None
    topo = engine.topology
    radius = contacts[0].radius.numpy() if contacts else np.zeros(R)
    model = model_vector(topo, params.numpy(), law or None, radius)
    x = torch.cat([t.detach() for t in state.tensors()], dim=-1).contiguous().numpy().copy()
    if control is None:
        u = np.zeros((B, R, 3))
    else:
        u = np.ascontiguousarray(torch.broadcast_to(control.detach(), (B, R, 3)).numpy())
    springs = _springs(engine)
    dbl = ctypes.POINTER(ctypes.c_double)
    code = lib.tsr_step(
        B, R, topo.n_springs, topo.n_anchors, engine.substeps, engine.physics_dt,
        ACTIVE_SET_ITERATIONS, x.ctypes.data_as(dbl), u.ctypes.data_as(dbl),
        model.ctypes.data_as(dbl), springs.ctypes.data_as(ctypes.POINTER(ctypes.c_int)), 1,
    )  # fmt: skip
    if code != 0:
        return None
    out = torch.from_numpy(x)
    return State(out[..., 0:3], out[..., 3:6], out[..., 6:10], out[..., 10:13])


def _springs(engine: Engine) -> np.ndarray:
    """The springs' node pairs (S, 2) as the kernel takes them, kept on the engine."""
    springs = engine.__dict__.get("_native_springs")
    if springs is None:
        springs = np.ascontiguousarray(engine.topology.spring_nodes, dtype=np.int32)
        engine.__dict__["_native_springs"] = springs
    return springs
