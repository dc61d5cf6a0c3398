"""The system topology graph of a spring-rod assembly (the paper's Fig. 3).

A :class:`Topology` is the fixed description of an assembly, never differentiated:

* **rods** are rigid bodies. Each has a length, a radius, two end nodes (end caps)
  given as offsets in the rod's principal (inertial) frame, and a control arm ``r_u``:
  the point, in the same frame, where a control force ``f_u`` acts.
* **nodes** are points springs attach to: a rod's end cap, a fixed world anchor (for
  the paper's one-rod element, whose springs are tied to the world), or an
  **attachment point** anywhere on a rod (``Rod.attachments``: a cable tied to a
  sphere's surface or a motor partway along the rod). The two end caps of a rod are
  the points motion capture tracks; springs may use any node.
* **springs** connect two nodes. Tension acts along the line between them.
* **cable actuators** (``Topology.cable_actuators``) each drive one spring: a command
  ``u`` changes that spring's tension by ``-h_c u`` (MuJoCo's tendon actuator, whose
  force ``h_c u`` acts to lengthen the tendon), with ``h_c`` the actuator's gain
  (``Params.cable_gain``).
* **winches** (``Topology.winches``) each wind one spring: a motor command ``u`` in
  [-1, 1] changes that spring's rest length at ``u * v_max`` [m/s], within its range
  ``[l_min, l_max]``, optionally through a first-order motor lag (``Params.winch_*``;
  :mod:`tensegrity_env.engine.winch`). The rest length is then part of the state.

The graph has one vertex per rod and per spring and directed edges
``rod -> spring`` (the rod's end-cap motion feeds the spring's compression
``Δp^m`` and velocity ``Δv^m``) and ``spring -> rod`` (the spring's force acts on
the rod), exactly as in the paper.

Node numbering is global: the ``2 * n_rods`` rod end caps first (rod ``r`` owns nodes
``2r`` and ``2r + 1``), then the world anchors in order, then every rod's attachment
points, rod by rod (:meth:`Topology.point_node`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

Vec3 = tuple[float, float, float]


class TopologyError(ValueError):
    """An assembly description that cannot be a valid spring-rod system."""


@dataclass(frozen=True)
class Rod:
    """A rigid rod.

    Attributes:
        name: unique name (MJCF body name).
        length: distance between the two end caps [m].
        radius: radius of the rod's capsule, used for rendering and contact [m].
        end_offsets: the two end caps in the rod's principal frame [m], shape (2, 3).
        control_arm: where control force ``f_u`` acts, in the rod's principal frame [m].
        frame_origin: the origin of the rod's MuJoCo body frame, in the rod's principal
            frame [m]: the point whose velocity MuJoCo's free joint integrates. It changes
            no force, only the integration step (zero when the body frame is at the
            centre of mass).
        end_cap: the end caps' shape against a floor, ``"capsule"`` (the ends of a
            capsule) or ``"sphere"`` (spheres centred on them); it sets MuJoCo's
            contact frame (see :mod:`tensegrity_env.effects.ground_contact`).
        attachments: more points springs attach to, in the rod's principal frame [m],
            each (x, y, z); not tracked by motion capture.
        cap_radius: each end cap's contact radius against a floor [m], (end 0, end 1),
            where the robot file gives the caps their own size (a sphere at each end);
            None: both are ``radius``.
        axial_gyration: the rod's moment of inertia about its end-cap axis per unit
            mass [m^2], as the robot file's mass distribution gives it (end caps cannot
            show it: it is the value fits hold); None: a solid rod's ``radius^2 / 2``.
    """

    name: str
    length: float
    radius: float = 0.016
    end_offsets: tuple[Vec3, Vec3] | None = None
    control_arm: Vec3 = (0.0, 0.0, 0.0)
    frame_origin: Vec3 = (0.0, 0.0, 0.0)
    end_cap: str = "capsule"
    attachments: tuple[Vec3, ...] = ()
    cap_radius: tuple[float, float] | None = None
    axial_gyration: float | None = None

    def ends(self) -> np.ndarray:
        """End-cap offsets in the rod frame, shape (2, 3) [m]; default ±length/2 along z."""
        if self.end_offsets is None:
            h = 0.5 * self.length
            return np.array([[0.0, 0.0, -h], [0.0, 0.0, h]])
        return np.asarray(self.end_offsets, dtype=float)


@dataclass(frozen=True)
class Spring:
    """A spring (cable) between two nodes, by global node index (see module doc)."""

    name: str
    node_a: int
    node_b: int


@dataclass(frozen=True)
class Topology:
    """Rods, world anchors and springs of one assembly. Validated on construction.

    Attributes:
        rods: the rigid rods, in state order.
        springs: the springs, in parameter order.
        anchors: fixed world points springs may attach to [m], each (x, y, z).
        name: a label for the assembly (MJCF model name).
        cable_actuators: the spring each cable actuator drives, by spring index, in
            actuator order (at most one actuator per spring).
        winches: the spring each winch winds, by spring index, in motor order (at most
            one winch per spring, none on a spring a cable actuator drives).
    """

    rods: tuple[Rod, ...]
    springs: tuple[Spring, ...]
    anchors: tuple[Vec3, ...] = ()
    name: str = "assembly"
    cable_actuators: tuple[int, ...] = ()
    winches: tuple[int, ...] = ()
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "rods", tuple(self.rods))
        object.__setattr__(self, "springs", tuple(self.springs))
        object.__setattr__(self, "anchors", tuple(tuple(map(float, a)) for a in self.anchors))
        object.__setattr__(self, "cable_actuators", tuple(int(c) for c in self.cable_actuators))
        object.__setattr__(self, "winches", tuple(int(w) for w in self.winches))
        self._validate()

    # ------------------------------------------------------------------ validation
    def _validate(self) -> None:
        if not self.rods:
            raise TopologyError(f"{self.name}: an assembly needs at least one rod")
        names = [r.name for r in self.rods] + [s.name for s in self.springs]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise TopologyError(f"{self.name}: duplicate names {dup}")
        for rod in self.rods:
            if not np.isfinite(rod.length) or rod.length <= 0:
                raise TopologyError(f"rod '{rod.name}': length must be positive, got {rod.length}")
            if not np.isfinite(rod.radius) or rod.radius < 0:
                raise TopologyError(f"rod '{rod.name}': radius must be >= 0, got {rod.radius}")
            if rod.cap_radius is not None and (
                len(rod.cap_radius) != 2 or not all(np.isfinite(c) and c >= 0 for c in rod.cap_radius)
            ):
                raise TopologyError(f"rod '{rod.name}': cap_radius must be two radii >= 0, got {rod.cap_radius}")
            if rod.axial_gyration is not None and not (np.isfinite(rod.axial_gyration) and rod.axial_gyration > 0):
                raise TopologyError(f"rod '{rod.name}': axial_gyration must be > 0, got {rod.axial_gyration}")
            ends = rod.ends()
            if ends.shape != (2, 3) or not np.all(np.isfinite(ends)):
                raise TopologyError(f"rod '{rod.name}': end_offsets must be two finite 3-vectors")
            if len(rod.control_arm) != 3 or not np.all(np.isfinite(rod.control_arm)):
                raise TopologyError(f"rod '{rod.name}': control_arm must be a finite 3-vector")
            if rod.end_cap not in ("capsule", "sphere"):
                raise TopologyError(
                    f"rod '{rod.name}': end_cap must be 'capsule' or 'sphere', got {rod.end_cap!r}"
                )
            if len(rod.frame_origin) != 3 or not np.all(np.isfinite(rod.frame_origin)):
                raise TopologyError(f"rod '{rod.name}': frame_origin must be a finite 3-vector")
            for a in rod.attachments:
                if len(a) != 3 or not np.all(np.isfinite(a)):
                    raise TopologyError(
                        f"rod '{rod.name}': attachment point {a} is not a finite 3-vector"
                    )
        for a in self.anchors:
            if len(a) != 3 or not np.all(np.isfinite(a)):
                raise TopologyError(f"{self.name}: anchor {a} is not a finite 3-vector")
        n = self.n_nodes
        for s in self.springs:
            for end in (s.node_a, s.node_b):
                if not (0 <= end < n):
                    raise TopologyError(
                        f"spring '{s.name}': node {end} does not exist "
                        f"(assembly has nodes 0..{n - 1})"
                    )
            if s.node_a == s.node_b:
                raise TopologyError(f"spring '{s.name}': both ends on node {s.node_a}")
            if self.is_anchor(s.node_a) and self.is_anchor(s.node_b):
                raise TopologyError(f"spring '{s.name}': both ends are world anchors")
            if self.node_rod[s.node_a] == self.node_rod[s.node_b] >= 0:
                raise TopologyError(f"spring '{s.name}': both ends on the same rod")
        for c in self.cable_actuators:
            if not 0 <= c < self.n_springs:
                raise TopologyError(
                    f"{self.name}: cable actuator drives spring {c}, which does not exist"
                )
        if len(set(self.cable_actuators)) != len(self.cable_actuators):
            raise TopologyError(f"{self.name}: two cable actuators drive the same spring")
        for w in self.winches:
            if not 0 <= w < self.n_springs:
                raise TopologyError(f"{self.name}: winch winds spring {w}, which does not exist")
        if len(set(self.winches)) != len(self.winches):
            raise TopologyError(f"{self.name}: two winches wind the same spring")
        both = sorted(set(self.winches) & set(self.cable_actuators))
        if both:
            raise TopologyError(
                f"{self.name}: spring(s) {[self.springs[s].name for s in both]} have both a"
                " winch and a cable actuator"
            )

    # ------------------------------------------------------------------ sizes
    @property
    def n_rods(self) -> int:
        return len(self.rods)

    @property
    def n_springs(self) -> int:
        return len(self.springs)

    @property
    def n_cables(self) -> int:
        """Cable actuators (control inputs that scale a spring's tension)."""
        return len(self.cable_actuators)

    @property
    def n_winches(self) -> int:
        """Winches (motors that wind a spring, changing its rest length)."""
        return len(self.winches)

    @property
    def n_anchors(self) -> int:
        return len(self.anchors)

    @property
    def n_points(self) -> int:
        """Attachment points on rods besides the end caps, all rods together."""
        return sum(len(r.attachments) for r in self.rods)

    @property
    def n_nodes(self) -> int:
        return 2 * self.n_rods + self.n_anchors + self.n_points

    def is_anchor(self, node: int) -> bool:
        return 2 * self.n_rods <= node < 2 * self.n_rods + self.n_anchors

    def point_node(self, rod: int, k: int) -> int:
        """Global node index of attachment point ``k`` of rod ``rod``."""
        if not 0 <= k < len(self.rods[rod].attachments):
            raise IndexError(f"rod '{self.rods[rod].name}' has no attachment point {k}")
        before = sum(len(r.attachments) for r in self.rods[:rod])
        return 2 * self.n_rods + self.n_anchors + before + k

    # ------------------------------------------------------------------ arrays
    @property
    def node_rod(self) -> np.ndarray:
        """Rod owning each node, -1 for world anchors, shape (n_nodes,)."""
        return np.concatenate(
            [
                np.repeat(np.arange(self.n_rods), 2),
                -np.ones(self.n_anchors, dtype=int),
                self.point_rods,
            ]
        )

    @property
    def point_rods(self) -> np.ndarray:
        """Rod owning each attachment point, in node order, shape (n_points,)."""
        return np.array(
            [r for r, rod in enumerate(self.rods) for _ in rod.attachments], dtype=int
        )

    @property
    def point_offsets(self) -> np.ndarray:
        """Attachment points in their rods' principal frames, (n_points, 3) [m]."""
        return np.array(
            [a for rod in self.rods for a in rod.attachments], dtype=float
        ).reshape(-1, 3)

    @property
    def node_offsets(self) -> np.ndarray:
        """Every node's position in its rod's principal frame, world anchors in the
        world frame, shape (n_nodes, 3) [m]."""
        return np.concatenate(
            [self.end_offsets.reshape(-1, 3), self.anchor_positions, self.point_offsets]
        )

    @property
    def end_offsets(self) -> np.ndarray:
        """End-cap offsets in each rod's principal frame, shape (n_rods, 2, 3) [m]."""
        return np.stack([r.ends() for r in self.rods])

    @property
    def control_arms(self) -> np.ndarray:
        """Control-force arm ``r_u`` of each rod in its principal frame, (n_rods, 3) [m]."""
        return np.array([r.control_arm for r in self.rods], dtype=float)

    @property
    def frame_origins(self) -> np.ndarray:
        """Each rod's body-frame origin in its principal frame, (n_rods, 3) [m]."""
        return np.array([r.frame_origin for r in self.rods], dtype=float).reshape(-1, 3)

    @property
    def cap_radii(self) -> np.ndarray:
        """Each end cap's contact radius as the robot file gives it, (n_rods, 2) [m]
        (:attr:`Rod.cap_radius`, else the rod's radius at both ends)."""
        return np.array([r.cap_radius or (r.radius, r.radius) for r in self.rods], dtype=float).reshape(-1, 2)

    @property
    def axial_gyrations(self) -> np.ndarray:
        """Each rod's axial moment of inertia per unit mass, (n_rods,) [m^2]
        (:attr:`Rod.axial_gyration`, else a solid rod's ``radius^2 / 2`` with the radius
        at least 1 mm)."""
        return np.array([r.axial_gyration if r.axial_gyration is not None else max(r.radius, 1e-3) ** 2 / 2
                         for r in self.rods], dtype=float)  # fmt: skip

    @property
    def anchor_positions(self) -> np.ndarray:
        """World anchors, shape (n_anchors, 3) [m]."""
        return np.array(self.anchors, dtype=float).reshape(-1, 3)

    @property
    def spring_nodes(self) -> np.ndarray:
        """Node index at each spring end, shape (n_springs, 2)."""
        return np.array([[s.node_a, s.node_b] for s in self.springs], dtype=int).reshape(-1, 2)

    def off_axis_points(self, atol: float = 1e-9) -> list[str]:
        """Attachment points off the line through their rod's end caps, by node name.

        Placing them needs the rod's twist about that line, which two tracked end caps
        do not give (rod states derived from end caps alone cannot place them).
        """
        out = []
        for r, rod in enumerate(self.rods):
            e = rod.ends()
            axis = (e[1] - e[0]) / np.linalg.norm(e[1] - e[0])
            for k, a in enumerate(rod.attachments):
                rel = np.asarray(a) - e[0]
                if np.linalg.norm(rel - (rel @ axis) * axis) > atol * (1.0 + rod.length):
                    out.append(self.node_name(self.point_node(r, k)))
        return out

    def node_name(self, node: int) -> str:
        if self.is_anchor(node):
            return f"anchor{node - 2 * self.n_rods}"
        if node >= 2 * self.n_rods:
            rod = int(self.node_rod[node])
            return f"{self.rods[rod].name}/point{node - self.point_node(rod, 0)}"
        return f"{self.rods[node // 2].name}/end{node % 2}"

    # ------------------------------------------------------------------ graph
    def edges(self) -> list[tuple[str, str]]:
        """Directed edges of the topology graph: (rod -> spring) and (spring -> rod)."""
        out: list[tuple[str, str]] = []
        for s in self.springs:
            for node in (s.node_a, s.node_b):
                r = self.node_rod[node]
                if r >= 0:
                    out.append((self.rods[r].name, s.name))
                    out.append((s.name, self.rods[r].name))
        return out

    def springs_of_rod(self, rod: int) -> list[int]:
        """Indices of the springs attached to rod ``rod``."""
        nr = self.node_rod
        return [i for i, s in enumerate(self.springs) if rod in (nr[s.node_a], nr[s.node_b])]

    # ------------------------------------------------------------------ (de)serialise
    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "name": self.name,
            "rods": [
                {
                    "name": r.name,
                    "length": r.length,
                    "radius": r.radius,
                    "end_offsets": r.ends().tolist(),
                    "control_arm": list(r.control_arm),
                    "frame_origin": list(r.frame_origin),
                    "end_cap": r.end_cap,
                    "attachments": [list(a) for a in r.attachments],
                    **({} if r.cap_radius is None else {"cap_radius": list(r.cap_radius)}),
                    **({} if r.axial_gyration is None else {"axial_gyration": r.axial_gyration}),
                }
                for r in self.rods
            ],
            "anchors": [list(a) for a in self.anchors],
            "springs": [{"name": s.name, "nodes": [s.node_a, s.node_b]} for s in self.springs],
        }
        if self.cable_actuators:
            out["cable_actuators"] = list(self.cable_actuators)
        if self.winches:
            out["winches"] = list(self.winches)
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Topology:
        try:
            rods = tuple(
                Rod(
                    name=str(r["name"]),
                    length=float(r["length"]),
                    radius=float(r.get("radius", 0.0)),
                    end_offsets=tuple(tuple(map(float, e)) for e in r["end_offsets"]),  # type: ignore[arg-type]  # any length: __post_init__ names a bad one
                    control_arm=tuple(map(float, r.get("control_arm", (0, 0, 0)))),  # type: ignore[arg-type]  # as end_offsets
                    frame_origin=tuple(map(float, r.get("frame_origin", (0, 0, 0)))),  # type: ignore[arg-type]  # as end_offsets
                    end_cap=str(r.get("end_cap", "capsule")),
                    attachments=tuple(tuple(map(float, a)) for a in r.get("attachments", [])),  # type: ignore[misc]  # as end_offsets
                    cap_radius=None if r.get("cap_radius") is None else tuple(map(float, r["cap_radius"])),  # type: ignore[arg-type]  # as end_offsets
                    axial_gyration=None if r.get("axial_gyration") is None else float(r["axial_gyration"]),
                )
                for r in d["rods"]
            )
            springs = tuple(
                Spring(str(s["name"]), int(s["nodes"][0]), int(s["nodes"][1])) for s in d["springs"]
            )
            anchors = tuple(tuple(map(float, a)) for a in d.get("anchors", []))
            name = str(d.get("name", "assembly"))
            cables = tuple(int(c) for c in d.get("cable_actuators", []))
            winches = tuple(int(w) for w in d.get("winches", []))
            return cls(
                rods=rods, springs=springs, anchors=anchors, name=name,  # type: ignore[arg-type]  # anchors: as end_offsets
                cable_actuators=cables, winches=winches,
            )  # fmt: skip
        except TopologyError:
            raise
        except (KeyError, TypeError, IndexError, ValueError, AttributeError, OverflowError) as e:
            raise TopologyError(f"malformed topology description: {e!r}") from None

    def to_json(self) -> str:
        return json.dumps(self.to_dict())

    @classmethod
    def from_json(cls, text: str) -> Topology:
        return cls.from_dict(json.loads(text))

    def same_as(self, other: Topology, atol: float = 1e-12) -> bool:
        """Structural equality up to floating-point tolerance on geometry."""
        if (self.n_rods, self.n_springs, self.n_anchors) != (
            other.n_rods,
            other.n_springs,
            other.n_anchors,
        ) or not np.array_equal(self.point_rods, other.point_rods):
            return False
        if not np.array_equal(self.spring_nodes, other.spring_nodes):
            return False
        if self.cable_actuators != other.cable_actuators or self.winches != other.winches:
            return False
        return all(
            np.allclose(getattr(self, f), getattr(other, f), atol=atol)
            for f in (
                "end_offsets",
                "control_arms",
                "frame_origins",
                "anchor_positions",
                "point_offsets",
                "cap_radii",
            )
        ) and np.allclose([r.length for r in self.rods], [r.length for r in other.rods], atol=atol)
