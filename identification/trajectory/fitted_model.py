"""A model fitted to data with the bookkeeping of its fit: what the residual loop keeps
of every candidate and what the trajectory fits return as a model."""

from __future__ import annotations

from dataclasses import dataclass, field

from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.model import Model
from tensegrity_env.params import Params


@dataclass(frozen=True)
class FittedModel:
    """A model fitted by the residual loop, with the bookkeeping of the fit.

    Attributes:
        model: topology, declared parameters, effects (identified values and
            uncertainty) and time step.
        n_params: number of fitted parameters (for the information criterion).
        notes: remarks from the fit (effect name -> text).
        uncertainty: standard errors of the fitted declared parameters by name (e.g.
            ``stiffness[s0]``), in their units; empty where the fit states none.
    """

    model: Model
    n_params: int
    notes: dict[str, str] = field(default_factory=dict)
    uncertainty: dict[str, float] = field(default_factory=dict)

    @property
    def params(self) -> Params:
        return self.model.params

    @property
    def effects(self) -> list[PhysicalEffect]:
        return list(self.model.effects)

    @property
    def names(self) -> list[str]:
        return self.model.effect_names
