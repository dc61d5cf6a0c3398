"""Translational and rotational drag on each rod, per axis of the rod's principal frame.

Gate: acts everywhere, opposing the motion. With ``v_l = Rᵀ v`` the centre-of-mass
velocity and ``ω_l`` the angular velocity in the rod's principal frame, per axis i:

* :class:`LinearDrag` (viscous, Stokes): ``F_l,i = -b_i v_l,i``, ``τ_l,i = -β_i ω_l,i``;
* :class:`QuadraticDrag` (pressure drag): ``F_l,i = -k_i |v_l,i| v_l,i``,
  ``τ_l,i = -κ_i |ω_l,i| ω_l,i``.

Forces act at the centre of mass; coefficients are shared by all rods (same
geometry) and differ per axis (a rod is slender: its axial drag is small). This is
the form of MuJoCo's inertia-box fluid model (``option density/viscosity``).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import torch

from tensegrity_env.effects.base import LinearEffect, ParamSpec
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params


def _axis_basis(rot: torch.Tensor, rate_local: torch.Tensor, quadratic: bool) -> torch.Tensor:
    """World vectors ``-R e_i φ(x_i)`` per axis i, (B, R, 3, 3): last dim = parameter."""
    phi = rate_local.abs() * rate_local if quadratic else rate_local  # (B, R, 3)
    return -rot * phi.unsqueeze(-2)  # column i of R times φ_i


class _Drag(LinearEffect):
    quadratic: ClassVar[bool] = False

    def basis(
        self, state: State, kin: Kinematics, params: Params
    ) -> tuple[torch.Tensor, torch.Tensor]:
        rot = kin.rot
        v_l = torch.einsum("brji,brj->bri", rot, state.v)
        w_l = torch.einsum("brji,brj->bri", rot, state.omega)
        zero = torch.zeros_like(rot)
        f_t = _axis_basis(rot, v_l, self.quadratic)
        t_r = _axis_basis(rot, w_l, self.quadratic)
        return torch.cat([f_t, zero], -1), torch.cat([zero, t_r], -1)

    def check(self) -> None:
        """Drag opposes motion: coefficients >= 0 (or within 3 standard errors of 0)."""
        for k, v in self.values.items():
            se = torch.as_tensor(np.nan_to_num(np.asarray(self.uncertainty.get(k, 0.0), float)))
            if (v.detach() < -3 * se.to(v)).any():
                raise InputError(f"effect '{self.name}': '{k}' must be >= 0 (drag opposes motion)")


class LinearDrag(_Drag):
    """Viscous drag: ``translational`` b (3,) [N*s/m], ``rotational`` β (3,) [N*m*s]."""

    name: ClassVar[str] = "linear_drag"
    summary: ClassVar[str] = "viscous drag opposing v and ω, per rod axis"
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "translational": ParamSpec("N*s/m", 0.0, shape=(3,)),
        "rotational": ParamSpec("N*m*s", 0.0, shape=(3,)),
    }


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
