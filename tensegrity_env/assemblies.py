"""The paper's two assemblies: the one-rod element and the 6-rod, 24-spring icosahedron.

Each builder returns an :class:`Assembly`: topology, ground-truth parameters and the
nominal pose (rod centres and orientations). Ground-truth parameters vary per spring
and per rod (seeded) so that per-element identification has something to find.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tensegrity_env.params import Params
from tensegrity_env.rotations import axis_angle_to_quat, np_quat_to_matrix
from tensegrity_env.topology import Rod, Spring, Topology

#: The paper's icosahedron: rod length and spring rest length [m].
ICOSAHEDRON_ROD_LENGTH = 1.04
ICOSAHEDRON_REST_LENGTH = 0.637
GRAVITY = (0.0, 0.0, -9.81)


@dataclass(frozen=True)
class Assembly:
    """Topology, ground-truth parameters and nominal pose of one assembly.

    Attributes:
        topology: the spring-rod graph.
        params: ground-truth physical parameters.
        pose_p: nominal rod centre positions, (R, 3) [m].
        pose_q: nominal rod orientations (w, x, y, z), (R, 4).
    """

    topology: Topology
    params: Params
    pose_p: np.ndarray
    pose_q: np.ndarray

    def node_positions(self) -> np.ndarray:
        """World positions of all nodes in the nominal pose, (n_nodes, 3) [m]."""
        return node_positions(self.topology, self.pose_p, self.pose_q)


def node_positions(topology: Topology, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """All nodes in world coordinates: end caps, anchors, then attachment points.

    ``p`` (..., R, 3) [m] and ``q`` (..., R, 4) are rod poses; returns (..., n_nodes, 3) [m].
    """
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    rod = topology.node_rod
    on = rod >= 0
    rot = np_quat_to_matrix(q)[..., rod[on], :, :]  # (..., n_rod_nodes, 3, 3)
    x = np.broadcast_to(topology.node_offsets, (*p.shape[:-2], topology.n_nodes, 3)).copy()
    x[..., on, :] = p[..., rod[on], :] + np.einsum(
        "...nij,nj->...ni", rot, topology.node_offsets[on]
    )
    return x


def cylinder_inertia(mass: np.ndarray, length: float, radius: float) -> np.ndarray:
    """Principal inertia of solid cylinders along z, (R, 3) [kg*m^2]."""
    m = np.asarray(mass, dtype=float)
    perp = m * (3 * radius**2 + length**2) / 12.0
    axial = 0.5 * m * radius**2
    return np.stack([perp, perp, axial], axis=-1)


def _vary(rng: np.random.Generator, base: float, spread: float, n: int) -> np.ndarray:
    return base * (1.0 + spread * rng.uniform(-1.0, 1.0, n))


def icosahedron(
    stiffness: float = 100.0,
    damping: float = 1.0,
    mass: float = 2.0,
    control_gain: float = 2.5,
    radius: float = 0.016,
    spread: float = 0.2,
    seed: int = 0,
) -> Assembly:
    """The 6-rod, 24-spring icosahedron (expanded octahedron) of the paper.

    Rods of 1.04 m lie in three mutually orthogonal parallel pairs; the pair
    separation is chosen so that all 24 springs are exactly at their 0.637 m rest
    length in the nominal pose. ``spread`` is the relative per-spring / per-rod
    variation of K, c (``spread``) and M (``spread / 2``) drawn with ``seed``.
    """
    L, l0 = ICOSAHEDRON_ROD_LENGTH, ICOSAHEDRON_REST_LENGTH
    a = L / 2
    # spring (0, s, a) -> (s, a, 0) has length^2 = s^2 + (a - s)^2 + a^2 = l0^2;
    # take the root closer to the regular icosahedron (s = a / golden ratio).
    s = (2 * a + np.sqrt(4 * a**2 - 8 * (2 * a**2 - l0**2))) / 4
    half_pi = np.pi / 2
    axes = [  # (rod axis orientation, offset of the rod centre)
        (np.array([1.0, 0, 0, 0]), (0, s, 0)),
        (np.array([1.0, 0, 0, 0]), (0, -s, 0)),
        (axis_angle_to_quat([0, 1, 0], half_pi), (0, 0, s)),
        (axis_angle_to_quat([0, 1, 0], half_pi), (0, 0, -s)),
        (axis_angle_to_quat([1, 0, 0], -half_pi), (s, 0, 0)),
        (axis_angle_to_quat([1, 0, 0], -half_pi), (-s, 0, 0)),
    ]
    pose_q = np.stack([q for q, _ in axes])
    pose_p = np.array([c for _, c in axes], dtype=float)
    rods = tuple(
        Rod(name=f"rod{i}", length=L, radius=radius, control_arm=(0.0, 0.0, L / 4))
        for i in range(6)
    )
    proto = Topology(rods=rods, springs=(), name="icosahedron")
    nodes = node_positions(proto, pose_p, pose_q)
    dist = np.linalg.norm(nodes[:, None] - nodes[None], axis=-1)
    pairs = [(i, j) for i in range(12) for j in range(i + 1, 12) if abs(dist[i, j] - l0) < 1e-9]
    assert len(pairs) == 24, f"icosahedron geometry gave {len(pairs)} springs"
    springs = tuple(Spring(f"spring{k}", i, j) for k, (i, j) in enumerate(pairs))
    topology = Topology(rods=rods, springs=springs, name="icosahedron")

    rng = np.random.default_rng(seed)
    masses = _vary(rng, mass, spread / 2, 6)
    params = Params.create(
        stiffness=_vary(rng, stiffness, spread, 24),
        damping=_vary(rng, damping, spread, 24),
        rest_length=np.full(24, l0),
        mass=masses,
        inertia=cylinder_inertia(masses, L, radius),
        control_gain=control_gain,
        gravity=GRAVITY,
    )
    return Assembly(topology, params, pose_p, pose_q)


def element(
    stiffness: float = 100.0,
    damping: float = 1.0,
    mass: float = 2.0,
    control_gain: float = 2.5,
    length: float = 1.0,
    radius: float = 0.016,
    hang: float = 0.5,
    spread: float = 0.2,
    seed: int = 0,
) -> Assembly:
    """The paper's basic element: one rod held by two springs (Fig. 1, left).

    The rod lies along world x at the origin; each end cap hangs from a world anchor
    ``hang`` metres above it. Rest lengths are chosen so that the nominal pose is a
    static equilibrium under gravity.
    """
    rods = (Rod(name="rod0", length=length, radius=radius, control_arm=(0.0, 0.0, length / 4)),)
    anchors = ((-length / 2, 0.0, hang), (length / 2, 0.0, hang))
    # rod0 end0 is at -x (rod z axis rotated onto world x), end1 at +x.
    springs = (Spring("spring0", 0, 2), Spring("spring1", 1, 3))
    topology = Topology(rods=rods, springs=springs, anchors=anchors, name="element")
    rng = np.random.default_rng(seed)
    K = _vary(rng, stiffness, spread, 2)
    m = np.array([mass])
    # each spring carries the weight share of its end: K_i (hang - l0_i) = m g / 2
    rest = hang - m[0] * abs(GRAVITY[2]) / (2 * K)
    params = Params.create(
        stiffness=K,
        damping=_vary(rng, damping, spread, 2),
        rest_length=rest,
        mass=m,
        inertia=cylinder_inertia(m, length, radius),
        control_gain=control_gain,
        gravity=GRAVITY,
    )
    pose_q = axis_angle_to_quat([0, 1, 0], np.pi / 2)[None]
    return Assembly(topology, params, np.zeros((1, 3)), pose_q)


ASSEMBLIES: dict[str, Callable[[], Assembly]] = {"icosahedron": icosahedron, "element": element}
