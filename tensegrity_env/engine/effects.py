"""The plug-in point for force effects beyond linear springs, gravity and control.

An effect is a small module with physical parameters. The engine's step calls
every effect at two fixed points, with no special cases for any of them:

* ``tension(frame, tension, kin)`` may rewrite the spring tensions (B, S) [N]
  (slack springs, cubic stiffness, rest-length offsets);
* ``wrench(state, kin, params)`` may add a force and torque (B, R, 3) on each rod
  about its centre of mass, world frame (drag, force fields).

An effect whose wrench is linear damping ``-b v_l``, ``-β ω_l`` per rod axis may also
return ``(b, β)`` from ``implicit_damping(like)`` (each (3,) or (R, 3)): the engine then
integrates that damping implicitly (see :meth:`~tensegrity_env.engine.step.Engine.accelerations`).

An effect with ``constraint = True`` (ground contact) reacts to everything else, as
MuJoCo's constraint solver does: the engine calls its ``wrench`` last, with
``applied=(force, torque)``, the total wrench of springs, control and every other
effect on each rod, so that the contact force depends on how hard the rest pushes.
"""

from __future__ import annotations

from typing import ClassVar, Protocol, runtime_checkable

import torch

from tensegrity_env.engine.forces import SpringFrame
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.params import Params


@runtime_checkable
class Effect(Protocol):
    """A physical effect the engine can include. Subclass :class:`EffectBase`."""

    @property
    def name(self) -> str: ...

    @property
    def constraint(self) -> bool: ...

    def tension(
        self, frame: SpringFrame, tension: torch.Tensor, kin: Kinematics
    ) -> torch.Tensor: ...

    def wrench(
        self,
        state: State,
        kin: Kinematics,
        params: Params,
        applied: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor] | None: ...

    def implicit_damping(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None: ...


class EffectBase:
    """Default no-op hooks; an effect overrides the ones where it acts."""

    name: ClassVar[str] = "effect"
    #: True for effects solved last against every applied force (see the module docstring)
    constraint: ClassVar[bool] = False

    def tension(self, frame: SpringFrame, tension: torch.Tensor, kin: Kinematics) -> torch.Tensor:
        return tension

    def wrench(
        self,
        state: State,
        kin: Kinematics,
        params: Params,
        applied: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Force and torque (B, R, 3) each on every rod [N, N*m], world frame; None: none.

        ``applied``: the wrench of everything else on each rod, passed to constraints
        (``constraint = True``) only; other effects leave it.
        """
        return None

    def implicit_damping(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Damping of the wrench integrated implicitly: b [N*s/m], β [N*m*s] per rod axis.

        None (the default): the wrench is integrated explicitly. ``like``: a tensor
        giving the dtype and device.
        """
        return None
