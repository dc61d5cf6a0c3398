"""Spring laws beyond Hooke: cubic stiffness, rest-length offsets and slack (tension-only) cables.

All act along each spring's own axis (its 1-D frame) and use the fitted ``K`` and
``l0`` of the params:

* :class:`CubicStiffness`: ``T += k3_s (l - l0)^3`` [N], gate: grows with the
  stretch, both ways;
* :class:`RestLengthOffset`: ``T += -K_s δ_s`` [N] (the rest length is ``l0 + δ``),
  gate: a constant bias on one spring;
* :class:`SlackSprings`: the listed springs are cables, ``T = K (l - l0) + c l̇`` only
  while ``l > l0``; shorter than rest they carry only their damping (MuJoCo's tendon
  spring dead band ``springlength = (0, l0)``), gate: ``l < l0``.
"""

from __future__ import annotations

from typing import ClassVar

import torch

from tensegrity_env.effects.base import (
    Gate,
    NativeForm,
    ParamSpec,
    PhysicalEffect,
    SpringLawEffect,
    spring_lengths,
    spring_tension_wrench,
)
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params


class CubicStiffness(SpringLawEffect):
    """Per-spring cubic stiffness ``stiffness`` k3 (S,) [N/m^3]: ``T += k3 (l - l0)^3``."""

    name: ClassVar[str] = "cubic_stiffness"
    summary: ClassVar[str] = "spring tension grows with (l - l0)^3"
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "stiffness": ParamSpec("N/m^3", 0.0, per="spring", positive=False),
    }
    gate: ClassVar[Gate] = Gate("acts along every spring, grows with (l - l0)^3")
    native: ClassVar[NativeForm | None] = NativeForm("block", ("cubic_stiffness",), ("stiffness",))

    def factor(self, state: State, kin: Kinematics, params: Params) -> torch.Tensor:
        length, _ = spring_lengths(kin, self.topology)
        return (length - params.rest_length.to(length)) ** 3


class RestLengthOffset(SpringLawEffect):
    """Per-spring rest-length offset ``offset`` δ (S,) [m]: ``T += -K δ``."""

    name: ClassVar[str] = "rest_length_offset"
    summary: ClassVar[str] = "a constant tension bias -K δ on a spring"
    mass_scaled: ClassVar[bool] = False  # a length: its tension -K δ scales through K
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "offset": ParamSpec("m", 0.0, per="spring", positive=False),
    }
    gate: ClassVar[Gate] = Gate("rest lengths are given, not fitted")
    native: ClassVar[NativeForm | None] = NativeForm("block", ("rest_length_offset",), ("offset",))

    def factor(self, state: State, kin: Kinematics, params: Params) -> torch.Tensor:
        return -params.stiffness.to(kin.x).expand(kin.x.shape[0], -1)


class SlackSprings(PhysicalEffect):
    """Springs ``springs`` (indices) are cables: no elastic force while ``l < l0``."""

    name: ClassVar[str] = "slack_springs"
    summary: ClassVar[str] = "tension-only springs: no elastic force when shorter than rest"
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "springs": ParamSpec("spring index", [], integer=True),
    }
    #: each scorer names cables its own way (from rod states or from end caps)
    gate: ClassVar[Gate] = Gate("springs lose their stiffness when compressed", needs="scorer")
    native: ClassVar[NativeForm | None] = NativeForm("mask", ("slack",), ("springs",))

    def check(self) -> None:
        idx = self.values["springs"]
        if idx.numel() and (idx.min() < 0 or idx.max() >= self.topology.n_springs):
            raise InputError(
                f"effect '{self.name}': spring indices must be in 0..{self.topology.n_springs - 1}"
            )

    def mask(self, like: torch.Tensor) -> torch.Tensor:
        """1 for cable springs, 0 for the others, (S,)."""
        m = torch.zeros(self.topology.n_springs, dtype=like.dtype, device=like.device)
        m[self.values["springs"].to(like.device)] = 1.0
        return m

    def elastic(self, length: torch.Tensor, rest: torch.Tensor) -> torch.Tensor:
        """True where a spring is longer than rest or no cable, (B, S)."""
        return (length > rest) | (self.mask(rest) == 0)

    def wrench(
        self,
        state: State,
        kin: Kinematics,
        params: Params,
        applied: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        if self.values["springs"].numel() == 0:
            return None
        length, _ = spring_lengths(kin, self.topology)
        stretch = length - params.rest_length.to(length)
        # remove the elastic push of slack cables: -K (l - l0) where l < l0
        dT = -params.stiffness.to(length) * stretch * (stretch < 0) * self.mask(length)
        return spring_tension_wrench(kin, self.topology, dT)


class CompressionStiffness(SpringLawEffect):
    """Per-spring stiffness change in compression ``stiffness`` ΔK (S,) [N/m].

    ``T += ΔK (l - l0)`` while ``l < l0``. The probe of the slack-cable candidate: a
    cable shows ``ΔK = -K`` (it loses its whole elastic push when shorter than rest).
    """

    name: ClassVar[str] = "compression_stiffness"
    summary: ClassVar[str] = "spring stiffness changes by ΔK when shorter than rest"
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "stiffness": ParamSpec("N/m", 0.0, per="spring", positive=False),
    }
    no_native: ClassVar[str] = "it is the slack-cable probe of a regression, never stepped"

    def factor(self, state: State, kin: Kinematics, params: Params) -> torch.Tensor:
        length, _ = spring_lengths(kin, self.topology)
        return (length - params.rest_length.to(length)).clamp_max(0.0)
