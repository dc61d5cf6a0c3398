"""The design matrix: each rod's six equations of motion, linear in the parameters.

For rod ``r`` and one transition, with ``σ = ±1`` the side of spring ``s`` the rod
holds (``+1`` at node a), ``e_s`` the spring axis, ``ρ`` the lever arm of the rod's
attachment point (an end cap or any point on the rod) and ``R`` the
rod rotation, the paper's decomposition gives six homogeneous linear equations::

    M_r (a - g)                         - Σ_s σ (K_s l_s - K_s l0_s + c_s l̇_s) e_s          - h f_u           = 0
    I_r ⊙ α_l + ω_l × (I_r ⊙ ω_l)      - Σ_s σ (K_s l_s - K_s l0_s + c_s l̇_s) Rᵀ(ρ × e_s)  - h Rᵀ(r_u × f_u) = 0

The unknowns are ``θ = [M, I, K, K·l0, c, h, h_c]`` (``K·l0`` is a separate linear unknown so
rest lengths are identified too; ``l0 = (K·l0)/K``; ``h_c`` is one gain per cable actuator,
whose command ``u`` adds ``-h_c u`` to its spring's tension, so its column is the
spring's unit-tension wrench times ``u``; present only with cable actuators; ``K·v`` is one unknown per winch, its spring's
stiffness times the winch's ``v_max``: a wound spring's rest length is
``l0 + v_max w(t)`` with ``w`` the winding per unit speed
(:func:`tensegrity_env.engine.winch.unit_winding`), so its column is the spring's
unit-tension wrench times ``w``; present only with winches). Each rod only touches its own
``M, I``, the springs attached to it and ``h``, so the design is built per rod on a
small set of *local* columns and accumulated into the normal matrix ``AᵀA`` in chunks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from identification.linear.features import TransitionFeatures
from tensegrity_env.topology import Topology

#: rows of each rod's block: 3 translational (world, [N]) + 3 rotational (rod frame, [N*m])
ROWS_PER_ROD = 6


@dataclass(frozen=True)
class ParameterLayout:
    """Names and positions of the unknowns θ.

    Attributes:
        topology: the assembly.
        shared: one K, c, l0 for all springs and one M, I for all rods.
        fit_rest_length: identify rest lengths (unknown ``K·l0``); otherwise they are known.
        names: human-readable name of each unknown, e.g. ``stiffness[spring3]``.
        groups: the Params field each unknown belongs to (``stiffness_rest`` for K·l0).
        elements: element index (spring/rod, or rod*3+axis for inertia) per unknown; -1 if shared.
    """

    topology: Topology
    shared: bool = False
    fit_rest_length: bool = True
    names: list[str] = field(default_factory=list)
    groups: list[str] = field(default_factory=list)
    elements: list[int] = field(default_factory=list)

    @classmethod
    def build(
        cls, topology: Topology, shared: bool = False, fit_rest_length: bool = True
    ) -> ParameterLayout:
        names, groups, elements = [], [], []

        def add(group: str, labels: list[str], elems: list[int]) -> None:
            for lab, el in zip(labels, elems, strict=True):
                names.append(f"{group}{lab}")
                groups.append(group)
                elements.append(el)

        rods = [r.name for r in topology.rods]
        springs = [s.name for s in topology.springs]
        if shared:
            for g in ("mass",):
                add(g, [""], [-1])
            add("inertia", ["[x]", "[y]", "[z]"], [0, 1, 2])
            spring_groups = ["stiffness", "stiffness_rest", "damping"]
            for g in spring_groups if fit_rest_length else ["stiffness", "damping"]:
                add(g, [""], [-1])
        else:
            add("mass", [f"[{n}]" for n in rods], list(range(len(rods))))
            add(
                "inertia",
                [f"[{n},{a}]" for n in rods for a in "xyz"],
                list(range(3 * len(rods))),
            )
            for g in (
                ["stiffness", "stiffness_rest", "damping"]
                if fit_rest_length
                else ["stiffness", "damping"]
            ):
                add(g, [f"[{n}]" for n in springs], list(range(len(springs))))
        add("control_gain", [""], [-1])
        driven = [topology.springs[c].name for c in topology.cable_actuators]
        add("cable_gain", [f"[{n}]" for n in driven], list(range(len(driven))))
        wound = [topology.springs[w].name for w in topology.winches]
        add("stiffness_winch_speed", [f"[{n}]" for n in wound], list(range(len(wound))))
        return cls(topology, shared, fit_rest_length, names, groups, elements)

    @property
    def n_params(self) -> int:
        return len(self.names)

    def index(self, group: str, element: int = -1) -> int:
        """Global index of the unknown of ``group`` for ``element`` (ignored if shared)."""
        for i, (g, e) in enumerate(zip(self.groups, self.elements, strict=True)):
            if g == group and (
                e == element or e == -1 or (group == "inertia" and self.shared and e == element % 3)
            ):
                return i
        raise KeyError(f"no unknown {group}[{element}]")

    def lookup(self, name: str) -> int:
        """Global index of an unknown by name, e.g. ``mass[rod0]``."""
        if name not in self.names:
            raise KeyError(name)
        return self.names.index(name)


@dataclass(frozen=True)
class RodSlots:
    """Springs attached to each rod, padded to the same count J.

    Attributes:
        spring: spring index per slot, (R, J); 0 where padded.
        node: the node (end cap or attachment point) where the rod holds the spring, (R, J).
        sign: +1 if the rod holds the spring's node a, -1 for node b, 0 where padded, (R, J).
        columns: global unknown index of each local column, (R, L); ``n_params`` = discard.
            Columns: M, I (3), then K, K·l0, c per slot, then h, then (with cable
            actuators) one ``h_c`` per slot.
        cable: the cable actuator driving each slot's spring, (R, J), -1 where none; None
            without cable actuators.
        winch: the winch winding each slot's spring, (R, J), -1 where none; None without
            winches. Its ``K·v`` columns follow the cable columns, one per slot.
    """

    spring: torch.Tensor
    node: torch.Tensor
    sign: torch.Tensor
    columns: torch.Tensor
    cable: torch.Tensor | None = None
    winch: torch.Tensor | None = None

    @property
    def n_local(self) -> int:
        return int(self.columns.shape[1])


def rod_slots(layout: ParameterLayout) -> RodSlots:
    """Local-column bookkeeping for :func:`rod_blocks`."""
    topo = layout.topology
    R = topo.n_rods
    attached = [topo.springs_of_rod(r) for r in range(R)]
    J = max(1, max(len(a) for a in attached))
    spring = np.zeros((R, J), dtype=np.int64)
    node = np.zeros((R, J), dtype=np.int64)
    sign = np.zeros((R, J))
    node_rod = topo.node_rod
    discard = layout.n_params
    driven = {s: c for c, s in enumerate(topo.cable_actuators)}
    wound = {s: w for w, s in enumerate(topo.winches)}
    first_winch = 4 + 3 * J + 1 + (J if driven else 0)
    L = first_winch + (J if wound else 0)
    columns = np.full((R, L), discard, dtype=np.int64)
    cable = -np.ones((R, J), dtype=np.int64)
    winch = -np.ones((R, J), dtype=np.int64)
    for r in range(R):
        columns[r, 0] = layout.index("mass", r)
        for k in range(3):
            columns[r, 1 + k] = layout.index("inertia", 3 * r + k)
        for j, s in enumerate(attached[r]):
            a, b = topo.springs[s].node_a, topo.springs[s].node_b
            mine = a if node_rod[a] == r else b
            spring[r, j], node[r, j], sign[r, j] = s, mine, 1.0 if mine == a else -1.0
            columns[r, 4 + 3 * j] = layout.index("stiffness", s)
            if layout.fit_rest_length:
                columns[r, 5 + 3 * j] = layout.index("stiffness_rest", s)
            columns[r, 6 + 3 * j] = layout.index("damping", s)
            if s in driven:
                cable[r, j] = driven[s]
                columns[r, 5 + 3 * J + j] = layout.index("cable_gain", driven[s])
            if s in wound:
                winch[r, j] = wound[s]
                columns[r, first_winch + j] = layout.index("stiffness_winch_speed", wound[s])
        columns[r, 4 + 3 * J] = layout.index("control_gain")
    return RodSlots(
        spring=torch.as_tensor(spring),
        node=torch.as_tensor(node),
        sign=torch.as_tensor(sign),
        columns=torch.as_tensor(columns),
        cable=torch.as_tensor(cable) if driven else None,
        winch=torch.as_tensor(winch) if wound else None,
    )


def _unit_wrenches(feat: TransitionFeatures, slots: RodSlots) -> torch.Tensor:
    """Per unit tension of each attached spring: force (world) and torque (rod frame) on
    the rod, (n, R, J, 6)."""
    sign = slots.sign.to(feat.accel.dtype)  # (R, J)
    fdir = sign.unsqueeze(-1) * feat.springs.axis[:, slots.spring]  # (n, R, J, 3)
    arm = feat.arms[:, slots.node]  # (n, R, J, 3)
    tdir = torch.einsum("nrji,nrkj->nrki", feat.rot, torch.cross(arm, fdir, dim=-1))
    return torch.cat([fdir, tdir], dim=-1)


def rod_blocks(
    feat: TransitionFeatures,
    slots: RodSlots,
    gravity: torch.Tensor,
    rest_length: torch.Tensor | None = None,
) -> torch.Tensor:
    """Local design blocks, (n, R, 6, L): rows = equations, columns = local unknowns.

    ``rest_length`` (S,) folds known rest lengths into the stiffness column (then the
    ``K·l0`` column is zero and discarded). The result is a view of a rod-major
    (R, n, 6, L) tensor, so :func:`accumulate_normal` reads it without a copy.
    """
    n, R = feat.accel.shape[:2]
    J = slots.spring.shape[1]
    dtype = feat.accel.dtype
    unit = _unit_wrenches(feat, slots).permute(1, 0, 3, 2).contiguous()  # (R, n, 6, J)
    # the scalar multiplying each unit vector for K, K*l0 and c: -l (or -(l - l0)), 1, -l̇
    length = feat.springs.length[:, slots.spring]  # (n, R, J)
    if rest_length is not None:
        length = length - rest_length.to(dtype)[slots.spring]
    ones = torch.zeros_like(length) if rest_length is not None else torch.ones_like(length)
    rate = feat.springs.rate[:, slots.spring]
    scal = torch.stack([-length, ones, -rate], dim=-1).transpose(0, 1)  # (R, n, J, 3)

    # fill a rod-major (R, n, 6, L) buffer in place: no concatenation copies
    A = torch.zeros(R, n, ROWS_PER_ROD, slots.n_local, dtype=dtype)
    torch.mul(unit.unsqueeze(-1), scal.unsqueeze(2), out=A[..., 4 : 4 + 3 * J].view(R, n, 6, J, 3))
    A[:, :, :3, 0] = (feat.accel - gravity).transpose(0, 1)
    w = feat.omega_local.transpose(0, 1)  # (R, n, 3)
    alpha = feat.alpha_local.transpose(0, 1)
    eye = torch.eye(3, dtype=dtype)
    for k in range(3):  # d/dI_k of I ⊙ α + ω × (I ⊙ ω), rotational rows only
        e_k = eye[k].expand_as(w)
        A[:, :, 3:, 1 + k] = alpha[..., k : k + 1] * e_k + torch.cross(
            w, e_k * w[..., k : k + 1], dim=-1
        )
    f_u = feat.control
    t_u = torch.einsum("nrji,nrj->nri", feat.rot, torch.cross(feat.control_arm, f_u, dim=-1))
    h = 4 + 3 * J
    A[:, :, :3, h] = -f_u.transpose(0, 1)
    A[:, :, 3:, h] = -t_u.transpose(0, 1)
    if slots.cable is not None:  # -σ (-h_c u) e: the unit-tension wrench times u
        assert feat.cables is not None  # features carry cable commands where slots do
        u = feat.cables[:, slots.cable.clamp_min(0)] * (slots.cable >= 0)  # (n, R, J)
        A[..., h + 1 : h + 1 + J] = unit * u.transpose(0, 1).unsqueeze(2)
    if slots.winch is not None:  # +σ (K v) w e, as the K·l0 column with w for 1
        first = h + 1 + (J if slots.cable is not None else 0)
        assert feat.winding is not None  # features carry the winding where slots do
        w = feat.winding[:, slots.winch.clamp_min(0)] * (slots.winch >= 0)  # (n, R, J)
        A[..., first : first + J] = unit * w.transpose(0, 1).unsqueeze(2)
    return A.permute(1, 0, 2, 3)


def accumulate_normal(A: torch.Tensor, slots: RodSlots, n_params: int, out: torch.Tensor) -> None:
    """Add ``AᵀA`` of local blocks (n, R, 6, L) into the global normal matrix ``out``.

    ``out`` is (n_params + 1, n_params + 1); the last row/column collects discarded columns.
    """
    n, R, rows, L = A.shape
    per_rod = A.permute(1, 0, 2, 3).reshape(R, n * rows, L)  # free for rod_blocks' output
    scatter_local_gram(torch.bmm(per_rod.transpose(1, 2), per_rod), slots, out)


def scatter_local_gram(G: torch.Tensor, slots: RodSlots, out: torch.Tensor) -> None:
    """Add per-rod local Gram matrices ``G`` (R, L, L) into the global normal matrix ``out``."""
    cols = slots.columns
    rows_idx = cols.unsqueeze(2).expand_as(G).reshape(-1)
    cols_idx = cols.unsqueeze(1).expand_as(G).reshape(-1)
    out.index_put_((rows_idx, cols_idx), G.reshape(-1), accumulate=True)


def with_hinges(slots: RodSlots, n_params: int, n_springs: int) -> RodSlots:
    """``slots`` with one more local column per attached spring: its hinge unknown ``ΔK``.

    The hinges are global unknowns ``n_params + s``; the discard column moves to
    ``n_params + n_springs`` (see :func:`hinge_blocks`).
    """
    cols = torch.where(slots.columns == n_params, n_params + n_springs, slots.columns)
    J = slots.spring.shape[1]
    padded = slots.sign == 0
    hinge = torch.where(padded, n_params + n_springs, n_params + slots.spring)
    return RodSlots(slots.spring, slots.node, slots.sign,
                    torch.cat([cols, hinge.reshape(-1, J)], dim=1), slots.cable,
                    slots.winch)  # fmt: skip


def hinge_blocks(feat: TransitionFeatures, slots: RodSlots, knots: torch.Tensor) -> torch.Tensor:
    """Local columns (n, R, 6, J) of a stiffness change ``ΔK_s`` below a knot ``τ_s`` [m].

    The spring's tension gains ``ΔK_s min(l_s - τ_s, 0)``: with ``τ_s = l0_s`` and
    ``ΔK_s = -K_s`` the spring is a cable, with no elastic push when shorter than rest.
    ``knots`` is (S,); append these to :func:`rod_blocks`' columns (:func:`with_hinges`).
    """
    dtype = feat.accel.dtype
    unit = _unit_wrenches(feat, slots)  # (n, R, J, 6)
    short = (feat.springs.length[:, slots.spring] - knots.to(dtype)[slots.spring]).clamp_max(0.0)
    return (unit * -short.unsqueeze(-1)).transpose(2, 3)  # same sign as K's column -l
