"""Ground contact: a soft floor with normal stiffness and damping and Coulomb friction.

Each rod end cap is a sphere of its contact radius ``r`` (``cap_radius``, one per end
cap: by default the robot file's, :attr:`~tensegrity_env.topology.Topology.cap_radii`,
the rod's radius at both ends for MuJoCo's capsule ends); the floor is the plane
``z = height``. The **gate**: an end cap touches the floor when its distance
``dist = z - r - height`` is below zero. The contact law is MuJoCo's
soft constraint (so the engine reproduces the MuJoCo twin), written in each rod's
own frame of contacts:

* every touching end cap has four friction-pyramid edges ``e = n ± μ t_k``
  (``n = ẑ``; ``t_1`` the horizontal direction from the rod centre to the cap for
  capsule end caps, the world ``y`` axis for sphere end caps, as MuJoCo's contact
  frames; ``t_2 = n × t_1``), acting at the contact point ``(x, y, height + dist / 2)``;
* each edge wants the **reference acceleration** ``a_ref = -B v_e - K d(dist) dist``
  (``v_e`` the contact point's velocity along the edge): a spring of stiffness ``K``
  [1/s²] and a damper ``B`` [1/s] per unit effective mass, i.e. a normal stiffness
  ``k_N ≈ m_eff d K`` [N/m] for a cap of effective mass ``m_eff`` [kg];
* the edge forces ``f >= 0`` [N] solve the small convex problem
  ``min ½ fᵀ (A + R) f + fᵀ (a0 - a_ref)`` per rod, with ``A`` the rod's inverse
  inertia seen by its edges, ``R = (1 - d)/d · 2μ²(1 + μ²)/M`` the softness and ``a0`` the
  edge accelerations without contact (gravity, springs, gyroscopic terms). The
  **impedance** ``d ∈ (0, 1)`` (how much of ``a_ref`` is enforced) rises from
  ``impedance_min`` at zero penetration to ``impedance`` at ``width``;
* so the net force on a cap is a normal force ``Σ f`` and a friction force of at
  most ``μ Σ f`` (Coulomb's cone, as a four-sided pyramid), both soft.

The law's parameters are shared by every end cap; the contact radius is each cap's own
(a real robot's caps differ in size, and its markers sit on their surfaces).
:data:`MUJOCO_DEFAULT` are MuJoCo's
defaults (``solref = 0.02 1``, ``solimp = 0.9 0.95 0.001 0.5 2``, friction 1);
``identification.trajectory.windowed_problem`` fits them to measured trajectories.

``a0`` is MuJoCo's ``J qacc`` without contact: with a rod's body frame off its centre
of mass (``Rod.frame_origin``), it includes the centripetal acceleration
``ω × (ω × r_o)`` of the body origin, whose velocity the free joint integrates.
It needs every other force on each rod. Contact is a constraint
(``constraint = True``): the engine evaluates it last and hands it the total wrench of
springs, control forces and every other effect, as MuJoCo's constraint solver sees all
passive and actuator forces. Called directly without that wrench, it uses the springs
(from the tensions seen in its ``tension`` hook) and gravity.

Where no gradient is wanted (double precision on the CPU, as the trajectory fits'
forward differences step it), the C kernel's ``tsr_contact_forces``
(``tensegrity_env/native/native_contact.c``, the same law the kernel's step uses) computes
the same geometry and law rod by rod (``benchmarks/bench_engine.py`` times both); the
two agree to round-off (``tests/unit/test_soft_contact_solve.py``). Otherwise, and
where no C compiler works, PyTorch does
(:data:`tensegrity_env.native.kernel.USE_NATIVE` switches the kernel off).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch

from tensegrity_env.effects.base import FitForm, Gate, NativeForm, ParamSpec, PhysicalEffect
from tensegrity_env.engine.forces import (
    SpringFrame,
    hooke_tension,
    kinematics_wrench,
    spring_frames,
    tension_to_node_forces,
)
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.io_utils import InputError
from tensegrity_env.native.kernel import CONTACT_LAW, usable_kernel
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology
from tensegrity_env.vec3 import dot, rotate, rotate_t, sum_small

#: MuJoCo's default contact: K = 1/(dmax² tc² ζ²), B = 2/(dmax tc) with tc = 0.02 s, ζ = 1.
MUJOCO_DEFAULT: dict[str, float] = {
    "stiffness": 1.0 / (0.95**2 * 0.02**2),
    "damping": 2.0 / (0.95 * 0.02),
    "impedance": 0.95,
    "impedance_min": 0.9,
    "width": 0.001,
    "friction": 1.0,
    "height": 0.0,
}

#: where a contact fit starts: a generic soft floor, not MuJoCo's values
CONTACT_START: dict[str, float] = {
    "stiffness": 1000.0,
    "damping": 50.0,
    "friction": 0.5,
    "impedance": 0.9,
}
#: the smallest default contact radius [m]: a rod file without one (radius 0) still gets
#: end caps that reach the floor before their centres do
MIN_CAP_RADIUS = 1e-3

#: contact parameters fitted through the engine
CONTACT_FREE = ("stiffness", "damping", "friction", "impedance")

#: the :meth:`GroundContact.contact_geometry` entries the contact law reads per touching rod
ROW_GEOMETRY = ("dist", "arm", "vel", "tangent")


#: Most active-set iterations of the per-rod contact problem (8 unknowns: usually a few;
#: near-parallel pyramid edges at small friction take more).
ACTIVE_SET_ITERATIONS = 30


def impedance_curve(
    depth: torch.Tensor, d_min: torch.Tensor, d_max: torch.Tensor, width: torch.Tensor
) -> torch.Tensor:
    """MuJoCo's impedance ``d(|dist|)`` with midpoint 0.5 and power 2, shape of ``depth``."""
    x = (depth.abs() / width).clamp(0.0, 1.0)
    y = torch.where(x < 0.5, 2.0 * x**2, 1.0 - 2.0 * (1.0 - x) ** 2)
    return d_min + y * (d_max - d_min)


