"""Read an MJCF model into rods, springs and ground-truth parameters (the convention of
:mod:`tensegrity_env.mjcf`); refuse what the spring-rod model cannot honour."""

from __future__ import annotations

import re
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from tensegrity_env.effects import ControlLag, GroundContact, ImplicitLinearDrag, SlackSprings
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf.end_caps import (
    CAP_TYPES,
    end_cap_radius,
    end_cap_sites,
    floor_geoms,
    mj_name,
    named_sites,
)
from tensegrity_env.mjcf.winches import MjWinches, winches_of
from tensegrity_env.mjcf.writer import SimOptions
from tensegrity_env.mjcf_checks import (
    Unsupported,
    cable_actuator_problem,
    check_ignore_names,
    contact_of,
    joint_damping_of,
    refuse_or_warn,
    unsupported_features,
)
from tensegrity_env.params import Params
from tensegrity_env.rotations import np_quat_mul, np_quat_to_matrix
from tensegrity_env.topology import Rod, Spring, Topology, TopologyError


@dataclass(frozen=True)
class MjcfAssembly:
    """What :func:`from_mjcf` reads back: the graph, the parameters and the MuJoCo maps.

    Attributes:
        topology: rods, anchors, springs.
        params: ground-truth parameters (``control_gain`` from the actuators, 1 if none).
        options: simulation options found in the model.
        model: the compiled MuJoCo model.
        rod_bodies: MuJoCo body id of each rod, (R,).
        rod_qpos: qpos address of each rod's free joint, (R,).
        rod_qvel: qvel address of each rod's free joint, (R,).
        body_ipos: inertial-frame offset in the body frame, (R, 3) [m].
        body_iquat: inertial-frame orientation in the body frame, (R, 4).
        actuators: actuator id of each rod's (x, y, z) control force, (R, 3), -1 if absent.
        contact: the floor contact the end caps feel, as parameters of
            :class:`~tensegrity_env.effects.ground_contact.GroundContact` (without
            ``height``); empty without a floor.
        slack_springs: springs with a dead band ``springlength="0 L"`` (tension-only
            cables of rest length L).
        cable_actuators: actuator id of each cable actuator, (C,), in the order of
            ``topology.cable_actuators``.
        cable_lag: the time constant of the cable actuators' first-order filter [s]
            (``dyntype="filter"``), 0 without a filter.
        joint_damping: the rods' free-joint damping [N*s/m and N*m*s], declared as
            implicit linear drag (:func:`~tensegrity_env.mjcf_checks.joint_damping_of`);
            0 without.
    """

    topology: Topology
    params: Params
    options: SimOptions
    model: mujoco.MjModel
    rod_bodies: np.ndarray
    rod_qpos: np.ndarray
    rod_qvel: np.ndarray
    body_ipos: np.ndarray
    body_iquat: np.ndarray
    actuators: np.ndarray
    contact: dict[str, float] = field(default_factory=dict)
    slack_springs: tuple[int, ...] = ()
    cable_actuators: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    cable_lag: float = 0.0
    joint_damping: float = 0.0

    def declared_effects(self, ground: bool | None = None) -> list[PhysicalEffect]:
        """What the file declares beyond linear springs, as effects: floor contact with
        the file's friction, solref and solimp (``ground``: whether there is a floor,
        default: the file's); tension-only springs; the cable actuators' filter as
        ``control_lag``; free-joint damping as implicit ``linear_drag``."""
        effects: list[PhysicalEffect] = []
        if self.options.ground if ground is None else ground:
            # parameter name -> value (a dict of floats, not the constructor's other keywords)
            contact: dict[str, Any] = self.contact or {"friction": self.options.friction}
            effects.append(GroundContact(self.topology, height=0.0, **contact))
        if self.slack_springs:
            effects.append(SlackSprings(self.topology, springs=list(self.slack_springs)))
        if self.cable_lag:
            effects.append(ControlLag(self.topology, time_constant=self.cable_lag))
        if self.joint_damping:
            d = [self.joint_damping] * 3
            effects.append(ImplicitLinearDrag(self.topology, translational=d, rotational=d))
        return effects

    def mj_winches(self) -> MjWinches:
        """The MuJoCo plant of the file's winches (sets ``tendon_lengthspring`` of
        :attr:`model` each step; see :mod:`tensegrity_env.mjcf.winches`)."""
        return MjWinches(self.model, self.topology, self.params, self.slack_springs)


