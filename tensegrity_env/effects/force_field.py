"""A constant force on every rod: wind, or a gravity that is not quite what was assumed.

Gate: none (same on every rod, always). ``force`` (3,) [N] acts at each rod's centre
of mass, world frame. (A wrong gravity would scale with each rod's mass; for rods of
similar mass a constant force explains nearly all of it.)
"""

from __future__ import annotations

from typing import ClassVar

import torch

from tensegrity_env.effects.base import Gate, LinearEffect, NativeForm, ParamSpec
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.params import Params


class ForceField(LinearEffect):
    """A uniform force ``force`` (3,) [N] on every rod, world frame."""

    name: ClassVar[str] = "force_field"
    summary: ClassVar[str] = "the same constant force on every rod (wind, wrong gravity)"
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "force": ParamSpec("N", 0.0, shape=(3,), positive=False),
    }
    gate: ClassVar[Gate] = Gate("acts on every rod, always")
    native: ClassVar[NativeForm | None] = NativeForm("block", ("force_field",), ("force",))

    def basis(
        self, state: State, kin: Kinematics, params: Params
    ) -> tuple[torch.Tensor, torch.Tensor]:
        B, R = state.p.shape[:2]
        eye = torch.eye(3, dtype=state.p.dtype, device=state.p.device)
        force = eye.expand(B, R, 3, 3)
        return force, torch.zeros_like(force)
