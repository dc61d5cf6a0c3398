"""A library of candidate effects beyond linear springs, gravity and control.

Every effect is a small module subclassing
:class:`tensegrity_env.engine.effects.EffectBase` (through
:class:`~tensegrity_env.effects.base.PhysicalEffect`) with physical parameters
(torch tensors, with units) and a physical gate (where it can act). :data:`EFFECTS`
maps each effect's ``name`` to its class; the params file's ``effects`` list holds
``effect.to_dict()`` entries, and::

    model = Model.load("params.json")  # tensegrity_env.model.Model
    engine = model.engine()

runs the extended model. A :class:`~tensegrity_env.effects.residual_network.ResidualNetwork`
entry (what the residual loop could not explain, NOT a physical effect) keeps its
weights in a sidecar file beside the params file: pass ``root=Path("params.json").parent``.
It is deliberately not in :data:`EFFECTS` (no named physical parameters; never a
candidate), but :func:`effect_from_dict` knows it by name.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from tensegrity_env.effects.base import LinearEffect, ParamSpec, PhysicalEffect
from tensegrity_env.effects.control import ControlLag
from tensegrity_env.effects.drag import ImplicitLinearDrag, LinearDrag, QuadraticDrag
from tensegrity_env.effects.force_field import ForceField
from tensegrity_env.effects.ground_contact import GroundContact
from tensegrity_env.effects.residual_network import ResidualNetwork
from tensegrity_env.effects.spring_friction import SpringFriction
from tensegrity_env.effects.springs import CubicStiffness, RestLengthOffset, SlackSprings
from tensegrity_env.io_utils import InputError
from tensegrity_env.topology import Topology

#: effect name -> class, every candidate the residual loop may add, in the order the
#: loop proposes them; its library, the trajectory fit's coordinates, the kernel packing
#: and the planted benchmarks read each class's declarations
EFFECTS: dict[str, type[PhysicalEffect]] = {
    cls.name: cls
    for cls in (
        GroundContact,
        SlackSprings,
        LinearDrag,
        QuadraticDrag,
        ForceField,
        CubicStiffness,
        RestLengthOffset,
        ControlLag,
        SpringFriction,
    )
}


def effect_from_dict(
    doc: Mapping[str, Any], topology: Topology, root: str | Path | None = None
) -> PhysicalEffect:
    """One effect from its ``to_dict()`` form. Raises :class:`InputError` if unknown.

    ``root``: the params file's directory, where a residual network's sidecar lies
    (None: the working directory).
    """
    if not isinstance(doc, Mapping) or "name" not in doc:
        raise InputError(f"effect entry {doc!r} needs a 'name'")
    name = str(doc["name"])
    if name == ResidualNetwork.name:
        return ResidualNetwork.from_dict(doc, topology, root)
    if name not in EFFECTS:
        raise InputError(f"unknown effect '{name}' (known: {', '.join(sorted(EFFECTS))})")
    return EFFECTS[name].from_dict(doc, topology)


def effects_from_document(
    doc: Mapping[str, Any], topology: Topology, root: str | Path | None = None
) -> list[PhysicalEffect]:
    """The effects listed in a params document (``load_params_document``); [] if none.

    ``root``: the params file's directory (sidecar files are relative to it).
    """
    entries = doc.get("effects", [])
    if not isinstance(entries, Sequence) or isinstance(entries, (str, bytes)):
        raise InputError("params file: 'effects' must be a list")
    return [effect_from_dict(e, topology, root) for e in entries]


def effects_to_document(effects: Sequence[PhysicalEffect]) -> list[dict[str, Any]]:
    """The ``effects`` section of a params file (``Model.save`` writes it)."""
    return [e.to_dict() for e in effects]


__all__ = [
    "EFFECTS",
    "ControlLag",
    "CubicStiffness",
    "ForceField",
    "GroundContact",
    "ImplicitLinearDrag",
    "LinearDrag",
    "LinearEffect",
    "ParamSpec",
    "PhysicalEffect",
    "QuadraticDrag",
    "ResidualNetwork",
    "RestLengthOffset",
    "SlackSprings",
    "SpringFriction",
    "effect_from_dict",
    "effects_from_document",
    "effects_to_document",
]
