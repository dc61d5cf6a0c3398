"""Dry (Coulomb) friction along each spring: a cable that rubs where it is routed.

Gate: acts along every spring whose length changes. Each spring ``s`` carries an extra
tension that opposes its elongation rate ``l̇`` [m/s] with a bounded size ``F_s`` [N]:

    ``T_s += F_s tanh(l̇_s / v_ε)``

(positive tension pulls the spring's two nodes together, so the friction resists
lengthening and shortening alike and only removes energy). Coulomb's law
``F_s sign(l̇)`` is discontinuous at ``l̇ = 0``; the regularisation velocity
:data:`REGULARISATION_VELOCITY` ``v_ε`` smooths it, so the force is differentiable and
the explicit step stays stable: below ``v_ε`` the friction acts as a damper
``F_s / v_ε``, above ``3 v_ε`` it is within 1 % of ``F_s``.

The tension is linear in ``F_s`` for a fixed ``v_ε``, so the one-step regression fits
it with the springs' stiffness and damping. MuJoCo's tendon ``frictionloss`` is the
same bounded friction, solved as a soft constraint (``solreffriction``) rather than
through a smooth sign: the two agree where the cables slide faster than ``v_ε`` and
differ near sticking (``tests/unit/test_spring_friction.py`` states the tolerance).

In the C kernel the law is the per-spring ``spring_friction`` slot with ``v_ε`` in the
``friction_velocity`` slot (:attr:`SpringFriction.native`).
"""

from __future__ import annotations

from typing import ClassVar

import torch

from tensegrity_env.effects.base import Gate, MujocoPlant, NativeForm, ParamSpec, SpringLawEffect
from tensegrity_env.engine.forces import spring_frames
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.params import Params

#: v_ε [m/s]: the smooth sign's width; a tensegrity's cables slide at 0.1-1 m/s, so
#: below 1 cm/s the friction is a stiff damper and above 3 cm/s the full Coulomb force
REGULARISATION_VELOCITY = 0.01


class SpringFriction(SpringLawEffect):
    """Per-spring dry friction ``friction`` F (S,) [N]: ``T += F tanh(l̇ / v_ε)``."""

    name: ClassVar[str] = "spring_friction"
    summary: ClassVar[str] = "dry (Coulomb) friction along each spring, opposing l̇"
    dissipative: ClassVar[bool] = True
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "friction": ParamSpec("N", 0.0, per="spring"),
    }
    gate: ClassVar[Gate] = Gate("acts along every spring whose length changes, opposing l̇")
    native: ClassVar[NativeForm | None] = NativeForm(
        "block",
        ("spring_friction",),
        ("friction",),
        constants=(("friction_velocity", REGULARISATION_VELOCITY),),
    )
    plant: ClassVar[MujocoPlant | None] = MujocoPlant(
        "tendon",
        "frictionloss",
        ignore=("tendon-friction",),
        params=("friction",),
        note="tendon frictionloss (soft dry-friction constraint)",
    )

    def factor(self, state: State, kin: Kinematics, params: Params) -> torch.Tensor:
        """``tanh(l̇ / v_ε)`` of every spring, (B, S) [-]."""
        nodes = torch.as_tensor(self.topology.spring_nodes, dtype=torch.long, device=kin.x.device)
        rate = spring_frames(kin, nodes[:, 0], nodes[:, 1]).rate
        return torch.tanh(rate / REGULARISATION_VELOCITY)

    def check(self) -> None:
        """Dry friction opposes sliding: ``F_s >= 0`` (or within 3 standard errors of 0)."""
        self.check_nonnegative("dry friction opposes sliding")
