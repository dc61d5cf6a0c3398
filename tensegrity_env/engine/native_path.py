"""Engine steps by the C kernel where no gradient is wanted.

An :class:`~tensegrity_env.engine.Engine` built with ``native=True`` hands a step to the
environments' C kernel (``tensegrity_env/envs/native_step.c``: the engine's physics
written out per assembly) when the kernel computes the same thing: no gradient wanted
through the state, the parameters or the effects, float64 on the CPU, no cable
commands, a kernel that builds, and only effects the kernel has (:func:`effects_block`:
ground contact, linear drag (explicit or implicit), quadratic drag, a force field, cubic
stiffness, rest-length offsets, slack springs), each with the shapes it takes. Parameters with a batch dimension (a forward-difference Jacobian's perturbed
copies) are stepped in runs of consecutive assemblies that share them, one model per
run. Otherwise the step runs in PyTorch as always. The two agree to round-off
(``tests/unit/test_native_engine_path.py``).

Why: a trajectory fit steps small batches (a few windows) thousands of times, where
PyTorch spends its time dispatching its ~150 operations per physics step, not on
arithmetic; the kernel fuses the substeps of a step into one call.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from tensegrity_env.engine.state import State

if TYPE_CHECKING:
    from tensegrity_env.engine.step import Engine
    from tensegrity_env.params import Params
    from tensegrity_env.topology import Topology

#: the parameters a batch dimension may vary, with their unbatched number of dimensions
BATCHED = {"stiffness": 1, "damping": 1, "rest_length": 1, "mass": 1, "inertia": 2,
           "control_gain": 0}  # fmt: skip


def native_step(
    engine: Engine,
    state: State,
    params: Params,
    control: torch.Tensor | None,
    cables: torch.Tensor | None,
) -> State | None:
    """``engine.step(state, params, control, cables)`` by the C kernel, or None where the
    kernel does not compute the same (see the module docstring)."""
    from tensegrity_env.effects.ground_contact import ACTIVE_SET_ITERATIONS, native_kernel

    if cables is not None and engine.cable_springs.numel():
        return None
    B, R = state.p.shape[:2]
    fields = {k: getattr(params, k) for k in (*BATCHED, "gravity")}
    if params.gravity.numel() != 3:
        return None
    tensors = [*state.tensors(), *fields.values()]
    if control is not None:
        tensors.append(control)
    lib = native_kernel(*tensors)
    if lib is None:
        return None
    built = _models(engine, fields, B)
    if built is None:
        return None
    models, start = built
    x = torch.cat([t.detach() for t in state.tensors()], dim=-1).contiguous().numpy()
    if control is None:
        u = np.zeros((B, R, 3))
    else:
        u = np.ascontiguousarray(torch.broadcast_to(control.detach(), (B, R, 3)).numpy())
    topo = engine.topology
    dbl = ctypes.POINTER(ctypes.c_double)
    code = lib.tsr_step_groups(
        B, R, topo.n_springs, topo.n_anchors, engine.substeps, engine.physics_dt,
        ACTIVE_SET_ITERATIONS, x.ctypes.data_as(dbl), u.ctypes.data_as(dbl),
        models.ctypes.data_as(dbl), len(start) - 1,
        start.ctypes.data_as(ctypes.POINTER(ctypes.c_long)),
        _springs(engine).ctypes.data_as(ctypes.POINTER(ctypes.c_int)), 1,
    )  # fmt: skip
    if code != 0:
        return None
    out = torch.from_numpy(x)
    return State(out[..., 0:3], out[..., 3:6], out[..., 6:10], out[..., 10:13])


def _models(
    engine: Engine, fields: dict[str, torch.Tensor], B: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """The kernel's models (G, L) and where each one's run of assemblies starts (G + 1,)
    for ``fields`` (the parameters) on ``engine``'s effects, or None where the kernel
    does not take them. Kept on the engine for the same parameter tensors (a rollout
    steps the same parameters every step); the tensors are held, so their ids stay
    theirs, and their versions tell an in-place change."""
    from tensegrity_env.envs.native import model_vector

    key = (*((id(t), t._version) for t in fields.values()), B)
    kept = engine.__dict__.get("_native_models")
    if kept is not None and kept[0] == key:
        return kept[2]
    block = effects_block(engine.effects, engine.topology)
    if block is None:
        return None
    contact, effects, radius = block
    batched = {k: v.dim() > BATCHED[k] for k, v in fields.items() if k in BATCHED}
    if any(batched.values()):
        rows = _model_rows(fields, batched, B)
        if rows is None:
            return None
        start = _runs(rows)
        first = torch.as_tensor(start[:-1])
        G = len(first)
        values = {"gravity": fields["gravity"].detach().numpy()}
        for k in BATCHED:
            v = fields[k].detach()
            v = v[first] if batched[k] else v.unsqueeze(0).expand(G, *v.shape)
            values[k] = v.reshape(G, -1).numpy()
    else:
        values = {k: v.detach().numpy() for k, v in fields.items()}
        start = np.array([0, B], dtype=np.int64)
    models = np.ascontiguousarray(model_vector(engine.topology, values, contact, radius, effects))
    engine.__dict__["_native_models"] = (key, tuple(fields.values()), (models, start))
    return models, start


def effects_block(
    effects: Sequence[Any], topology: Topology
) -> tuple[dict[str, float] | None, np.ndarray, np.ndarray] | None:
    """The kernel's view of ``effects``: the ground contact's law (None without one),
    the effects block (``native_step.c``'s layout) and the end caps' contact radii
    (R,) [m]; None where an effect has no native form or its parameters are not the
    single set the kernel takes (a batch of them, or a gradient wanted)."""
    from tensegrity_env.effects import (
        CubicStiffness,
        ForceField,
        GroundContact,
        ImplicitLinearDrag,
        LinearDrag,
        QuadraticDrag,
        RestLengthOffset,
        SlackSprings,
    )
    from tensegrity_env.envs.native import EFFECT_HEAD

    S = topology.n_springs
    block = np.zeros(EFFECT_HEAD + 3 * S)
    contact, radius = None, None
    where = {LinearDrag: (0, ("translational", "rotational")),
             QuadraticDrag: (6, ("translational", "rotational")), ForceField: (12, ("force",)),
             CubicStiffness: (EFFECT_HEAD, ("stiffness",)),
             RestLengthOffset: (EFFECT_HEAD + S, ("offset",))}  # fmt: skip
    for e in effects:
        values = getattr(e, "values", {})
        if any(torch.is_tensor(v) and v.requires_grad and torch.is_grad_enabled()
               for v in values.values()):  # fmt: skip
            return None
        kind = type(e)
        if kind is GroundContact:
            if contact is not None or not all(v.numel() == 1 for v in values.values()):
                return None
            contact = {k: float(v.detach()) for k, v in values.items()}
            radius = e.radius.numpy()
        elif kind is ImplicitLinearDrag:  # its wrench, and its damping implicitly
            flat = np.concatenate([values[k].detach().cpu().double().numpy().reshape(-1)
                                   for k in ("translational", "rotational")])  # fmt: skip
            if flat.size != 6:
                return None
            block[0:6] += flat
            block[15:21] += flat
        elif kind in where:
            at, keys = where[kind]
            flat = np.concatenate([values[k].detach().cpu().double().numpy().reshape(-1)
                                   for k in keys])  # fmt: skip
            width = 6 if kind in (LinearDrag, QuadraticDrag) else (3 if kind is ForceField else S)
            if flat.size != width:
                return None
            block[at : at + width] += flat
        elif kind is SlackSprings:
            block[EFFECT_HEAD + 2 * S + values["springs"].cpu().numpy().astype(int)] = 1.0
        else:
            return None
    if radius is None:
        radius = np.zeros(topology.n_rods)
    return contact, block, radius


def _model_rows(
    fields: dict[str, torch.Tensor], batched: dict[str, bool], B: int
) -> torch.Tensor | None:
    """The batched parameters side by side, one row per assembly (B, ·), or None where
    a batch dimension is not the state's."""
    cols = []
    for k, b in batched.items():
        if not b:
            continue
        v = fields[k].detach()
        if v.shape[0] != B:
            return None
        cols.append(v.reshape(B, -1))
    return torch.cat(cols, dim=1)


def _runs(rows: torch.Tensor) -> np.ndarray:
    """Where each run of equal consecutive rows starts, and the end: (G + 1,)."""
    change = torch.nonzero((rows[1:] != rows[:-1]).any(dim=1))[:, 0] + 1
    return np.concatenate([[0], change.numpy(), [rows.shape[0]]]).astype(np.int64)


def _springs(engine: Engine) -> np.ndarray:
    """The springs' node pairs (S, 2) as the kernel takes them, kept on the engine."""
    springs = engine.__dict__.get("_native_springs")
    if springs is None:
        springs = np.ascontiguousarray(engine.topology.spring_nodes, dtype=np.int32)
        engine.__dict__["_native_springs"] = springs
    return springs