def mujoco_error(e: ValueError) -> str:
    """MuJoCo's error on loading a model, on one line, led by the line of the file it
    names (``Line number=13``, ``Element 'inertial', line 17``)."""
    parts = [line.strip() for line in str(e).splitlines() if line.strip()]
    found = re.search(r"\bline(?: number)?\s*=?\s*(\d+)", str(e), re.IGNORECASE)
    where = f"line {found.group(1)}: " if found else ""
    return f"{where}MuJoCo cannot load it ({'; '.join(parts) or type(e).__name__})"


def from_mjcf(
    source: str | Path,
    xml: str | None = None,
    ignore: Collection[str] = (),
    end_caps: Collection[str] = (),
) -> MjcfAssembly:
    """Read an MJCF file (or ``xml`` text, with ``source`` used in messages).

    ``end_caps`` names the end-cap sites (two per rod) where the convention (the two
    sites at a rod's ends along its axis) does not find them.

    Every feature that changes the dynamics and is not modelled is refused
    (:mod:`tensegrity_env.mjcf_checks`), unless named in ``ignore``: then it is
    accepted with an :class:`~tensegrity_env.mjcf_checks.IgnoredFeatureWarning`.

    Raises :class:`InputError` with one line naming the file and the problem.
    """
    check_ignore_names(ignore)
    src = str(source)
    try:
        if xml is not None:
            model = mujoco.MjModel.from_xml_string(xml)
        else:
            if not Path(src).is_file():
                raise InputError(f"{src}: no such MJCF file")
            model = mujoco.MjModel.from_xml_path(src)
    except ValueError as e:
        raise InputError(f"{src}: {mujoco_error(e)}") from None
    m = model
    BODY, SITE, TEN = mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_SITE, mujoco.mjtObj.mjOBJ_TENDON

    # rods: bodies with exactly one free joint
    rod_bodies = [
        b
        for b in range(1, m.nbody)
        if m.body_jntnum[b] == 1 and m.jnt_type[m.body_jntadr[b]] == mujoco.mjtJoint.mjJNT_FREE
    ]
    if not rod_bodies:
        raise InputError(f"{src}: no rods (bodies with a free joint) found")
    for b in range(1, m.nbody):
        if b not in rod_bodies and m.body_jntnum[b] > 0:
            raise InputError(
                f"{src}: body '{mj_name(m, BODY, b)}' has joints but is not a free rod"
            )
    rod_index = {b: i for i, b in enumerate(rod_bodies)}

    # control actuators: site transmission on a rod site, refsite on the world body
    arm_sites: dict[int, int] = {}
    actuators = -np.ones((len(rod_bodies), 3), dtype=int)
    gains: list[float] = []
    cables = cable_actuators_of(m, src)
    winches = winches_of(m, src)
    for a in range(m.nu):
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_SITE:
            continue
        site, ref = m.actuator_trnid[a]
        body = m.site_bodyid[site]
        gear = m.actuator_gear[a]
        axis = int(np.argmax(np.abs(gear[:3])))
        if body not in rod_index or ref < 0 or m.site_bodyid[ref] != 0:
            raise InputError(
                f"{src}: actuator '{mj_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a)}' is not a world-frame"
                " force on a rod site (needs site= on a rod and refsite= on the world body)"
            )
        arm_sites[rod_index[body]] = site
        actuators[rod_index[body], axis] = a
        gains.append(float(m.actuator_gainprm[a, 0] * gear[axis]))
    if gains and not np.allclose(gains, gains[0]):
        raise InputError(f"{src}: control actuators have different gains {sorted(set(gains))}")

    # the sites springs attach to
    tendon_sites: list[tuple[int, int]] = []
    for t in range(m.ntendon):
        adr, num = m.tendon_adr[t], m.tendon_num[t]
        types = m.wrap_type[adr : adr + num]
        if num != 2 or not np.all(types == mujoco.mjtWrap.mjWRAP_SITE):
            raise InputError(
                f"{src}: tendon '{mj_name(m, TEN, t)}' is not a two-site spatial tendon (a spring)"
            )
        tendon_sites.append((int(m.wrap_objid[adr]), int(m.wrap_objid[adr + 1])))

    # geometry in each rod's inertial (principal) frame
    ipos = np.array([m.body_ipos[b] for b in rod_bodies])
    iquat = np.array([m.body_iquat[b] for b in rod_bodies])
    Ri = np_quat_to_matrix(iquat)  # inertial frame -> body frame

    def to_inertial(i: int, pos_body: np.ndarray) -> tuple[float, float, float]:
        return tuple((Ri[i].T @ (pos_body - ipos[i])).tolist())

    # end caps of each rod (named, or by convention); its other spring sites are
    # attachment points, in order of first use
    named = named_sites(m, end_caps, src)
    rod_ends: list[list[int]] = []
    rod_points: list[list[int]] = [[] for _ in rod_bodies]
    for i, b in enumerate(rod_bodies):
        sites = [s for s in range(m.nsite) if m.site_bodyid[s] == b]
        local = {s: np.asarray(to_inertial(i, m.site_pos[s])) for s in sites}
        axis = int(np.argmin(m.body_inertia[b]))
        rod_ends.append(end_cap_sites(m, b, sites, arm_sites.get(i), local, axis, named, src))
    for pair in tendon_sites:
        for s in pair:
            b = int(m.site_bodyid[s])
            if b in rod_index:
                i = rod_index[b]
                if s not in rod_ends[i] and s not in rod_points[i]:
                    rod_points[i].append(s)

    floor = floor_geoms(m)
    rods = []
    cap_geoms: list[int] = []
    shape_found: list[Unsupported] = []
    for i, b in enumerate(rod_bodies):
        e0, e1 = (np.asarray(to_inertial(i, m.site_pos[s])) for s in rod_ends[i])
        if not np.linalg.norm(e1 - e0) > 0:  # before the end caps' geoms are looked for
            raise InputError(f"{src}: rod '{mj_name(m, BODY, b)}': length must be positive, got "
                             f"0.0 (end-cap sites '{mj_name(m, SITE, rod_ends[i][0])}' and "
                             f"'{mj_name(m, SITE, rod_ends[i][1])}' coincide)")  # fmt: skip
        radii, geoms = end_cap_radius(m, b, rod_ends[i], floor, src)
        radius = max(radii)
        own = abs(radii[0] - radii[1]) > 1e-12 * (1.0 + radius)  # caps of their own sizes
        cap_geoms += geoms
        shapes = {CAP_TYPES[int(m.geom_type[g])] for g in geoms}
        if floor and "cylinder" in shapes:
            shape_found.append(
                Unsupported("end-cap-shape", f"rod '{mj_name(m, BODY, b)}' has cylinder end caps")
            )
        if len(shapes) > 1 and floor:
            raise InputError(
                f"{src}: rod '{mj_name(m, BODY, b)}': end caps of different shapes {sorted(shapes)}"
            )
        arm = to_inertial(i, m.site_pos[arm_sites[i]]) if i in arm_sites else (0.0, 0.0, 0.0)
        along = int(np.argmax(np.abs(e1 - e0)))  # the principal axis the end caps lie on
        rods.append(
            Rod(
                name=mj_name(m, BODY, b),
                length=float(np.linalg.norm(e1 - e0)),
                radius=radius,
                end_offsets=(tuple(e0.tolist()), tuple(e1.tolist())),
                control_arm=arm,
                frame_origin=to_inertial(i, np.zeros(3)),
                end_cap="sphere" if shapes == {"sphere"} else "capsule",
                attachments=tuple(to_inertial(i, m.site_pos[s]) for s in rod_points[i]),
                cap_radius=(radii[0], radii[1]) if own else None,
                axial_gyration=float(m.body_inertia[b][along] / m.body_mass[b])
                if m.body_mass[b] > 0 and m.body_inertia[b][along] > 0 else None,
            )
        )

    # nodes: end caps by rod, then world anchors in order of first use
    node_of_site: dict[int, int] = {}
    for i, ends in enumerate(rod_ends):
        node_of_site[ends[0]], node_of_site[ends[1]] = 2 * i, 2 * i + 1
    world_sites = [
        s for pair in tendon_sites for s in pair if s not in node_of_site and m.site_bodyid[s] == 0
    ]
    anchor_sites = list(dict.fromkeys(world_sites))  # in order of first use
    anchors = [tuple(m.site_pos[s].tolist()) for s in anchor_sites]
    for k, s in enumerate(anchor_sites):
        node_of_site[s] = 2 * len(rods) + k
    n_point = 2 * len(rods) + len(anchors)
    for points in rod_points:
        for s in points:
            node_of_site[s] = n_point
            n_point += 1
    springs = []
    for t, pair in enumerate(tendon_sites):
        for s in pair:
            if s not in node_of_site:
                body = m.site_bodyid[s]
                raise InputError(
                    f"{src}: spring '{mj_name(m, TEN, t)}' attaches to site '{mj_name(m, SITE, s)}'"
                    f" on body '{mj_name(m, BODY, body)}', which is neither a rod nor the world"
                )
        springs.append(Spring(mj_name(m, TEN, t), node_of_site[pair[0]], node_of_site[pair[1]]))
    try:
        topology = Topology(
            rods=tuple(rods),
            springs=tuple(springs),
            anchors=tuple(anchors),
            name=m.names[: m.names.index(b"\0")].decode() or "assembly",
            cable_actuators=tuple(int(m.actuator_trnid[a, 0]) for a in cables.ids),
            winches=tuple(winches.tendons),
        )
    except TopologyError as e:
        raise InputError(f"{src}: {e}") from None

    stiffness = m.tendon_stiffness.copy()
    for t in range(m.ntendon):
        if stiffness[t] <= 0:
            raise InputError(f"{src}: spring '{mj_name(m, TEN, t)}' has non-positive stiffness")
        if m.tendon_damping[t] < 0:
            raise InputError(f"{src}: spring '{mj_name(m, TEN, t)}' has negative damping")
    for b in rod_bodies:
        if m.body_mass[b] <= 0 or np.any(m.body_inertia[b] <= 0):
            raise InputError(f"{src}: rod '{mj_name(m, BODY, b)}' has non-positive mass or inertia")
    # what the file says beyond rods and springs: modelled, or refused unless ignored
    contact, contact_found = contact_of(m, cap_geoms, floor, src)
    tendon_actuators = [
        a for a in range(m.nu) if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_TENDON
    ]  # supported ones are cable commands, the rest in cables.found
    controls = [int(a) for a in actuators[actuators >= 0]] + tendon_actuators
    found = unsupported_features(m, rod_bodies, floor, controls)
    refuse_or_warn(found + contact_found + shape_found + cables.found, ignore, src)
    # dead band [0, L]: a tension-only (slack) spring of rest length L
    low, high = m.tendon_lengthspring[:, 0], m.tendon_lengthspring[:, 1]
    slack = tuple(int(t) for t in np.nonzero((low == 0) & (high > 0))[0])
    winch_values: dict[str, Any] = dict(winches.values)  # WINCH_FIELDS -> (W,) arrays
    params = Params.create(
        stiffness=stiffness,
        damping=m.tendon_damping.copy(),
        rest_length=np.where((low == 0) & (high > 0), high, low),
        mass=m.body_mass[rod_bodies].copy(),
        inertia=m.body_inertia[rod_bodies].copy(),
        control_gain=gains[0] if gains else 1.0,
        gravity=m.opt.gravity.copy(),
        cable_gain=[m.actuator_gainprm[a, 0] * m.actuator_gear[a, 0] for a in cables.ids],
        **winch_values,
    )
    bad = [f for f, v in params.numpy().items() if not np.all(np.isfinite(v))]
    if not (np.isfinite(m.opt.timestep) and m.opt.timestep > 0):
        bad.append("timestep")
    if bad:
        raise InputError(f"{src}: {', '.join(bad)}: NaN, inf or out of range in the file")
    integrator = {
        int(mujoco.mjtIntegrator.mjINT_EULER): "Euler",
        int(mujoco.mjtIntegrator.mjINT_RK4): "RK4",
        int(mujoco.mjtIntegrator.mjINT_IMPLICIT): "implicit",
        int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST): "implicitfast",
    }.get(int(m.opt.integrator), "Euler")
    options = SimOptions(
        timestep=float(m.opt.timestep),
        integrator=integrator,
        ground=bool(floor),
        rod_collisions=any(f.feature == "rod-collisions" for f in found),
        control=bool(gains),
        friction=contact.get("friction", SimOptions.friction),
        cable_lag=cables.lag,
    )
    return MjcfAssembly(
        topology=topology,
        params=params,
        options=options,
        model=model,
        rod_bodies=np.array(rod_bodies),
        rod_qpos=np.array([m.jnt_qposadr[m.body_jntadr[b]] for b in rod_bodies]),
        rod_qvel=np.array([m.jnt_dofadr[m.body_jntadr[b]] for b in rod_bodies]),
        body_ipos=ipos,
        body_iquat=iquat,
        actuators=actuators,
        contact=contact,
        slack_springs=slack,
        cable_actuators=np.array(cables.ids, dtype=int),
        cable_lag=cables.lag,
        joint_damping=joint_damping_of(m, rod_bodies) or 0.0,
    )


