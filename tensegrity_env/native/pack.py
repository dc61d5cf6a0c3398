"""One adapter from a model to the C kernel: :func:`pack_model`.

The environments' stepper and the engine's no-gradient step both pack their model here:
the topology, the parameters (one set, or one per run of assemblies that share them;
the winches' speeds, ranges and lags among them) and the effects, each as its class
declares (its ``native`` form: slots of the effects block, :data:`EFFECT_SLOTS`, or the
contact law), in ``native_step.h``'s layout. A model the kernel does not compute raises :class:`NotNative` with the
reason (an effect's declared ``no_native``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from tensegrity_env.effects.base import NativeForm
from tensegrity_env.native.kernel import CONTACT_LAW
from tensegrity_env.topology import Topology

#: entries of the kernel's effects block besides the per-spring ones: linear drag b, β,
#: quadratic drag k, κ (3 each, per rod axis), a force field (3), the linear damping
#: integrated implicitly b, β (3 each) and the dry friction's regularisation velocity (1)
EFFECT_HEAD = 22
#: per-spring entries of the effects block: cubic stiffness, rest-length offset, slack
#: mask, dry friction
PER_SPRING = 4


def effect_slots(n_springs: int) -> dict[str, tuple[int, int]]:
    """The effects block's slots, name -> (offset, width), for ``n_springs`` springs:
    ``native_step.h``'s layout (:data:`EFFECT_HEAD` entries, then :data:`PER_SPRING`
    per spring)."""
    S, H = n_springs, EFFECT_HEAD
    return {
        "linear_drag": (0, 6), "quadratic_drag": (6, 6), "force_field": (12, 3),
        "implicit_damping": (15, 6), "friction_velocity": (21, 1), "cubic_stiffness": (H, S),
        "rest_length_offset": (H + S, S), "slack": (H + 2 * S, S),
        "spring_friction": (H + 3 * S, S),
    }  # fmt: skip


#: the slots' names (:func:`effect_slots`), for effects to declare theirs against
EFFECT_SLOTS = tuple(effect_slots(0))

#: the winches' parameters in the order the kernel's model holds them, each (W,)
WINCH_PARAMS = ("winch_speed", "winch_lag", "winch_min", "winch_max")

#: the parameters a batch dimension may vary, with their unbatched number of dimensions
BATCHED = {"stiffness": 1, "damping": 1, "rest_length": 1, "mass": 1, "inertia": 2,
           "control_gain": 0, **dict.fromkeys(WINCH_PARAMS, 1)}  # fmt: skip

#: the parameters the kernel's model holds (the batched ones and gravity (3,))
PACKED_PARAMS = (*BATCHED, "gravity")

__all__ = ["BATCHED", "EFFECT_HEAD", "EFFECT_SLOTS", "PACKED_PARAMS", "PER_SPRING",
           "WINCH_PARAMS", "NotNative", "PackedModel", "effect_slots", "effects_block",
           "model_vector", "pack_model"]  # fmt: skip


class NotNative(ValueError):
    """The kernel does not compute this model (the message says why)."""


@dataclass(frozen=True)
class PackedModel:
    """A model in the kernel's layout.

    Attributes:
        models: (G, L) float64, one packed model per run of assemblies (G = 1 where
            every assembly shares the parameters).
        start: (G + 1,) int64, where each model's run of assemblies starts, then the
            batch size (``[0, B]`` for one model; ``[0, 0]`` where the batch is open).
    """

    models: np.ndarray
    start: np.ndarray


def pack_model(
    topology: Topology,
    params: Mapping[str, torch.Tensor],
    effects: Sequence[object],
    batch: int | None = None,
) -> PackedModel:
    """``topology`` with ``params`` (:data:`PACKED_PARAMS`: the
    :class:`~tensegrity_env.params.Params` fields of those names) and ``effects``, in
    the kernel's layout.

    ``batch``: the number of assemblies B it will step. Parameters with a batch
    dimension (B, ·) (a forward-difference Jacobian's perturbed copies) give one model
    per run of consecutive assemblies that share them; None: one model for any batch
    (batched parameters are refused).

    Raises:
        NotNative: an effect the kernel does not have, or parameters it does not take.
    """
    if params["gravity"].numel() != 3:
        raise NotNative("gravity is not one vector (3,)")
    W = topology.n_winches
    for k in WINCH_PARAMS:
        if params[k].shape[-1:] != (W,):
            raise NotNative(f"{k} has shape {tuple(params[k].shape)}, the robot {W} winch(es)")
    contact, block, radius = effects_block(effects, topology)
    batched = {k: params[k].dim() > n for k, n in BATCHED.items()}
    values: dict[str, np.ndarray]
    if any(batched.values()):
        if batch is None:
            raise NotNative("parameters with a batch dimension")
        start = _runs(_model_rows(params, batched, batch))
        first = torch.as_tensor(start[:-1])
        G = len(first)
        values = {"gravity": _array(params["gravity"])}
        for k in BATCHED:
            v = params[k].detach()
            v = v[first] if batched[k] else v.unsqueeze(0).expand(G, *v.shape)
            values[k] = _array(v.reshape(G, -1))
    else:
        values = {k: _array(params[k]) for k in PACKED_PARAMS}
        start = np.array([0, 0 if batch is None else batch], dtype=np.int64)
    models = model_vector(topology, values, contact, radius, block)
    return PackedModel(np.ascontiguousarray(models.reshape(-1, models.shape[-1])), start)


def effects_block(
    effects: Sequence[object], topology: Topology
) -> tuple[dict[str, float] | None, np.ndarray, np.ndarray]:
    """The kernel's view of ``effects``: the ground contact's law (None without one),
    the effects block (``native_step.h``'s layout, :data:`EFFECT_HEAD` + 3 S) and the
    end caps' contact radii (R,) [m].

    Raises:
        NotNative: an effect with no native form, or parameters not the single set the
            kernel takes (a batch of them).
    """
    S = topology.n_springs
    block = np.zeros(EFFECT_HEAD + PER_SPRING * S)
    slots = effect_slots(S)
    contact, radius = None, None
    for e in effects:
        values: dict[str, torch.Tensor] = getattr(e, "values", {})
        name = getattr(e, "name", type(e).__name__)
        # declared on the effect's own class: a subclass that changes the force (a
        # different law) must declare its form again, or it steps in PyTorch
        form: NativeForm | None = vars(type(e)).get("native")
        if form is None:
            why = vars(type(e)).get("no_native", "its class declares none")
            raise NotNative(f"effect '{name}' has no native form: {why}")
        if form.kind == "contact":
            if contact is not None:
                raise NotNative(f"more than one {name} effect")
            law = {k: v for k, v in values.items() if k in CONTACT_LAW}
            if not all(v.numel() == 1 for v in law.values()):
                raise NotNative(f"{name}: the kernel takes one value per parameter of the law")
            contact = {k: float(v.detach()) for k, v in law.items()}
            radius = e.radius.detach().cpu().double().numpy().reshape(-1, 2)  # type: ignore[attr-defined]  # the "contact" form carries end-cap radii
        elif form.kind == "mask":
            idx = values[form.keys[0]].cpu().numpy().astype(int)
            for slot in form.slots:
                block[slots[slot][0] + idx] = 1.0
        else:
            flat = _flat(values, form.keys)
            for slot in form.slots:
                at, width = slots[slot]
                if flat.size != width:
                    raise NotNative(f"{name}: the kernel takes {width} values, got {flat.size}")
                block[at : at + width] += flat
        for slot, value in form.constants:
            block[slots[slot][0]] = value
    if radius is None:
        radius = np.zeros((topology.n_rods, 2))
    return contact, block, radius


def model_vector(
    topology: Topology,
    params: Mapping[str, np.ndarray],
    contact: Mapping[str, float] | None,
    radius: np.ndarray,
    effects: np.ndarray | None = None,
) -> np.ndarray:
    """The kernel's packed model (``native_step.h``'s layout) of ``topology`` with
    ``params`` (arrays of :data:`PACKED_PARAMS`) and the ground contact's ``contact``
    values (:data:`CONTACT_LAW`; None: no contact); ``radius`` (R, 2) [m] the end caps'
    contact radii; ``effects`` the effects block (:data:`EFFECT_HEAD` + 4 S entries;
    None: no effect beside contact). The winches' block follows: W, each spring's winch
    (1 + its index, 0: none) (S,), then :data:`WINCH_PARAMS` (W,) each (absent from
    ``params``: the topology has no winch).

    ``params`` may carry a batch dimension (stiffness (G, S), mass (G, R), inertia
    (G, R, 3), control gain (G, ...), winch parameters (G, W)): one model per row,
    (G, L); else (L,).
    """
    S, W = topology.n_springs, topology.n_winches
    c = np.zeros(8) if contact is None else np.array([1.0, *(contact[k] for k in CONTACT_LAW)])
    if effects is None:
        effects = np.zeros(EFFECT_HEAD + PER_SPRING * S)
    winch_of = np.zeros(S)
    winch_of[np.asarray(topology.winches, dtype=int)] = np.arange(1, W + 1)
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
        per_model(params["gravity"], 3), per_model(c, 8), per_model(radius, 2 * R),
        per_model(topology.frame_origins, 3 * R),
        per_model(np.array([float(r.end_cap == "sphere") for r in topology.rods]), R),
        per_model(np.array([float(topology.n_points)]), 1),
        per_model(topology.point_rods.astype(float), topology.n_points),
        per_model(topology.point_offsets, 3 * topology.n_points),
        per_model(effects, EFFECT_HEAD + PER_SPRING * S),
        per_model(np.array([float(W)]), 1), per_model(winch_of, S),
        *(per_model(params.get(k, np.zeros(0)), W) for k in WINCH_PARAMS),
    ]  # fmt: skip
    out = np.ascontiguousarray(np.concatenate(parts, axis=1), dtype=np.float64)
    return out if G else out[0]


def _array(t: torch.Tensor) -> np.ndarray:
    """``t`` as a float64 NumPy array (detached, on the CPU)."""
    return np.asarray(t.detach().cpu().numpy(), dtype=np.float64)


def _flat(values: Mapping[str, torch.Tensor], keys: Sequence[str]) -> np.ndarray:
    """The effect's ``keys`` values one after the other, float64, flat."""
    return np.concatenate([values[k].detach().cpu().double().numpy().reshape(-1) for k in keys])


def _model_rows(
    params: Mapping[str, torch.Tensor], batched: Mapping[str, bool], B: int
) -> torch.Tensor:
    """The batched parameters side by side, one row per assembly (B, ·). Raises
    :class:`NotNative` where a batch dimension is not the state's."""
    cols = []
    for k, b in batched.items():
        if not b:
            continue
        v = params[k].detach()
        if v.shape[0] != B:
            raise NotNative(f"{k} has a batch of {v.shape[0]}, the state one of {B}")
        cols.append(v.reshape(B, -1))
    return torch.cat(cols, dim=1)


def _runs(rows: torch.Tensor) -> np.ndarray:
    """Where each run of equal consecutive rows starts, and the end: (G + 1,)."""
    change = torch.nonzero((rows[1:] != rows[:-1]).any(dim=1))[:, 0] + 1
    return np.concatenate([[0], change.numpy(), [rows.shape[0]]]).astype(np.int64)
