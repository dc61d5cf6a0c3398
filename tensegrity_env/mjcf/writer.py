"""Write an assembly and its ground-truth parameters as MJCF (the convention of
:mod:`tensegrity_env.mjcf`)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import SupportsFloat

import mujoco
import numpy as np

from tensegrity_env.mjcf.winches import winch_numerics
from tensegrity_env.params import Params
from tensegrity_env.rotations import np_quat_to_matrix
from tensegrity_env.topology import Topology

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
        cable_lag: time constant of the cable actuators' first-order filter [s]
            (``dyntype="filter"``); 0 writes them unfiltered.
    """

    timestep: float = 1e-3
    integrator: str = "Euler"
    ground: bool = False
    rod_collisions: bool = False
    control: bool = True
    friction: float = 1.0
    cable_lag: float = 0.0


def _f(x: SupportsFloat) -> str:
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
        own = rod.cap_radius is not None  # end caps of their own sizes: a sphere at each end
        ET.SubElement(
            body, "geom", name=f"{rod.name}_geom", type="capsule",
            fromto=_v(np.concatenate([ends[r, 0] - o, ends[r, 1] - o])),
            size=_f(max(rod.radius, 1e-3)), contype="0" if own else rod_type,
            conaffinity="0" if own else rod_aff, rgba="0.8 0.3 0.2 1", mass="0",
        )  # fmt: skip
        for e in range(2) if own else ():
            ET.SubElement(
                body, "geom", name=f"{rod.name}_cap{e}", type="sphere", pos=_v(ends[r, e] - o),
                size=_f(max(rod.cap_radius[e], 1e-3)), contype=rod_type,  # type: ignore[index]  # own: set
                conaffinity=rod_aff, rgba="0.8 0.3 0.2 1", mass="0",
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
    if topology.cable_actuators:
        found = root.find("actuator")
        act = ET.SubElement(root, "actuator") if found is None else found
        lag = {"dyntype": "filter", "dynprm": _f(options.cable_lag)} if options.cable_lag else {}
        for c, s in enumerate(topology.cable_actuators):
            ET.SubElement(act, "general", {
                "name": f"{topology.springs[s].name}_cable", "tendon": topology.springs[s].name,
                "gainprm": _f(P["cable_gain"][c]), **lag,
            })  # fmt: skip
    if topology.winches:  # the winch convention of tensegrity_env.mjcf.winches
        custom = ET.SubElement(root, "custom")
        for name, data in winch_numerics(topology, params):
            ET.SubElement(custom, "numeric", name=name, data=data)
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
