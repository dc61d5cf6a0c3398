"""Translational and rotational drag on each rod, per axis of the rod's principal frame.

Gate: acts everywhere, opposing the motion. With ``v_l = Rᵀ v`` the centre-of-mass
velocity and ``ω_l`` the angular velocity in the rod's principal frame, per axis i:

* :class:`LinearDrag` (viscous, Stokes): ``F_l,i = -b_i v_l,i``, ``τ_l,i = -β_i ω_l,i``;
* :class:`QuadraticDrag` (pressure drag): ``F_l,i = -k_i |v_l,i| v_l,i``,
  ``τ_l,i = -κ_i |ω_l,i| ω_l,i``.

Forces act at the centre of mass; coefficients are shared by all rods (same
geometry) and differ per axis (a rod is slender: its axial drag is small). This is
the form of MuJoCo's inertia-box fluid model (``option density/viscosity``).

Linear drag has two forms, written as ``"form"`` in the params file's entry:

* ``explicit`` (:class:`LinearDrag`, the default): the drag wrench joins every other
  force, so the physics step must stay below ``2 I / β`` (a thin rod's tiny axial
  inertia makes that step short);
* ``implicit`` (:class:`ImplicitLinearDrag`): the damping is integrated implicitly,
  per rod axis ``(M + h b) v' = M v + h f`` and ``(I + h β) ω_l' = I ω_l + h τ_l``
  (``h`` the physics step, ``f``, ``τ_l`` every other force and torque): stable for
  any ``β``, and equal to MuJoCo's joint ``damping`` on a free joint under its Euler
  integrator (isotropic ``b = β``, body frame at the centre of mass). Both forms agree
  to a relative ``h b / M`` per step.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import torch

from tensegrity_env.effects.base import (
    FitForm,
    Gate,
    LinearEffect,
    MujocoPlant,
    NativeForm,
    ParamSpec,
)
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params
from tensegrity_env.rotations import quat_to_matrix
from tensegrity_env.topology import Topology
from tensegrity_env.vec3 import rotate_t

#: the forms of linear drag (the params file's ``"form"``)
LINEAR_DRAG_FORMS = ("explicit", "implicit")


def _axis_basis(rot: torch.Tensor, rate_local: torch.Tensor, quadratic: bool) -> torch.Tensor:
    """World vectors ``-R e_i φ(x_i)`` per axis i, (B, R, 3, 3): last dim = parameter."""
    phi = rate_local.abs() * rate_local if quadratic else rate_local  # (B, R, 3)
    return -rot * phi.unsqueeze(-2)  # column i of R times φ_i


class _Drag(LinearEffect):
    quadratic: ClassVar[bool] = False
    dissipative: ClassVar[bool] = True
    #: theta = translational (3) then rotational (3): rotational entries start at 3
    fit_form: ClassVar[FitForm] = FitForm(roll_entry=3)

    def basis(
        self, state: State, kin: Kinematics, params: Params
    ) -> tuple[torch.Tensor, torch.Tensor]:
        rot = kin.rot
        v_l = rotate_t(rot, state.v)
        w_l = rotate_t(rot, state.omega)
        zero = torch.zeros_like(rot)
        f_t = _axis_basis(rot, v_l, self.quadratic)
        t_r = _axis_basis(rot, w_l, self.quadratic)
        return torch.cat([f_t, zero], -1), torch.cat([zero, t_r], -1)

    def check(self) -> None:
        """Drag opposes motion: coefficients >= 0 (or within 3 standard errors of 0)."""
        self.check_nonnegative("drag opposes motion")


class LinearDrag(_Drag):
    """Viscous drag: ``translational`` b (3,) [N*s/m], ``rotational`` β (3,) [N*m*s]."""

    name: ClassVar[str] = "linear_drag"
    summary: ClassVar[str] = "viscous drag opposing v and ω, per rod axis"
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "translational": ParamSpec("N*s/m", 0.0, shape=(3,)),
        "rotational": ParamSpec("N*m*s", 0.0, shape=(3,)),
    }
    gate: ClassVar[Gate] = Gate("acts everywhere, opposing v and ω")
    native: ClassVar[NativeForm | None] = NativeForm(
        "block", ("linear_drag",), ("translational", "rotational")
    )
    plant: ClassVar[MujocoPlant | None] = MujocoPlant(
        "option", "viscosity", ignore=("fluid",), note="inertia-box fluid"
    )
    #: how the engine integrates it (see the module docstring)
    form: ClassVar[str] = "explicit"

    def to_dict(self) -> dict[str, Any]:
        """The base entry, plus ``"form": "implicit"`` for the implicit form."""
        doc = super().to_dict()
        if self.form != "explicit":
            doc["form"] = self.form
        return doc

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any], topology: Topology) -> LinearDrag:
        """Rebuild from :meth:`to_dict` output in its ``"form"`` (default explicit)."""
        form = doc.get("form", "explicit")
        if form not in LINEAR_DRAG_FORMS:
            raise InputError(
                f"effect 'linear_drag': form must be one of {', '.join(LINEAR_DRAG_FORMS)}, "
                f"got {form!r}"
            )
        target = ImplicitLinearDrag if form == "implicit" else LinearDrag
        return super(LinearDrag, target).from_dict(doc, topology)


class ImplicitLinearDrag(LinearDrag):
    """Viscous drag integrated implicitly (``"form": "implicit"``; see the module docstring).

    The wrench is that of :class:`LinearDrag`; :meth:`implicit_damping` hands the
    engine the coefficients it integrates implicitly. In a one-step regression the
    equation of motion is ``M a = f - b v'`` with ``v'`` the velocity after the step,
    so :meth:`transition_basis` evaluates the basis there.
    """

    form: ClassVar[str] = "implicit"
    #: its wrench, and the same coefficients integrated implicitly
    native: ClassVar[NativeForm | None] = NativeForm(
        "block", ("linear_drag", "implicit_damping"), ("translational", "rotational")
    )
    #: MuJoCo's free-joint damping is planted as a plant of its own (``joint_damping``)
    plant: ClassVar[MujocoPlant | None] = None

    def implicit_damping(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Translational b (3,) [N*s/m] and rotational β (3,) [N*m*s] per rod axis."""
        return self.value("translational", like), self.value("rotational", like)

    def transition_basis(
        self, s0: State, s1: State, kin: Kinematics, params: Params
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The basis at the velocities after the step: ``v_l' = R_0ᵀ v_1``, ``ω_l' = R_1ᵀ ω_1``."""
        rot0, rot1 = kin.rot, quat_to_matrix(s1.q)
        v_l = rotate_t(rot0, s1.v)
        w_l = rotate_t(rot1, s1.omega)
        zero = torch.zeros_like(rot0)
        f_t = _axis_basis(rot0, v_l, False)
        t_r = _axis_basis(rot0, w_l, False)
        return torch.cat([f_t, zero], -1), torch.cat([zero, t_r], -1)


class QuadraticDrag(_Drag):
    """Pressure drag: ``translational`` k (3,) [N*s²/m²], ``rotational`` κ (3,) [N*m*s²]."""

    name: ClassVar[str] = "quadratic_drag"
    summary: ClassVar[str] = "quadratic (pressure) drag opposing v|v| and ω|ω|, per rod axis"
    quadratic: ClassVar[bool] = True
    #: ``|v_x| v_x + |v_y| v_y`` across the rod changes with its roll, even with equal
    #: cross coefficients (MuJoCo's box drag does too); linear drag with equal ones does not
    sees_roll: ClassVar[bool] = True
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "translational": ParamSpec("N*s^2/m^2", 0.0, shape=(3,)),
        "rotational": ParamSpec("N*m*s^2", 0.0, shape=(3,)),
    }
    gate: ClassVar[Gate] = Gate("acts everywhere, opposing v|v| and ω|ω|")
    native: ClassVar[NativeForm | None] = NativeForm(
        "block", ("quadratic_drag",), ("translational", "rotational")
    )
    plant: ClassVar[MujocoPlant | None] = MujocoPlant(
        "option", "density", ignore=("fluid",), note="inertia-box fluid"
    )
