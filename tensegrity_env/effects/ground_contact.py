"""Ground contact: a penalty floor with normal stiffness and damping and smoothed Coulomb friction.

Each rod end cap is a sphere of the rod's radius ``r`` (MuJoCo's capsule ends). The
floor is the plane ``z = height``. Per end cap, with ``x`` its centre:

* **gate**: the cap touches the floor when ``z - r <= height``; penetration
  ``δ = height - (z - r) >= 0`` [m], contact point ``x - r ẑ`` (the sphere's bottom);
* **normal**: ``F_n = max(k δ - d v_n, 0)`` [N] along ``+ẑ``, ``v_n`` the contact
  point's vertical velocity (a spring-damper that only pushes);
* **friction**: ``F_t = -μ F_n v_t / sqrt(|v_t|² + ε²)`` [N], ``v_t`` the contact
  point's tangential (x, y) slip velocity and ``ε`` a small slip speed that smooths
  Coulomb's law (below ε the friction acts like viscous damping, which keeps the
  explicit integrator stable and the model differentiable).

Forces act at the contact point, so friction also exerts a torque about each rod's
centre of mass. :data:`MUJOCO_DEFAULT` holds values fitted to MuJoCo's default
soft contact (``solref = 0.02 1``, ``solimp = 0.9 0.95 0.001``, friction 1) for the
paper's icosahedron at a 1 ms step (``identification.diagnose``/``tests`` refit them).
"""

from __future__ import annotations

from typing import Any, ClassVar

import torch

from tensegrity_env.effects.base import ParamSpec, PhysicalEffect
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology

#: Parameters fitted to MuJoCo's default contact (icosahedron, dt = 1 ms, friction 1).
MUJOCO_DEFAULT: dict[str, float] = {
    "stiffness": 2.0e4,
    "damping": 300.0,
    "friction": 1.0,
    "slip_speed": 0.05,
    "height": 0.0,
}


class GroundContact(PhysicalEffect):
    """End caps against a floor at ``z = height`` (see the module docstring).

    Parameters: ``stiffness`` k [N/m], ``damping`` d [N*s/m], ``friction`` μ [-],
    ``slip_speed`` ε [m/s], ``height`` [m]; all scalars, shared by every end cap.
    """

    name: ClassVar[str] = "ground_contact"
    summary: ClassVar[str] = (
        "end caps meet a floor: penalty spring-damper + smoothed Coulomb friction"
    )
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "stiffness": ParamSpec("N/m", MUJOCO_DEFAULT["stiffness"]),
        "damping": ParamSpec("N*s/m", MUJOCO_DEFAULT["damping"]),
        "friction": ParamSpec("1", MUJOCO_DEFAULT["friction"]),
        "slip_speed": ParamSpec("m/s", MUJOCO_DEFAULT["slip_speed"]),
        "height": ParamSpec("m", MUJOCO_DEFAULT["height"]),
    }

    def __init__(self, topology: Topology, uncertainty: Any = None, **values: Any) -> None:
        super().__init__(topology, uncertainty, **values)
        #: each rod's end-cap radius, (R,) [m]
        self.radius = torch.tensor(
            [max(r.radius, 1e-3) for r in topology.rods], dtype=torch.float64
        )

    def check(self) -> None:
        v = {k: t.detach() for k, t in self.values.items()}
        for key in ("stiffness", "damping", "friction"):
            if (v[key] < 0).any():
                raise InputError(f"effect '{self.name}': '{key}' must be >= 0")
        if (v["slip_speed"] <= 0).any():
            raise InputError(f"effect '{self.name}': 'slip_speed' must be > 0")

    def contact_quantities(self, state: State, kin: Kinematics) -> dict[str, torch.Tensor]:
        """Per end cap, (B, R, 2): ``depth`` δ [m] (> 0 in contact), ``vn`` [m/s], ``slip`` [m/s].

        Also ``arm`` (B, R, 2, 3) [m], the contact point's offset from the rod's centre
        of mass, and ``vt`` (B, R, 2, 2) [m/s], the tangential slip velocity.
        """
        B, R = state.p.shape[:2]
        caps = kin.x[:, : 2 * R].reshape(B, R, 2, 3)
        radius = self.radius.to(caps)[None, :, None]  # (1, R, 1)
        depth = self.value("height", caps) - (caps[..., 2] - radius)
        down = torch.zeros(3, dtype=caps.dtype, device=caps.device)
        down[2] = -1.0
        arm = kin.arms + radius.unsqueeze(-1) * down  # contact point - COM
        vel = state.v.unsqueeze(2) + torch.cross(
            state.omega.unsqueeze(2).expand_as(arm), arm, dim=-1
        )
        vt = vel[..., :2]
        return {
            "depth": depth,
            "vn": vel[..., 2],
            "vt": vt,
            "slip": torch.linalg.vector_norm(vt, dim=-1),
            "arm": arm,
        }

    def contact_forces(self, state: State, kin: Kinematics) -> tuple[torch.Tensor, torch.Tensor]:
        """Contact force on every end cap (B, R, 2, 3) [N] and its arm (B, R, 2, 3) [m]."""
        c = self.contact_quantities(state, kin)
        like = c["depth"]
        k, d = self.value("stiffness", like), self.value("damping", like)
        mu, eps = self.value("friction", like), self.value("slip_speed", like)
        touching = c["depth"] > 0
        fn = torch.where(touching, torch.relu(k * c["depth"] - d * c["vn"]), torch.zeros_like(like))
        speed = torch.sqrt((c["vt"] ** 2).sum(-1) + eps**2)
        ft = -(mu * fn / speed).unsqueeze(-1) * c["vt"]
        return torch.cat([ft, fn.unsqueeze(-1)], dim=-1), c["arm"]

    def wrench(
        self, state: State, kin: Kinematics, params: Params
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        force, arm = self.contact_forces(state, kin)
        return force.sum(2), torch.cross(arm, force, dim=-1).sum(2)
