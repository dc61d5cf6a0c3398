"""MuJoCo ground truth: write an assembly as MJCF, and read any MJCF of the same form back.

The convention (DESIGN.md) that any MJCF must follow to be read:

* a **rod** is a body with one free joint and (at least) two sites, its end caps:
  the points motion capture tracks and the floor touches. With more sites, the end
  caps are the two at the rod's ends along its long axis (the principal axis of least
  inertia; of sites equally far out, the one nearest the axis), or the sites named
  in ``end_caps``;
* a **spring** is a spatial tendon through exactly two sites, each a site on a rod (an
  end cap, or any other site: an attachment point) or a site on the world body (a
  fixed anchor), with ``stiffness``, ``damping`` and ``springlength``;
* optional **control**: ``general`` actuators with a site transmission on a rod site
  (the arm ``r_u``) and a ``refsite`` on the world body (so the force direction is fixed
  in the world); the actuator gain is the control gain ``h`` and belongs to the ground
  truth only.

Rods are written with an explicit ``<inertial>`` (principal axes = body axes), so
``M`` and ``I`` are exactly the parameters. Reading takes each rod's mass, centre of
mass, principal frame and inertia from the compiled model (``body_mass``,
``body_ipos``, ``body_iquat``, ``body_inertia``: an ``<inertial>`` element or the
union of the body's geoms), whatever the body frame; the body frame's origin is kept
(``Rod.frame_origin``) because MuJoCo's free joint integrates that point. Rod-rod collisions are off by default
(``contype``/``conaffinity`` bits); with a ground plane, end caps collide with it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf_checks import (
    Unsupported,
    check_ignore_names,
    contact_of,
    refuse_or_warn,
    unsupported_features,
)
from tensegrity_env.params import Params
from tensegrity_env.rotations import np_quat_mul, np_quat_to_matrix
from tensegrity_env.topology import Rod, Spring, Topology, TopologyError

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class SimOptions:
    """How the MuJoCo ground truth is simulated.

    Attributes:
        timestep: physics step [s].
        integrator: MuJoCo integrator name ("Euler" is semi-implicit, as the engine).
        ground: add a ground plane at z = 0 that rod end caps collide with.
        rod_collisions: let rods collide with each other (off: an undeclared effect).
        control: add three world-axis force actuators per rod at its control arm.
        friction: sliding friction coefficient of the ground contact.
    """

    timestep: float = 1e-3
    integrator: str = "Euler"
    ground: bool = False
    rod_collisions: bool = False
    control: bool = True
    friction: float = 1.0


def _f(x: float) -> str:
    return repr(float(x))


def _v(xs: np.ndarray | tuple[float, ...] | list[float]) -> str:
    return " ".join(_f(x) for x in np.ravel(xs))


def to_mjcf(
    topology: Topology,
    params: Params,
    options: SimOptions = SimOptions(),
    pose_p: np.ndarray | None = None,
    pose_q: np.ndarray | None = None,
) -> str:
    """MJCF text of the assembly with its ground-truth parameters.

    ``pose_p`` (R, 3) [m] and ``pose_q`` (R, 4) give the rods' initial poses (``qpos0``):
    centres of mass and principal-frame orientations. Each body frame is the principal
    frame moved to the rod's ``frame_origin``.
    """
    P = params.numpy()
    R = topology.n_rods
    pose_p = np.zeros((R, 3)) if pose_p is None else np.asarray(pose_p, float)
    pose_q = np.tile([1.0, 0, 0, 0], (R, 1)) if pose_q is None else np.asarray(pose_q, float)

    root = ET.Element("mujoco", model=topology.name)
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(
        root,
        "option",
        timestep=_f(options.timestep),
        integrator=options.integrator,
        gravity=_v(P["gravity"]),
    )
    ET.SubElement(ET.SubElement(root, "visual"), "global", offwidth="1280", offheight="720")
    asset = ET.SubElement(root, "asset")
    ET.SubElement(
        asset, "texture", name="grid", type="2d", builtin="checker", width="512", height="512",
        rgb1=".2 .3 .4", rgb2=".1 .15 .2",
    )  # fmt: skip
    ET.SubElement(asset, "material", name="grid", texture="grid", texrepeat="8 8", reflectance=".1")
    world = ET.SubElement(root, "worldbody")
    ET.SubElement(world, "light", pos="0 0 6", dir="0 0 -1", directional="true")
    # collision bits: rods (2) only meet the floor (1) unless rod_collisions is on
    rod_type, rod_aff = ("3", "3") if options.rod_collisions else ("2", "1")
    if options.ground:
        ET.SubElement(
            world, "geom", name="floor", type="plane", size="0 0 0.05", material="grid",
            contype="1", conaffinity="2", friction=f"{_f(options.friction)} 0.005 0.0001",
        )  # fmt: skip
    ET.SubElement(world, "site", name="world_frame", pos="0 0 0", size="0.001")
    for k, anchor in enumerate(topology.anchors):
        ET.SubElement(world, "site", name=f"anchor{k}", pos=_v(anchor), size="0.02", rgba="1 1 0 1")
    ends = topology.end_offsets
    origins = topology.frame_origins
    for r, rod in enumerate(topology.rods):
        # the body frame is the principal frame moved to the rod's frame_origin
        o = origins[r]
        body_pos = pose_p[r] + np_quat_to_matrix(pose_q[r]) @ o if o.any() else pose_p[r]
        body = ET.SubElement(world, "body", name=rod.name, pos=_v(body_pos), quat=_v(pose_q[r]))
        ET.SubElement(body, "freejoint", name=rod.name)
        ET.SubElement(
            body,
            "inertial",
            pos=_v(0.0 - o) if o.any() else "0 0 0",
            mass=_f(P["mass"][r]),
            diaginertia=_v(P["inertia"][r]),
        )
        ET.SubElement(
            body, "geom", name=f"{rod.name}_geom", type="capsule",
            fromto=_v(np.concatenate([ends[r, 0] - o, ends[r, 1] - o])),
            size=_f(max(rod.radius, 1e-3)), contype=rod_type, conaffinity=rod_aff,
            rgba="0.8 0.3 0.2 1", mass="0",
        )  # fmt: skip
        for e in range(2):
            ET.SubElement(
                body, "site", name=f"{rod.name}_end{e}", pos=_v(ends[r, e] - o), size="0.02"
            )
        for k, point in enumerate(rod.attachments):
            ET.SubElement(
                body, "site", name=f"{rod.name}_point{k}", pos=_v(np.asarray(point) - o),
                size="0.01",
            )  # fmt: skip
        ET.SubElement(
            body, "site", name=f"{rod.name}_arm", pos=_v(np.asarray(rod.control_arm) - o),
            size="0.005",
        )  # fmt: skip

    tendon = ET.SubElement(root, "tendon")
    for s, spring in enumerate(topology.springs):
        sp = ET.SubElement(
            tendon, "spatial", name=spring.name, stiffness=_f(P["stiffness"][s]),
            damping=_f(P["damping"][s]), springlength=_f(P["rest_length"][s]), width="0.005",
            rgba="0.2 0.6 1 1",
        )  # fmt: skip
        for node in (spring.node_a, spring.node_b):
            ET.SubElement(sp, "site", site=_site_of_node(topology, node))

    if options.control:
        act = ET.SubElement(root, "actuator")
        for rod in topology.rods:
            for k, ax in enumerate(AXES):
                gear = np.zeros(6)
                gear[k] = 1.0
                ET.SubElement(
                    act, "general", name=f"{rod.name}_f{ax}", site=f"{rod.name}_arm",
                    refsite="world_frame", gear=_v(gear), gainprm=_f(P["control_gain"]),
                )  # fmt: skip
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def _site_of_node(topology: Topology, node: int) -> str:
    if topology.is_anchor(node):
        return f"anchor{node - 2 * topology.n_rods}"
    if node >= 2 * topology.n_rods:
        rod = int(topology.node_rod[node])
        return f"{topology.rods[rod].name}_point{node - topology.point_node(rod, 0)}"
    return f"{topology.rods[node // 2].name}_end{node % 2}"


def build_model(
    topology: Topology,
    params: Params,
    options: SimOptions = SimOptions(),
    pose_p: np.ndarray | None = None,
    pose_q: np.ndarray | None = None,
) -> mujoco.MjModel:
    """Compiled MuJoCo model of the assembly."""
    return mujoco.MjModel.from_xml_string(to_mjcf(topology, params, options, pose_p, pose_q))


# ---------------------------------------------------------------------- reading
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


def _name(m: mujoco.MjModel, obj: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(m, obj, i) or f"#{i}"


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
        raise InputError(f"{src}: MuJoCo cannot load it ({str(e).splitlines()[0]})") from None
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
            raise InputError(f"{src}: body '{_name(m, BODY, b)}' has joints but is not a free rod")
    rod_index = {b: i for i, b in enumerate(rod_bodies)}

    # control actuators: site transmission on a rod site, refsite on the world body
    arm_sites: dict[int, int] = {}
    actuators = -np.ones((len(rod_bodies), 3), dtype=int)
    gains: list[float] = []
    for a in range(m.nu):
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_SITE:
            continue
        site, ref = m.actuator_trnid[a]
        body = m.site_bodyid[site]
        gear = m.actuator_gear[a]
        axis = int(np.argmax(np.abs(gear[:3])))
        if body not in rod_index or ref < 0 or m.site_bodyid[ref] != 0:
            raise InputError(
                f"{src}: actuator '{_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a)}' is not a world-frame"
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
                f"{src}: tendon '{_name(m, TEN, t)}' is not a two-site spatial tendon (a spring)"
            )
        tendon_sites.append((int(m.wrap_objid[adr]), int(m.wrap_objid[adr + 1])))

    # geometry in each rod's inertial (principal) frame
    ipos = np.array([m.body_ipos[b] for b in rod_bodies])
    iquat = np.array([m.body_iquat[b] for b in rod_bodies])
    Ri = np_quat_to_matrix(iquat)  # inertial frame -> body frame

    def to_inertial(i: int, pos_body: np.ndarray) -> tuple[float, float, float]:
        return tuple((Ri[i].T @ (pos_body - ipos[i])).tolist())  # type: ignore[return-value]

    # end caps of each rod (named, or by convention); its other spring sites are
    # attachment points, in order of first use
    named = _named_sites(m, end_caps, src)
    rod_ends: list[list[int]] = []
    rod_points: list[list[int]] = [[] for _ in rod_bodies]
    for i, b in enumerate(rod_bodies):
        sites = [s for s in range(m.nsite) if m.site_bodyid[s] == b]
        local = {s: np.asarray(to_inertial(i, m.site_pos[s])) for s in sites}
        axis = int(np.argmin(m.body_inertia[b]))
        rod_ends.append(
            _end_cap_sites(m, b, sites, arm_sites.get(i), local, axis, named, src)
        )
    for pair in tendon_sites:
        for s in pair:
            b = int(m.site_bodyid[s])
            if b in rod_index:
                i = rod_index[b]
                if s not in rod_ends[i] and s not in rod_points[i]:
                    rod_points[i].append(s)

    floor = _floor_geoms(m)
    rods = []
    cap_geoms: list[int] = []
    shape_found: list[Unsupported] = []
    for i, b in enumerate(rod_bodies):
        e0, e1 = (np.asarray(to_inertial(i, m.site_pos[s])) for s in rod_ends[i])
        radius, geoms = _end_cap_radius(m, b, rod_ends[i], floor, src)
        cap_geoms += geoms
        shapes = {_CAP_TYPES[int(m.geom_type[g])] for g in geoms}
        if floor and "cylinder" in shapes:
            shape_found.append(
                Unsupported("end-cap-shape", f"rod '{_name(m, BODY, b)}' has cylinder end caps")
            )
        if len(shapes) > 1 and floor:
            raise InputError(
                f"{src}: rod '{_name(m, BODY, b)}': end caps of different shapes {sorted(shapes)}"
            )
        arm = to_inertial(i, m.site_pos[arm_sites[i]]) if i in arm_sites else (0.0, 0.0, 0.0)
        rods.append(
            Rod(
                name=_name(m, BODY, b),
                length=float(np.linalg.norm(e1 - e0)),
                radius=radius,
                end_offsets=(tuple(e0.tolist()), tuple(e1.tolist())),  # type: ignore[arg-type]
                control_arm=arm,
                frame_origin=to_inertial(i, np.zeros(3)),
                end_cap="sphere" if shapes == {"sphere"} else "capsule",
                attachments=tuple(to_inertial(i, m.site_pos[s]) for s in rod_points[i]),
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
                    f"{src}: spring '{_name(m, TEN, t)}' attaches to site '{_name(m, SITE, s)}'"
                    f" on body '{_name(m, BODY, body)}', which is neither a rod nor the world"
                )
        springs.append(Spring(_name(m, TEN, t), node_of_site[pair[0]], node_of_site[pair[1]]))
    try:
        topology = Topology(
            rods=tuple(rods),
            springs=tuple(springs),
            anchors=tuple(anchors),  # type: ignore[arg-type]
            name=m.names[: m.names.index(b"\0")].decode() or "assembly",
        )
    except TopologyError as e:
        raise InputError(f"{src}: {e}") from None

    stiffness = m.tendon_stiffness.copy()
    for t in range(m.ntendon):
        if stiffness[t] <= 0:
            raise InputError(f"{src}: spring '{_name(m, TEN, t)}' has non-positive stiffness")
        if m.tendon_damping[t] < 0:
            raise InputError(f"{src}: spring '{_name(m, TEN, t)}' has negative damping")
    for b in rod_bodies:
        if m.body_mass[b] <= 0 or np.any(m.body_inertia[b] <= 0):
            raise InputError(f"{src}: rod '{_name(m, BODY, b)}' has non-positive mass or inertia")
    # what the file says beyond rods and springs: modelled, or refused unless ignored
    contact, contact_found = contact_of(m, cap_geoms, floor, src)
    found = unsupported_features(m, rod_bodies, floor, [int(a) for a in actuators[actuators >= 0]])
    refuse_or_warn(found + contact_found + shape_found, ignore, src)
    # dead band [0, L]: a tension-only (slack) spring of rest length L
    low, high = m.tendon_lengthspring[:, 0], m.tendon_lengthspring[:, 1]
    slack = tuple(int(t) for t in np.nonzero((low == 0) & (high > 0))[0])
    params = Params.create(
        stiffness=stiffness,
        damping=m.tendon_damping.copy(),
        rest_length=np.where((low == 0) & (high > 0), high, low),
        mass=m.body_mass[rod_bodies].copy(),
        inertia=m.body_inertia[rod_bodies].copy(),
        control_gain=gains[0] if gains else 1.0,
        gravity=m.opt.gravity.copy(),
    )
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
    )


def _named_sites(m: mujoco.MjModel, names: Collection[str], src: str) -> set[int]:
    """Site ids of the ``end_caps`` names; an unknown name is refused."""
    out = set()
    for name in names:
        s = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
        if s < 0:
            raise InputError(f"{src}: end-cap site '{name}' does not exist")
        out.add(int(s))
    return out


def _end_cap_sites(
    m: mujoco.MjModel,
    body: int,
    sites: list[int],
    arm: int | None,
    local: dict[int, np.ndarray],
    axis: int,
    named: set[int],
    src: str,
) -> list[int]:
    """The two end-cap sites of a rod, in site order.

    The sites named in ``end_caps`` when the rod has any; else its only two sites
    besides the control arm; else the site at each end along the rod's long axis
    (``axis`` of the principal frame, positions ``local``), the one nearest the axis
    among sites equally far out (a site on an end cap's surface beside its centre).
    """
    rod = _name(m, mujoco.mjtObj.mjOBJ_BODY, body)
    why = "the end caps are the points motion capture tracks and the floor touches"
    mine = [s for s in sites if s in named]
    if named and mine:
        if len(mine) != 2:
            raise InputError(f"{src}: rod '{rod}': {len(mine)} end-cap sites named, needs 2 ({why})")
        return sorted(mine)
    cands = [s for s in sites if s != arm]
    if len(cands) < 2:
        raise InputError(
            f"{src}: rod '{rod}' has {len(cands)} site(s) besides its control arm and needs two"
            f" end-cap sites ({why})"
        )
    if len(cands) == 2:
        return sorted(cands)
    along = np.array([local[s][axis] for s in cands])
    off = np.array([np.linalg.norm(np.delete(local[s], axis)) for s in cands])
    tol = 1e-9 * (1.0 + float(np.ptp(along)))
    ends = []
    for extreme in (along.min(), along.max()):
        out = [k for k in range(len(cands)) if abs(along[k] - extreme) <= tol]
        near = [k for k in out if off[k] <= off[out].min() + tol]
        if len(near) > 1:
            names = ", ".join(f"'{_name(m, mujoco.mjtObj.mjOBJ_SITE, cands[k])}'" for k in near)
            raise InputError(
                f"{src}: rod '{rod}': cannot tell which of sites {names} is the end cap ({why});"
                " name the end-cap sites (end_caps)"
            )
        ends.append(cands[near[0]])
    return sorted(ends)


def _floor_geoms(m: mujoco.MjModel) -> list[int]:
    """Planes on the world body (the floor), by geom id."""
    return [
        g
        for g in range(m.ngeom)
        if m.geom_bodyid[g] == 0 and int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_PLANE)
    ]


def _touches(m: mujoco.MjModel, g: int, floor: list[int]) -> bool:
    """Whether geom ``g`` can collide with any floor plane (contype/conaffinity bits)."""
    return any(
        (m.geom_contype[g] & m.geom_conaffinity[f]) or (m.geom_contype[f] & m.geom_conaffinity[g])
        for f in floor
    )


#: geom types an end cap may be: a sphere centred at the end-cap site, or a capsule or
#: cylinder with one end of its axis there
_CAP_TYPES = {
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
}


def _end_cap_radius(
    m: mujoco.MjModel, body: int, sites: list[int], floor: list[int], src: str
) -> tuple[float, list[int]]:
    """Contact radius of a rod's end caps [m]: the geom found at each end-cap site.

    A geom is at a site when it is a sphere centred there or a capsule/cylinder whose
    axis ends there; with a floor, only geoms that can collide with it count. Where
    several are, the largest radius is the one that meets the floor. 0 without a floor
    and no such geom; refused when a floor is present and an end cap has none, or
    when the two end caps' radii differ (one contact radius per rod).

    Returns:
        the radius [m] and the end-cap geoms (ids).
    """
    radii, cap_geoms = [], []
    for s in sites:
        x = m.site_pos[s]
        found, geoms = [0.0], [-1]
        for g in range(m.ngeom):
            if m.geom_bodyid[g] != body or int(m.geom_type[g]) not in _CAP_TYPES:
                continue
            if floor and not _touches(m, g, floor):
                continue
            size, pos = m.geom_size[g], m.geom_pos[g]
            tol = 1e-9 * (1.0 + float(np.abs(pos).max()) + float(size[0]))
            if int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_SPHERE):
                ends = [pos]
            else:
                half = np_quat_to_matrix(m.geom_quat[g]) @ np.array([0.0, 0.0, size[1]])
                ends = [pos - half, pos + half]
            if any(float(np.linalg.norm(x - e)) <= tol for e in ends):
                found.append(float(size[0]))
                geoms.append(g)
        if floor and max(found) == 0.0:
            raise InputError(
                f"{src}: rod '{_name(m, mujoco.mjtObj.mjOBJ_BODY, body)}': no sphere, capsule or"
                f" cylinder end that meets the floor at end-cap site"
                f" '{_name(m, mujoco.mjtObj.mjOBJ_SITE, s)}' (ground contact needs the end"
                " cap's radius)"
            )
        radii.append(max(found))
        cap_geoms.append(geoms[int(np.argmax(found))])
    if abs(radii[0] - radii[1]) > 1e-12 * (1.0 + max(radii)):
        raise InputError(
            f"{src}: rod '{_name(m, mujoco.mjtObj.mjOBJ_BODY, body)}': end caps of different"
            f" radii {radii} (the contact model has one radius per rod)"
        )
    return max(radii), [g for g in cap_geoms if g >= 0]


def inertial_quat(assembly: MjcfAssembly, body_quat: np.ndarray) -> np.ndarray:
    """Orientation of each rod's principal frame from body quaternions (..., R, 4)."""
    return np_quat_mul(body_quat, np.broadcast_to(assembly.body_iquat, body_quat.shape))