class GroundContact(PhysicalEffect):
    """End caps against a soft floor at ``z = height`` (see the module docstring).

    Parameters: ``stiffness`` K [1/s²], ``damping`` B [1/s] (per unit effective
    mass), ``impedance`` d_max and ``impedance_min`` d_min [-], ``width`` [m] (the
    penetration over which d rises), ``friction`` μ [-], ``height`` [m], and
    ``cap_radius`` (R, 2) [m] each end cap's contact radius (default: the robot
    file's, at least :data:`MIN_CAP_RADIUS`).
    """

    name: ClassVar[str] = "ground_contact"
    constraint: ClassVar[bool] = True
    summary: ClassVar[str] = (
        "end caps meet a floor: soft normal spring-damper + Coulomb friction (MuJoCo-style)"
    )
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "stiffness": ParamSpec("1/s^2 (N/m per kg of effective mass)", MUJOCO_DEFAULT["stiffness"]),
        "damping": ParamSpec("1/s (N*s/m per kg of effective mass)", MUJOCO_DEFAULT["damping"]),
        "impedance": ParamSpec("1", MUJOCO_DEFAULT["impedance"], unit_interval=True),
        "impedance_min": ParamSpec("1", MUJOCO_DEFAULT["impedance_min"], unit_interval=True),
        "width": ParamSpec("m", MUJOCO_DEFAULT["width"]),
        "friction": ParamSpec("1", MUJOCO_DEFAULT["friction"]),
        "height": ParamSpec("m", MUJOCO_DEFAULT["height"], positive=False),
        "cap_radius": ParamSpec("m", MIN_CAP_RADIUS, per="rod", shape=(2,)),
    }
    gate: ClassVar[Gate] = Gate("end caps reach a floor that stops them", needs="floor")
    #: fitted through the engine in two stages: the impedance is held at its start until
    #: stiffness, damping and friction are near, then all are freed (freed at once from a
    #: far start, the impedance runs to its bound of 1, where its logit has no gradient)
    fit_form: ClassVar[FitForm] = FitForm(
        route="engine",
        free=CONTACT_FREE,
        stages=(tuple(k for k in CONTACT_FREE if k != "impedance"), CONTACT_FREE),
        start=CONTACT_START,
    )
    native: ClassVar[NativeForm | None] = NativeForm("contact")

    def __init__(
        self, topology: Topology, uncertainty: Any = None, *, validate: bool = True, **values: Any
    ) -> None:
        if "cap_radius" not in values:
            values["cap_radius"] = np.maximum(topology.cap_radii, MIN_CAP_RADIUS)
        super().__init__(topology, uncertainty, validate=validate, **values)
        nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long)
        self._node_a, self._node_b = nodes[:, 0], nodes[:, 1]
        inc = torch.zeros(topology.n_nodes, topology.n_springs, dtype=torch.float64)
        idx = torch.arange(topology.n_springs)
        inc[self._node_a, idx] = 1.0
        inc[self._node_b, idx] = -1.0
        self._incidence = inc
        #: rods with sphere end caps (their contact frame is fixed in the world), (R,)
        self._sphere = torch.tensor([r.end_cap == "sphere" for r in topology.rods])
        origins = topology.frame_origins
        #: body-frame origins in each rod's principal frame (R, 3) [m], None at the COM
        self._origins = torch.as_tensor(origins) if origins.any() else None
        self._seen: tuple[Kinematics, SpringFrame, torch.Tensor] | None = None

    @property
    def radius(self) -> torch.Tensor:
        """Each end cap's contact radius, (R, 2) [m]."""
        return self.values["cap_radius"]

    def default_radius(self) -> bool:
        """Whether every end cap has the robot file's contact radius (the default)."""
        default = np.maximum(self.topology.cap_radii, MIN_CAP_RADIUS)
        return bool(np.array_equal(self.radius.detach().cpu().numpy(), default))

    def to_dict(self) -> dict[str, Any]:
        """As :meth:`PhysicalEffect.to_dict`; the contact radii only where they are not the
        robot file's (a document of the default contact is unchanged by them)."""
        out = super().to_dict()
        if self.default_radius() and "cap_radius" not in self.uncertainty:
            out["params"].pop("cap_radius")
            out["units"].pop("cap_radius")
        return out

    def check(self) -> None:
        v = {k: float(t.detach().min()) for k, t in self.values.items()}
        for key in ("stiffness", "damping", "friction", "width", "cap_radius"):
            if v[key] < 0:
                raise InputError(f"effect '{self.name}': '{key}' must be >= 0")
        for key in ("impedance", "impedance_min"):
            hi = float(self.values[key].detach().max())
            if not (0 < v[key] and hi < 1):
                raise InputError(f"effect '{self.name}': '{key}' must be in (0, 1)")

    # ------------------------------------------------------------------ hooks
    def tension(self, frame: SpringFrame, tension: torch.Tensor, kin: Kinematics) -> torch.Tensor:
        self._seen = (kin, frame, tension)  # the springs' pull, for the free acceleration a0
        return tension

    def wrench(
        self,
        state: State,
        kin: Kinematics,
        params: Params,
        applied: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Contact force and torque on each rod, (B, R, 3) each, world frame.

        ``applied``: the force and torque (B, R, 3) of everything else on each rod
        (springs, control, other effects), which the engine passes since contact is a
        constraint; None: the springs' pull alone (gravity is always included).
        """
        force, arm = self.contact_forces(state, kin, params, applied)
        return sum_small(force, 2), sum_small(torch.cross(arm, force, dim=-1), 2)

    # ------------------------------------------------------------------ physics
    def _spring_wrench(self, kin: Kinematics, params: Params) -> tuple[torch.Tensor, torch.Tensor]:
        if self._seen is not None and self._seen[0] is kin:
            _, frame, tension = self._seen
        else:
            a, b = self._node_a.to(kin.x.device), self._node_b.to(kin.x.device)
            frame = spring_frames(kin, a, b)
            tension = hooke_tension(frame, params.stiffness, params.damping, params.rest_length)
        nodes = tension_to_node_forces(tension, frame, self._incidence.to(tension))
        return kinematics_wrench(nodes, kin)

    def clearance(self, state: State, kin: Kinematics) -> torch.Tensor:
        """Each end cap's distance above the floor, (B, R, 2) [m] (< 0 in contact)."""
        return self.contact_geometry(state, kin)["dist"]

    def floor_height(self) -> float:
        return float(self.values["height"].reshape(-1)[0])

    def contact_geometry(self, state: State, kin: Kinematics) -> dict[str, torch.Tensor]:
        """Per end cap (B, R, 2): ``dist`` [m] (< 0 in contact), ``slip`` [m/s], ``vn`` [m/s].

        Also ``arm`` (B, R, 2, 3) [m], the contact point's offset from the rod's centre
        of mass, ``tangent`` (B, R, 2, 3) the friction direction ``t_1`` and ``vel``
        (B, R, 2, 3) [m/s] the contact point's velocity.
        """
        B, R = state.p.shape[:2]
        caps = kin.x[:, : 2 * R].reshape(B, R, 2, 3)
        radius = self.value("cap_radius", caps)[None]
        dist = caps[..., 2] - radius - self.value("height", caps)
        point = torch.cat([caps[..., :2], (self.value("height", caps) + dist / 2)[..., None]], -1)
        arm = point - state.p.unsqueeze(2)
        vel = state.v.unsqueeze(2) + torch.cross(state.omega.unsqueeze(2).expand_as(arm), arm, -1)
        horiz = torch.cat([kin.arms[..., :2], torch.zeros_like(kin.arms[..., :1])], -1)
        norm = torch.linalg.vector_norm(horiz, dim=-1, keepdim=True)
        x_axis = torch.zeros_like(horiz)
        x_axis[..., 0] = 1.0
        tangent = torch.where(norm > 1e-12, horiz / norm.clamp_min(1e-12), x_axis)
        if self._sphere.any():  # MuJoCo's sphere-plane contact frame: t_1 = y, fixed
            y_axis = torch.zeros_like(horiz)
            y_axis[..., 1] = 1.0
            tangent = torch.where(
                self._sphere.to(tangent.device)[None, :, None, None], y_axis, tangent
            )
        return {
            "dist": dist,
            "arm": arm,
            "vel": vel,
            "vn": vel[..., 2],
            "slip": torch.linalg.vector_norm(vel[..., :2], dim=-1),
            "tangent": tangent,
        }

    def contact_forces(
        self,
        state: State,
        kin: Kinematics,
        params: Params,
        applied: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Contact force on every end cap (B, R, 2, 3) [N] and its arm (B, R, 2, 3) [m].

        ``applied``: see :meth:`wrench`. Only the rods with a cap in contact are solved
        (gathered into one batch of rows); the others get no force. Where no gradient is
        wanted, the C kernel computes the same (:meth:`_native_forces`).
        """
        native = self._native_forces(state, kin, params, applied)
        if native is not None:
            return native
        g = self.contact_geometry(state, kin)
        dist = g["dist"]
        B, R = dist.shape[:2]
        active = dist < 0  # the gate, (B, R, 2)
        touching = active.any(-1).reshape(-1)
        if not bool(touching.any()):
            return torch.zeros_like(g["arm"]), g["arm"]
        rows = torch.nonzero(touching).squeeze(-1)  # touching (assembly, rod) pairs, (N,)

        def take(x: torch.Tensor, trailing: int) -> torch.Tensor:
            """The touching rows of a per-rod tensor ((B or 1, R) or (R,), then ``trailing``
            dims); one shared by the batch is indexed by rod."""
            if x.dim() == 2 + trailing and x.shape[0] == B:
                return x.reshape(B * R, *x.shape[2:]).index_select(0, rows)
            return x.reshape(R, *x.shape[x.dim() - trailing :]).index_select(0, rows % R)

        # mass (1 or B, R) and inertia (1 or B, R, 3): params may carry a batch dimension
        m_b = params.mass if params.mass.dim() == 2 else params.mass[None]
        i_b = params.inertia if params.inertia.dim() == 3 else params.inertia[None]
        f_s, t_s = self._spring_wrench(kin, params) if applied is None else applied
        origins = None if self._origins is None else take(self._origins.to(dist), 1)
        force = self._row_forces(
            {k: take(g[k], 2 if g[k].dim() == 4 else 1) for k in ROW_GEOMETRY},
            take(kin.rot, 2), take(state.omega, 1), take(m_b, 0), take(i_b, 1),
            take(f_s, 1), take(t_s, 1), params.gravity, take(active, 1), origins,
        )  # fmt: skip
        out = torch.zeros(B * R, 2, 3, dtype=force.dtype, device=force.device)
        return out.index_copy(0, rows, force).reshape(B, R, 2, 3), g["arm"]

    def _native_forces(
        self,
        state: State,
        kin: Kinematics,
        params: Params,
        applied: tuple[torch.Tensor, torch.Tensor] | None,
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        """:meth:`contact_forces` by the C kernel (``tsr_contact_forces``: the geometry
        and the law, rod by rod), where
        :func:`~tensegrity_env.native.kernel.usable_kernel` takes the inputs and the
        contact law's parameters are shared by every end cap; else None."""
        B, R = state.p.shape[:2]
        law = [self.value(k, state.p) for k in CONTACT_LAW]
        mass, inertia = params.mass, params.inertia
        per_assembly = mass.dim() == 2 and mass.shape[0] == B and B > 1
        if not per_assembly and (mass.numel() != R or inertia.numel() != 3 * R):
            return None
        if per_assembly and inertia.shape != (B, R, 3):
            return None
        rows = [state.p, state.v, state.omega, kin.rot, kin.arms]
        others = [*rows, mass, inertia, params.gravity, *law, self.radius]
        if not all(v.numel() == 1 for v in law) or usable_kernel(*others) is None:
            return None  # (before the spring wrench: the PyTorch law computes its own)
        f_s, t_s = self._spring_wrench(kin, params) if applied is None else applied
        kernel = usable_kernel(f_s, t_s)
        if kernel is None:
            return None
        rows = [x.detach().contiguous() for x in rows]
        wrench = [x.detach().expand(B, R, 3).contiguous() for x in (f_s, t_s)]
        mass, inertia = mass.detach().contiguous(), inertia.detach().contiguous()
        radius = self.radius.detach().to(state.p).contiguous()
        sphere = self._sphere.to(torch.uint8).contiguous()
        origins = None if self._origins is None else self._origins.to(state.p).contiguous()
        gravity = params.gravity.detach().reshape(3).contiguous()
        law_c = torch.cat([v.detach().reshape(1) for v in law])
        force = torch.empty(B, R, 2, 3, dtype=torch.float64)
        arm = torch.empty(B, R, 2, 3, dtype=torch.float64)
        kernel.tsr_contact_forces(
            B, R, *(x.data_ptr() for x in rows), mass.data_ptr(), inertia.data_ptr(),
            int(per_assembly), *(x.data_ptr() for x in wrench), radius.data_ptr(),
            sphere.data_ptr(), None if origins is None else origins.data_ptr(),
            gravity.data_ptr(), law_c.data_ptr(), ACTIVE_SET_ITERATIONS, force.data_ptr(),
            arm.data_ptr(),
        )  # fmt: skip
        return force, arm

    def _row_forces(
        self,
        g: dict[str, torch.Tensor],
        rot: torch.Tensor,
        omega: torch.Tensor,
        mass: torch.Tensor,
        inertia: torch.Tensor,
        f_s: torch.Tensor,
        t_s: torch.Tensor,
        gravity: torch.Tensor,
        active: torch.Tensor,
        origins: torch.Tensor | None,
    ) -> torch.Tensor:
        """Contact forces on the end caps (N, 2, 3) [N] of N rods, each row one rod.

        ``g``: :meth:`contact_geometry`'s entries for these rows ((N, 2) and (N, 2, 3));
        ``rot`` (N, 3, 3); ``omega``, ``f_s``, ``t_s`` (N, 3) the angular velocity and the
        applied force and torque; ``mass`` (N,) [kg]; ``inertia`` (N, 3) [kg m^2];
        ``active`` (N, 2) the gate; ``origins`` (N, 3) the body-frame origins or None.
        """
        dist = g["dist"]
        N = dist.shape[0]
        like = dist
        K, Bd = self.value("stiffness", like), self.value("damping", like)
        mu = self.value("friction", like)
        imp = impedance_curve(
            dist,
            self.value("impedance_min", like),
            self.value("impedance", like),
            self.value("width", like),
        )
        # the four pyramid edges of each cap: n ± μ t1, n ± μ t2, (N, 2, 4, 3)
        n = torch.zeros_like(g["tangent"])
        n[..., 2] = 1.0
        t1 = g["tangent"]
        t2 = torch.cross(n, t1, dim=-1)
        signs = torch.tensor([1.0, -1.0], dtype=like.dtype, device=like.device)
        tk = torch.stack([t1, t1, t2, t2], dim=-2) * torch.cat([signs, signs])[:, None]
        edges = n.unsqueeze(-2) + mu * tk
        arm = g["arm"].unsqueeze(-2).expand_as(edges)
        # J M^-1 J^T from the rod's mass and inertia: (N, 8, 8)
        lin = edges.reshape(N, 8, 3)
        ang_w = torch.cross(arm, edges, dim=-1).reshape(N, 8, 3)
        root_i = inertia.sqrt()
        ang_l = (ang_w @ rot) / root_i[:, None]  # each edge's Rᵀ (arm × e), row by row
        m = mass[:, None, None]
        jac = torch.cat([lin / m.sqrt(), ang_l], -1)  # (N, 8, 6), scaled by M^-1/2
        A = jac @ jac.transpose(-1, -2)
        # free accelerations a0 of the edges: gravity, applied forces, gyroscopic terms
        acc = f_s / mass[:, None] + gravity
        if origins is not None:
            # MuJoCo's constraint acceleration is J qacc: it carries the centripetal
            # acceleration of the body origin a free joint integrates
            r_o = rotate(rot, origins)
            acc = acc + torch.cross(omega, torch.cross(omega, r_o, dim=-1), dim=-1)
        omega_l = rotate_t(rot, omega)
        torque_l = rotate_t(rot, t_s)
        gyro = torch.cross(omega_l, inertia * omega_l, dim=-1)
        alpha_l = (torque_l - gyro) / inertia
        a0 = torch.einsum("nei,ni->ne", lin, acc) + torch.einsum(
            "nei,ni->ne", ang_l, alpha_l * root_i
        )
        # reference accelerations and softness per edge, (N, 8)
        v_e = dot(edges, g["vel"].unsqueeze(-2)).reshape(N, 8)
        d8 = imp.unsqueeze(-1).expand(N, 2, 4).reshape(N, 8)
        dist8 = dist.unsqueeze(-1).expand(N, 2, 4).reshape(N, 8)
        aref = -Bd * v_e - K * d8 * dist8
        soft = (1.0 - d8) / d8 * 2.0 * mu**2 * (1.0 + mu**2) / m[..., 0]
        mask = active.unsqueeze(-1).expand(N, 2, 4).reshape(N, 8)
        A.diagonal(dim1=-2, dim2=-1).add_(soft)  # A is this function's own tensor
        f = solve_soft_contacts(A, a0 - aref, mask)
        return sum_small(f.reshape(N, 2, 4).unsqueeze(-1) * edges, -2)


def solve_soft_contacts(H: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``argmin_{f >= 0, f = 0 off mask} ½ fᵀ H f + fᵀ b`` for a batch of small problems.

    ``H`` (..., n, n) symmetric positive definite, ``b`` and ``mask`` (..., n). A
    primal-dual active-set iteration (exact once the active set settles, a few
    iterations for n = 8); if it has not settled, one projected Gauss-Seidel sweep.
    Each iteration solves only the problems whose active set is still changing (a
    settled one would give the same forces again); a problem with nothing on ``mask``
    gets no force. The C kernel's ``solve_contacts`` is the same iteration, one problem
    at a time.
    """
    n = H.shape[-1]
    batch = b.shape[:-1]
    H, b, mask = H.reshape(-1, n, n), b.reshape(-1, n), mask.reshape(-1, n)
    S = mask & (b < 0)
    f = torch.zeros_like(b)
    todo = torch.nonzero(mask.any(-1)).squeeze(-1)  # problems still unsettled
    for _ in range(ACTIVE_SET_ITERATIONS):
        if todo.numel() == 0:
            break
        H_t, b_t, S_t = H[todo], b[todo], S[todo]
        # H on the active rows and columns, the identity elsewhere
        on = S_t.to(H.dtype)
        H_S = H_t * (on.unsqueeze(-1) * on.unsqueeze(-2))
        H_S.diagonal(dim1=-2, dim2=-1).add_(1.0 - on)
        f_t, info = torch.linalg.solve_ex(H_S, torch.where(S_t, -b_t, torch.zeros_like(b_t)))
        # singular only for a state that has blown up (caps 1e9 m away): no force there
        f_t = torch.where((info > 0).unsqueeze(-1), torch.zeros_like(f_t), f_t)
        f = f.index_copy(0, todo, f_t)
        w = (H_t @ f_t.unsqueeze(-1)).squeeze(-1) + b_t
        S_new = mask[todo] & ((S_t & (f_t > 0)) | (~S_t & (w < 0)))
        changed = (S_new != S_t).any(-1)
        S = S.index_copy(0, todo, S_new)
        todo = todo[changed]
    f = torch.where(mask, f.clamp_min(0.0), torch.zeros_like(f))
    if todo.numel() == 0:  # exact: f >= 0 on S, w >= 0 off S
        return f.reshape(*batch, n)
    for i in range(n):
        w_i = (H[..., i, :] * f).sum(-1) + b[..., i]
        new = (f[..., i] - w_i / H[..., i, i]).clamp_min(0.0)
        f = torch.where((torch.arange(n, device=f.device) == i) & mask, new.unsqueeze(-1), f)
    return f.reshape(*batch, n)
