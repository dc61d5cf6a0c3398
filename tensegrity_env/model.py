"""One spring-rod model: topology, declared parameters, effects and time step.

:class:`Model` is the fixed description that the engine, the environments and the
identification pass around (the role Brax's ``System`` plays there): which rods and
springs (:class:`~tensegrity_env.topology.Topology`), their physical values
(:class:`~tensegrity_env.params.Params`), the effects beyond linear springs, gravity and
control (ground contact, drag, ... from :mod:`tensegrity_env.effects`), and the
integrator step ``dt`` [s]. It is also the ``params.json`` document:
:meth:`Model.load` reads one, :meth:`Model.save` writes one (atomically)::

    model = Model.load("params.json")
    engine = model.engine()
    x_next = engine.step(x, model.params)

``params.json`` holds the continuous-time physics only; ``dt`` is not stored in it:
:meth:`Model.load` takes it as an argument (default :data:`DEFAULT_DT`, the MuJoCo
twin's 1 ms).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from tensegrity_env.effects import effects_from_document, effects_to_document
from tensegrity_env.io_utils import InputError, atomic_write_json
from tensegrity_env.params import (
    PARAMS_FORMAT,
    PARAMS_VERSION,
    UNITS,
    Params,
    load_params_document,
    params_from_dict,
    params_to_dict,
)
from tensegrity_env.topology import Topology, TopologyError

if TYPE_CHECKING:
    from tensegrity_env.effects.base import PhysicalEffect
    from tensegrity_env.engine import Engine

#: integrator step of a loaded model unless given [s] (the MuJoCo twin's timestep)
DEFAULT_DT = 1e-3
#: top-level sections of ``params.json`` that :class:`Model` itself writes
MODEL_SECTIONS = ("format", "version", "units", "topology", "params", "effects")


@dataclass(frozen=True)
class Model:
    """A spring-rod model: what the engine needs to step it.

    Attributes:
        topology: rods, springs and end caps.
        params: declared physical parameters (shapes per :class:`Params`; units in
            :data:`tensegrity_env.params.UNITS`).
        effects: effect modules applied after the declared forces, in order
            (contact last); a tuple (a list given is converted).
        dt: integrator step [s].
    """

    topology: Topology
    params: Params
    effects: tuple[PhysicalEffect, ...] = ()
    dt: float = DEFAULT_DT

    def __post_init__(self) -> None:
        object.__setattr__(self, "effects", tuple(self.effects))
        object.__setattr__(self, "dt", float(self.dt))
        if not self.dt > 0:
            raise ValueError(f"Model: dt must be > 0 s, got {self.dt}")

    @property
    def effect_names(self) -> list[str]:
        """Names of the effects, in order."""
        return [e.name for e in self.effects]

    def replace(self, **changes: Any) -> Model:
        """A copy with some fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def engine(
        self,
        dtype: torch.dtype = torch.float64,
        device: str | torch.device = "cpu",
        physics_dt: float | None = None,
    ) -> Engine:
        """The differentiable engine of this model (parameters are passed per step).

        Each :meth:`~tensegrity_env.engine.Engine.step` advances :attr:`dt` [s] in
        substeps of at most ``physics_dt`` [s] (default
        :data:`~tensegrity_env.engine.PHYSICS_DT`, 1 ms;
        :func:`~tensegrity_env.engine.substeps_for`): a model loaded at a motion-capture
        rate (``dt=1/120``) steps at 0.93 ms, as ``identify`` and ``diagnose`` integrate
        it by default (``--physics-dt``), not once per sample interval.
        """
        from tensegrity_env.engine import PHYSICS_DT, Engine, substeps_for

        substeps = substeps_for(self.dt, PHYSICS_DT if physics_dt is None else physics_dt)
        return Engine(self.topology, self.dt, self.effects, dtype=dtype, device=device,
                      substeps=substeps)  # fmt: skip

    def violation(self) -> str:
        """What lies outside the physical domain, in one line, or ``""`` when nothing does.

        The checks :meth:`load` applies: :meth:`~tensegrity_env.params.Params.validate`
        on the declared parameters and each effect's
        :meth:`~tensegrity_env.effects.base.PhysicalEffect.check` (for example drag
        coefficients >= 0 within 3 of their standard errors).
        """
        return self.params_violation() or self.effects_violation()

    def effects_violation(self) -> str:
        """The first effect's :meth:`~tensegrity_env.effects.base.PhysicalEffect.check`
        failure, or ``""`` when every effect lies in its physical domain."""
        return next((v for v in (e.violation() for e in self.effects) if v), "")

    def params_violation(self) -> str:
        """What of the declared parameters lies outside the physical domain, or ``""``."""
        try:
            self.params.validate(self.topology, source="declared parameters")
        except InputError as e:
            return str(e)
        return ""

    # ------------------------------------------------------------------ files
    @classmethod
    def read(cls, path: str | Path, dt: float = DEFAULT_DT) -> Model:
        """A declared model from a ``params.json`` (:meth:`load`), a robot MJCF
        (``.xml``: its parameters, and as effects what it declares beyond linear springs,
        see :meth:`~tensegrity_env.mjcf.MjcfAssembly.declared_effects`) or an NTRT YAML
        model (``.yaml``: :func:`~tensegrity_env.ntrt.from_ntrt`, a floor and
        tension-only cables declared); raises
        :class:`InputError` naming the file."""
        path = Path(path)
        if path.suffix.lower() in (".yaml", ".yml"):
            from tensegrity_env.ntrt import from_ntrt

            robot = from_ntrt(path)
            return cls(robot.topology, robot.params, tuple(robot.declared_effects()), dt)
        if path.suffix.lower() != ".xml":
            return cls.load(path, dt)
        from tensegrity_env.mjcf import from_mjcf

        asm = from_mjcf(path)
        return cls(asm.topology, asm.params, tuple(asm.declared_effects()), dt)

    @classmethod
    def load(cls, path: str | Path, dt: float = DEFAULT_DT) -> Model:
        """Read a ``params.json`` file; raises :class:`InputError` naming the file.

        Effects listed in its ``effects`` section are built (a residual network's
        sidecar weights are read relative to the file's directory). The file's other
        sections (provenance, identifiability, ...) are left to
        :func:`~tensegrity_env.params.load_params_document`.
        """
        path = Path(path)
        doc = load_params_document(path)
        try:
            topology = Topology.from_dict(doc["topology"])
        except (KeyError, TopologyError) as e:
            raise InputError(f"{path}: bad topology ({e})") from None
        params = params_from_dict(doc.get("params", {}), source=str(path))
        params.validate(topology, source=str(path))
        try:
            effects = effects_from_document(doc, topology, root=path.parent)
        except InputError as e:
            raise InputError(f"{path}: {e}") from None
        return cls(topology, params, tuple(effects), dt)

    def to_document(self, extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The ``params.json`` document (a JSON-ready dict).

        ``extra``: further top-level sections, for example ``identifiability`` (what
        the data could and could not determine), ``diagnose`` or ``provenance``; they
        may not replace the model's own sections (:data:`MODEL_SECTIONS`).
        """
        clash = sorted(set(extra or {}) & set(MODEL_SECTIONS))
        if clash:
            raise ValueError(f"Model.to_document: extra sections {clash} are the model's own")
        doc: dict[str, Any] = {
            "format": PARAMS_FORMAT,
            "version": PARAMS_VERSION,
            "units": UNITS,
            "topology": self.topology.to_dict(),
            "params": params_to_dict(self.params),
            "effects": effects_to_document(self.effects),
        }
        doc.update(extra or {})
        return doc

    def save(self, path: str | Path, extra: Mapping[str, Any] | None = None) -> Path:
        """Write ``params.json`` atomically (temporary file, then rename); returns the path.

        ``extra`` as in :meth:`to_document`; values that are not finite (an infinite
        standard error) are written as ``null``
        (:func:`~tensegrity_env.io_utils.atomic_write_json`). A residual network's
        sidecar weights are not written here (``ResidualNetwork.save``).
        """
        return atomic_write_json(path, self.to_document(extra))
