"""The ground truth behind the environments: a prestressed icosahedron on a floor.

The paper's icosahedron (:func:`tensegrity_env.assemblies.icosahedron`) has every
spring exactly at its rest length in the nominal pose (no prestress) and 100 N/m
springs; under gravity on a floor it folds flat (its centre ends 16 mm above the
floor, the rod radius). A rolling tensegrity robot is prestressed, so the
environments' ground truth is the same topology, rod masses and control gain
``h_true = 2.5`` with stiffer springs (300 N/m ±20 %, 3 N*s/m) and rest lengths at
85 % of the nominal spring length (about 29 N of pretension per spring). It stands
with its centre about 0.3 m high and rolls under bounded control forces.

The rods are 5 cm in radius (end caps the size of a real robot's motor housings),
not 16 mm: an end cap rolling sideways on the floor spins its rod about its own
axis at ``v / r``, and the thin rods' spin (300 rad/s when pushed along at 1 m/s)
made the explicitly integrated gyroscopic coupling of every Euler-integrated model,
MuJoCo's included, blow up within seconds.

:func:`twin_assembly` builds it; :func:`face_down_pose` puts a triangular face on
the floor; :func:`twin_mjcf` writes the MuJoCo twin (floor, three world-axis force
actuators per rod with gain ``h_true``) that ships as
``tensegrity_env/assets/icosahedron_rolling.xml``.
"""

from __future__ import annotations

import numpy as np

from tensegrity_env.assemblies import Assembly, icosahedron, node_positions
from tensegrity_env.mjcf import SimOptions, to_mjcf
from tensegrity_env.rotations import axis_angle_to_quat, np_quat_mul, np_quat_to_matrix
from tensegrity_env.topology import Topology

#: ground truth of the environments (see the module docstring)
TWIN_STIFFNESS = 300.0  # N/m, nominal (varied ±20 % per spring)
TWIN_DAMPING = 3.0  # N*s/m, nominal (varied ±20 % per spring)
TWIN_PRESTRESS = 0.85  # rest length / nominal spring length
TWIN_RADIUS = 0.05  # m, rods and end caps
TWIN_TIMESTEP = 1e-3  # s
#: clearance between the lowest end-cap surface and the floor in the initial pose [m]
DROP_CLEARANCE = 1e-3


def twin_assembly() -> Assembly:
    """The prestressed icosahedron: topology, true parameters, nominal pose."""
    a = icosahedron(stiffness=TWIN_STIFFNESS, damping=TWIN_DAMPING, radius=TWIN_RADIUS)
    params = a.params.replace(rest_length=a.params.rest_length * TWIN_PRESTRESS)
    return Assembly(a.topology, params, a.pose_p, a.pose_q)


def face_down_pose(
    topology: Topology, pose_p: np.ndarray, pose_q: np.ndarray, clearance: float = DROP_CLEARANCE
) -> tuple[np.ndarray, np.ndarray]:
    """The nominal pose turned so that a triangular face lies parallel to the floor.

    The face whose outward normal is ``(-1, -1, -1)/√3`` in the nominal frame is turned
    to face straight down, and the pose is lifted so that the lowest end-cap surface is
    ``clearance`` above ``z = 0``. Returns rod centres (R, 3) [m] and orientations (R, 4).
    """
    normal, below = np.full(3, -1.0) / np.sqrt(3.0), np.array([0.0, 0.0, -1.0])
    axis = np.cross(normal, below)  # turn about it by the angle between the two
    down = axis_angle_to_quat(axis, np.arctan2(np.linalg.norm(axis), float(normal @ below)))
    rot = np_quat_to_matrix(down)
    centre = pose_p.mean(axis=0)
    p = (pose_p - centre) @ rot.T
    q = np_quat_mul(np.broadcast_to(down, pose_q.shape), pose_q)
    caps = node_positions(topology, p, q)[: 2 * topology.n_rods]
    radius = max(r.radius for r in topology.rods)
    p[:, 2] += clearance + radius - caps[:, 2].min()
    return p, q


def twin_mjcf(ground: bool = True) -> str:
    """MJCF text of the twin: the prestressed icosahedron face down, with control actuators."""
    a = twin_assembly()
    p, q = face_down_pose(a.topology, a.pose_p, a.pose_q)
    options = SimOptions(timestep=TWIN_TIMESTEP, ground=ground, control=True)
    return to_mjcf(a.topology, a.params, options, p, q)
