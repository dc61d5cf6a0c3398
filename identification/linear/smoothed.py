"""Linear regression on smoothed end caps: the first stage of end-cap identification.

Measured data holds end-cap positions only; finite differences of noisy positions
destroy accelerations. A Savitzky-Golay filter
(:func:`identification.data.end_caps.smooth_rod_states`) gives end-cap positions,
velocities and accelerations in continuous time; rod states and their rates follow
from the rod geometry, and the paper's linear equations of motion
(:func:`identification.linear.design.rod_blocks`) are solved exactly
(:func:`smoothed_regression`). Fast, but biased by the noise left after smoothing and
by the smoothing itself: :class:`identification.trajectory.identifier.TrajectoryIdentifier`
starts its multi-step fit from it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch

from identification.data.end_caps import RodAxes, SmoothedStates
from identification.linear.design import (
    ROWS_PER_ROD,
    ParameterLayout,
    accumulate_normal,
    hinge_blocks,
    rod_blocks,
    rod_slots,
    with_hinges,
)
from identification.linear.features import TransitionFeatures
from identification.linear.solve import solve_constrained
from tensegrity_env.engine.forces import spring_frames
from tensegrity_env.engine.kinematics import AttachmentPoints, Kinematics
from tensegrity_env.io_utils import InputError
from tensegrity_env.rotations import quat_to_matrix
from tensegrity_env.topology import Topology

DTYPE = torch.float64


def parse_anchors(topology: Topology, anchors: Mapping[str, float]) -> dict[tuple[str, int], float]:
    """``{"mass[rod0]": 1.95}`` -> ``{("mass", 0): 1.95}``.

    Names: ``mass[ROD]``, ``inertia_perp[ROD]`` (or ``inertia[ROD,x]`` for a perpendicular
    axis), ``stiffness[SPRING]``, ``damping[SPRING]``, ``rest_length[SPRING]``,
    ``control_gain``. Values must be positive. Raises :class:`InputError`.
    """
    rods = {r.name: i for i, r in enumerate(topology.rods)}
    springs = {s.name: i for i, s in enumerate(topology.springs)}
    out: dict[tuple[str, int], float] = {}
    for name, value in anchors.items():
        group, _, rest = name.partition("[")
        element = rest.rstrip("]").split(",")[0]
        key: tuple[str, int] | None = None
        if name == "control_gain":
            key = ("control_gain", 0)
        elif group in ("mass", "inertia_perp", "inertia") and element in rods:
            key = ("inertia_perp" if group == "inertia" else group, rods[element])
        elif group in ("stiffness", "damping", "rest_length") and element in springs:
            key = (group, springs[element])
        if key is None:
            raise InputError(
                f"unknown anchor '{name}'; use mass[{topology.rods[0].name}], "
                f"stiffness[{topology.springs[0].name}], inertia_perp[ROD], control_gain, ..."
            )
        if (
            group == "inertia"
            and rest.rstrip("]").split(",")[-1] == "xyz"[RodAxes.of(topology).axis[key[1]]]
        ):
            raise InputError(
                f"anchor '{name}': the axial inertia is not identifiable from end caps"
            )
        if not float(value) > 0:
            raise InputError(f"anchor '{name}' must be positive, got {value}")
        out[key] = float(value)
    return out


def smoothed_features(
    topology: Topology, s: SmoothedStates, control: np.ndarray, keep: np.ndarray | None = None,
    cables: np.ndarray | None = None, winding: np.ndarray | None = None,
) -> TransitionFeatures:  # fmt: skip
    """:class:`TransitionFeatures` at every sample ``t < T`` away from the ends (``s.margin``).

    Continuous-time accelerations from the smoothing replace the transition's finite
    differences; ``control`` is (N, T, R, 3), ``cables`` the cable actuators' commands
    (N, T, C) (None: without cable actuators), ``winding`` the winches' winding per unit
    speed at each sample (N, T, W) [m per m/s]
    (:func:`~tensegrity_env.engine.winch.unit_winding`; None: without winches); ``keep``
    (N, T) selects samples (None: all).
    Samples whose filter window holds a gap (``s.whole`` False) are never used: their
    accelerations would come from a polynomial fitted across the gap.
    """
    T = control.shape[1]
    t = slice(s.margin, max(s.margin + 1, min(T, s.p.shape[1] - s.margin)))
    defined = s.whole[:, :T]
    if not defined.all():
        keep = defined if keep is None else keep & defined

    def pick(arr: np.ndarray) -> torch.Tensor:
        part = arr[:, t]
        flat = part.reshape(-1, *arr.shape[2:]) if keep is None else part[keep[:, t]]
        return torch.as_tensor(flat, dtype=DTYPE)

    p, q, omega, alpha, accel = map(pick, (s.p, s.q, s.omega, s.alpha, s.a))
    x_end, xd_end, u = map(pick, (s.x, s.xd, control))
    n, R = p.shape[:2]
    rot = quat_to_matrix(q)
    anchors = torch.as_tensor(topology.anchor_positions, dtype=DTYPE).expand(n, -1, -1)
    x_all, xd_all = [x_end, anchors], [xd_end, torch.zeros_like(anchors)]
    points, point_arms = AttachmentPoints.of(topology), None
    if points is not None:  # on the rod axes (refused otherwise), placed by the smoothing
        v = pick(s.v)
        point_arms = torch.einsum("npij,pj->npi", rot[:, points.rod], points.offset)
        x_all.append(p[:, points.rod] + point_arms)
        xd_all.append(v[:, points.rod] + torch.cross(omega[:, points.rod], point_arms, dim=-1))
    kin = Kinematics(
        rot=rot,
        arms=x_end.reshape(n, R, 2, 3) - p.unsqueeze(2),
        x=torch.cat(x_all, dim=1),
        xd=torch.cat(xd_all, dim=1),
        points=points,
        point_arms=point_arms,
    )
    nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long)
    arm_u = torch.einsum("nrij,rj->nri", rot, torch.as_tensor(topology.control_arms, dtype=DTYPE))
    return TransitionFeatures(
        accel=accel,
        alpha_local=torch.einsum("nrji,nrj->nri", rot, alpha),
        omega_local=torch.einsum("nrji,nrj->nri", rot, omega),
        rot=rot,
        arms=kin.node_arms,
        springs=spring_frames(kin, nodes[:, 0], nodes[:, 1]),
        control=u,
        control_arm=arm_u,
        cables=None if cables is None else pick(cables),
        winding=None if winding is None else pick(winding),
    )


def pivot_rows(
    blocks: torch.Tensor, feat: TransitionFeatures, cap: torch.Tensor, radius: torch.Tensor
) -> torch.Tensor:
    """Each pivoting rod's equations about its contact point, free of the contact force.

    ``blocks`` (n, R, 6, L) are :func:`~identification.linear.design.rod_blocks`' rows
    (force, world; torque about the centre, rod frame) times the parameters, equal to the
    unknown contact force ``F`` at ``c`` and its torque ``ρ_c × F`` (``ρ_c`` the contact
    point from the rod's centre); ``R τ_rows - ρ_c × F_rows`` is 0 whatever ``F``. ``cap``
    (n, R): the cap (0, 1) a rod leans on, -1 where it does not (rows unchanged);
    ``radius`` (R,) [m]: the contact point lies that far below the cap's centre. Returns
    (n, R, 6, L): a pivoting rod's three moment rows (world, [N*m]) then three zero rows.
    """
    n, R = cap.shape
    leaning = cap >= 0
    node = 2 * torch.arange(R) + cap.clamp_min(0)  # (n, R)
    arm = torch.gather(feat.arms, 1, node.unsqueeze(-1).expand(n, R, 3)).clone()
    arm[..., 2] -= radius
    moment = torch.einsum("nrij,nrjl->nril", feat.rot, blocks[:, :, 3:])
    moment = moment - torch.cross(arm.unsqueeze(-1).expand_as(moment), blocks[:, :, :3], dim=2)
    pivoted = torch.cat([moment, torch.zeros_like(moment)], dim=2)
    return torch.where(leaning[:, :, None, None], pivoted, blocks)


def smoothed_regression(
    topology: Topology,
    smooth: SmoothedStates,
    control: np.ndarray,
    anchors: Mapping[str, float] | None = None,
    gravity: Sequence[float] = (0.0, 0.0, -9.81),
    keep: np.ndarray | None = None,
    knots: np.ndarray | None = None,
    rod_keep: np.ndarray | None = None,
    cables: np.ndarray | None = None,
    pivots: np.ndarray | None = None,
    radius: np.ndarray | None = None,
    winding: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Stage 1: linear regression on end caps smoothed by
    :func:`~identification.data.end_caps.smooth_rod_states`.

    ``keep`` (N, T): the samples used (None: all), e.g. those away from a floor.
    ``rod_keep`` (N, T, R): the rods' Newton-Euler equations used at each sample (None:
    every rod of a kept sample), e.g. only the rods away from a floor: a rod that does
    not touch it obeys the declared model while the others roll on it.
    ``pivots`` (N, T, R): the end cap (0 or 1) a rod leans on at each sample, -1 where
    none (only with ``rod_keep``, and never where it is set): that rod's three moment
    equations about the cap's contact point, ``radius`` (R,) [m] below the cap's centre,
    are used instead of its six (:func:`pivot_rows`): an unknown contact force there
    (normal and friction) drops out.
    ``knots`` (S,) [m]: also fit each spring's stiffness change ``ΔK`` below its knot
    (:func:`~identification.linear.design.hinge_blocks`), returned as ``compression_stiffness``
    with its standard error ``compression_stiffness_se`` (S,) [N/m].
    ``cables`` (N, T, C): the cable actuators' commands (a robot with cable actuators).
    ``winding`` (N, T, W) [m per m/s]: how far each winch has wound at each sample per
    unit ``v_max`` (:func:`~tensegrity_env.engine.winch.unit_winding` of the command log
    with the motors' lag; a robot with winches, whose rest lengths stay within range).
    Returns natural-unit values: ``stiffness``, ``damping``, ``rest_length`` (S,; a wound
    spring's at the start), ``mass``, ``inertia_perp`` (R,), ``control_gain`` (1,),
    ``cable_gain`` (C,), ``winch_speed`` (W,) [m/s] and the residual sum of squares
    ``rss`` (1,); NaN where the regression cannot tell. Samples near the ends, where the filter extrapolates, are not used.
    Anchors (see :func:`parse_anchors`) fix the scale; without one it is ``mass`` of the
    first rod = 1.
    """
    topo = topology
    axes = RodAxes.of(topo)
    layout = ParameterLayout.build(topo)
    slots = rod_slots(layout)
    if rod_keep is not None:
        used_rods = rod_keep if pivots is None else rod_keep | (pivots >= 0)
        any_rod = np.asarray(used_rods.any(-1))  # (n,): samples with a rod kept
        keep = any_rod if keep is None else keep & any_rod
    if topo.n_cables and cables is None:
        cables = np.zeros((*control.shape[:2], topo.n_cables))
    if topo.n_winches and winding is None:
        raise InputError(f"{topo.name}: the robot has winches; give their winding (the command log)")
    feat = smoothed_features(topo, smooth, control, keep, cables, winding)
    P = layout.n_params
    S = topo.n_springs if knots is not None else 0
    blocks = rod_blocks(feat, slots, torch.tensor(gravity, dtype=DTYPE))
    n_rows = feat.n * topo.n_rods * ROWS_PER_ROD
    if knots is not None:
        blocks = torch.cat([blocks, hinge_blocks(feat, slots, torch.as_tensor(knots))], dim=-1)
        slots = with_hinges(slots, P, S)
    if rod_keep is not None:  # the same samples smoothed_features picked, (n, R)
        assert keep is not None
        used = keep & smooth.whole[:, : control.shape[1]]
        t = slice(smooth.margin, max(smooth.margin + 1,
                                     min(control.shape[1], smooth.p.shape[1] - smooth.margin)))  # fmt: skip
        whole = torch.as_tensor(rod_keep[:, t][used[:, t]])
        n_rows = int(whole.sum()) * ROWS_PER_ROD
        if pivots is not None:
            assert radius is not None
            cap = torch.as_tensor(pivots[:, t][used[:, t]], dtype=torch.long).masked_fill(whole, -1)
            blocks = pivot_rows(blocks, feat, cap, torch.as_tensor(radius, dtype=DTYPE))
            whole = whole | (cap >= 0)
            n_rows += int((cap >= 0).sum()) * ROWS_PER_ROD // 2
        blocks = blocks * whole.to(DTYPE)[:, :, None, None]
    normal = torch.zeros(P + S + 1, P + S + 1, dtype=DTYPE)
    accumulate_normal(blocks, slots, P + S, normal)
    fixed = {}
    rods, springs = [r.name for r in topo.rods], [s.name for s in topo.springs]
    for (group, i), value in parse_anchors(topo, anchors or {}).items():
        names = {
            "mass": [f"mass[{rods[i]}]"],
            "stiffness": [f"stiffness[{springs[i]}]"],
            "damping": [f"damping[{springs[i]}]"],
            "control_gain": ["control_gain"],
            "inertia_perp": [
                f"inertia[{rods[i]},{'xyz'[k]}]" for k in range(3) if k != axes.axis[i]
            ],
        }.get(group, [])  # rest lengths do not set the scale
        for name in names:
            fixed[layout.lookup(name)] = float(value)
    if not any(v != 0 for v in fixed.values()):
        fixed = {layout.index("mass", 0): 1.0}
    sol = solve_constrained(normal[:-1, :-1], fixed, n_rows)
    th: dict[str, list[float]] = {
        g: []
        for g in ("mass", "inertia", "stiffness", "stiffness_rest", "damping", "control_gain",
                  "cable_gain", "stiffness_winch_speed")
    }
    for value, group in zip(sol.theta[:P], layout.groups, strict=True):
        th[group].append(value)
    hinge = {"compression_stiffness": sol.theta[P:], "compression_stiffness_se": sol.stderr[P:]}
    inertia = np.array(th["inertia"]).reshape(-1, 3)
    perp = np.isfinite(inertia) & (np.eye(3)[axes.axis] == 0)  # the two perpendicular axes
    count = perp.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return {
            "stiffness": np.array(th["stiffness"]),
            "damping": np.array(th["damping"]),
            "rest_length": np.array(th["stiffness_rest"]) / np.array(th["stiffness"]),
            "mass": np.array(th["mass"]),
            "inertia_perp": np.where(count > 0, np.where(perp, inertia, 0).sum(1) / count, np.nan),
            "control_gain": np.array(th["control_gain"]),
            "cable_gain": np.array(th["cable_gain"]),
            "winch_speed": np.array(th["stiffness_winch_speed"])
            / np.array(th["stiffness"])[list(topo.winches)],
            "rss": np.array([sol.rss]),
        } | (hinge if S else {})