@dataclass(frozen=True)
class CableActuators:
    """The supported tendon actuators of a model (what :func:`cable_actuators_of` finds).

    Attributes:
        ids: actuator ids, in actuator order.
        lag: their common filter time constant [s], 0 without a filter.
        found: the unsupported ones, refused by name unless ``--ignore actuators``.
    """

    ids: list[int]
    lag: float
    found: list[Unsupported]


def cable_actuators_of(m: mujoco.MjModel, src: str) -> CableActuators:
    """Tendon actuators that are cable commands: force ``gain * gear * u`` along a spring
    (:func:`~tensegrity_env.mjcf_checks.cable_actuator_problem`); all filtered with one
    time constant or none filtered (one ``control_lag``); one actuator per spring."""
    ACT = mujoco.mjtObj.mjOBJ_ACTUATOR
    ids, found, lags = [], [], set()
    driven: dict[int, int] = {}
    for a in range(m.nu):
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_TENDON:
            continue
        name = mj_name(m, ACT, a)
        problem = cable_actuator_problem(m, a)
        if problem is not None:
            found.append(Unsupported("actuators", f"cable actuator '{name}' has {problem}"))
            continue
        t = int(m.actuator_trnid[a, 0])
        if t in driven:
            raise InputError(
                f"{src}: actuators '{mj_name(m, ACT, driven[t])}' and '{name}' drive the same"
                " tendon (one cable actuator per spring)"
            )
        driven[t] = a
        ids.append(a)
        filtered = int(m.actuator_dyntype[a]) == int(mujoco.mjtDyn.mjDYN_FILTER)
        lags.add(float(m.actuator_dynprm[a, 0]) if filtered else 0.0)
    if len(lags) > 1:
        raise InputError(
            f"{src}: cable actuators have different filters (time constants"
            f" {sorted(lags)} s); the model has one control_lag"
        )
    return CableActuators(ids, lags.pop() if lags else 0.0, found)


def inertial_quat(assembly: MjcfAssembly, body_quat: np.ndarray) -> np.ndarray:
    """Orientation of each rod's principal frame from body quaternions (..., R, 4)."""
    return np_quat_mul(body_quat, np.broadcast_to(assembly.body_iquat, body_quat.shape))
