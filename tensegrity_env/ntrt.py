"""Read a robot described as an NTRT YAML model (the NASA Tensegrity Robotics Toolkit's
YAML model builder) into rods, springs and nominal parameters.

What is read, with NTRT's meaning:

* ``nodes``: ``<tags>: [x, y, z]`` in NTRT's length unit (``length_unit`` metres; NTRT
  models are usually built in decimetres, with gravity 98.1 dm/s^2), y up. A node's key
  is a space-separated list of tags; a pair names a node by any tag that no other node
  carries, a substructure's node as ``<child>.<tag>``.
* ``pair_groups``: ``<tags>: [[node, node], ...]``; a pair is built by the builder whose
  key's tags it all carries.
* ``builders``: ``tgRodInfo`` (``radius``, ``density``, ``friction``, ...): a solid
  cylinder between its two nodes, mass ``density * pi r^2 L``. Rods that share a node
  are one rigid body (NTRT builds them as one compound): its mass, centre of mass and
  principal inertia are the sum of its cylinders' (and of the spheres at its nodes).
  Its end caps are the two nodes of its heaviest cylinder; springs attached at its
  other nodes attach to attachment points. ``tgSphereInfo``: a solid sphere at every
  node carrying the builder's tag, its mass added to the rod through that node; a
  sphere at an end cap larger than the rod's radius is that end cap's contact radius
  against a floor (:attr:`~tensegrity_env.topology.Rod.cap_radius`). The contact is
  at the end caps: rods beyond them (NTRT's ``extensions``) add their mass only.
  ``tgBasicActuatorInfo``: a tension-only cable (NTRT's cables push nothing), stiffness
  ``stiffness``, damping ``damping``, rest length the built length minus
  ``pretension / stiffness``. A cable whose builder tag starts with ``activ`` or
  ``actuat`` is driven by a motor in NTRT (a controller sets its rest length): it
  becomes a spring with a cable actuator.
* ``substructures``: ``<child>: {path, rotation: {axis, angle [deg], reference},
  translation}``: the child model rotated about ``reference`` (default: the centroid of
  its nodes), then translated, as NTRT applies them; builders of every file apply to
  all pairs, a parent's replacing a child's of the same key.

The world frame is turned z-up (NTRT is y-up), lengths are converted to metres.
Gravity is the project's, ``(0, 0, -9.81)`` m/s^2. What NTRT sets beyond that (a
cable's ``max_tension``, rolling friction, restitution) is not modelled and not read.
Anything else (boxes, kinematic actuators, bond groups, scale, offset) is refused in
one line naming the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import yaml

from tensegrity_env.assemblies import cylinder_inertia
from tensegrity_env.effects import GroundContact, SlackSprings
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params
from tensegrity_env.rotations import TO_Z_UP, axis_angle_to_quat, np_quat_to_matrix
from tensegrity_env.topology import Rod, Spring, Topology, TopologyError

#: NTRT's documented 3-prism in its YAML model format (decimetres, y up): an example model
EXAMPLE_PRISM = """\
builders:
  rod: {class: tgRodInfo, parameters: {density: 0.5, radius: 0.1}}
  string: {class: tgBasicActuatorInfo, parameters: {stiffness: 100, damping: 3, pretension: 50}}
nodes:
  bottom1: [-5, 0, 0]
  bottom2: [5, 0, 0]
  bottom3: [0, 0, 8.66]
  top1: [-5, 5, 0]
  top2: [5, 5, 0]
  top3: [0, 5, 8.66]
pair_groups:
  rod: [[bottom1, top2], [bottom2, top3], [bottom3, top1]]
  string: [[bottom1, bottom2], [bottom2, bottom3], [bottom1, bottom3], [top1, top2], [top2, top3],
           [top1, top3], [bottom1, top1], [bottom2, top2], [bottom3, top3]]
"""
#: metres per NTRT length unit by default: NTRT's models (and the ETH jumping robot's)
#: are built in decimetres
DECIMETRE = 0.1
#: the builder classes read (NTRT's class names)
ROD, CABLE, SPHERE = "tgRodInfo", "tgBasicActuatorInfo", "tgSphereInfo"
#: tag prefixes of cables a motor drives
ACTUATED = ("activ", "actuat")
#: keys of a substructure entry that are read
CHILD_KEYS = {"path", "rotation", "translation"}


@dataclass(frozen=True)
class NtrtRobot:
    """What :func:`from_ntrt` reads.

    Attributes:
        topology: rods (end caps at the nodes of each rigid body's heaviest rod),
            springs (every cable), cable actuators (the motor-driven cables).
        params: the model's nominal parameters [SI]: stiffness, damping, rest lengths,
            each rigid body's mass and principal inertia, gravity (0, 0, -9.81).
        rest_caps: (2R, 3) the end caps as the model builds them [m], z up.
        rest_p: (R, 3) each rod's centre of mass in that pose [m].
        rest_q: (R, 4) each rod's principal frame in that pose, a unit quaternion
            (w, x, y, z) taking it to the world.
        friction: the rods' friction coefficient (the first rod builder's).
        source: the top-level file.
    """

    topology: Topology
    params: Params
    rest_caps: np.ndarray
    rest_p: np.ndarray
    rest_q: np.ndarray
    friction: float
    source: Path

    def declared_effects(self, ground: bool = True) -> list[PhysicalEffect]:
        """What the model declares beyond linear springs: every cable tension-only, and
        (``ground``) a floor at height 0 with the rods' friction (NTRT models run on a
        ground its applications add)."""
        effects: list[PhysicalEffect] = []
        if ground:
            effects.append(GroundContact(self.topology, height=0.0, friction=self.friction))
        effects.append(SlackSprings(self.topology, springs=list(range(self.topology.n_springs))))
        return effects


@dataclass
class _Structure:
    """Nodes and pairs of one file with its substructures, in NTRT units."""

    pos: list[np.ndarray]
    tags: list[set[str]]
    pairs: list[tuple[int, int, set[str]]]
    builders: dict[str, dict[str, Any]]


def _load(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise InputError(f"{path}: no such NTRT YAML file")
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise InputError(f"{path}: not valid YAML{where}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read it ({e})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: an NTRT model is a mapping with nodes, pair_groups, builders")
    extra = sorted(set(doc) - {"nodes", "pair_groups", "builders", "substructures"})
    if extra:
        raise InputError(f"{path}: section {extra[0]!r} is not read (nodes, pair_groups, builders, "
                         "substructures are)")  # fmt: skip
    return doc


def _vector(path: Path, where: str, value: Any) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{path}: {where}: {value!r} is not three numbers") from None
    if v.shape != (3,) or not np.isfinite(v).all():
        raise InputError(f"{path}: {where}: {value!r} is not three finite numbers")
    return v


def _find(path: Path, s: _Structure, name: str, where: str, children: dict[str, range]) -> int:
    """The node a pair names: ``<tag>`` or ``<child>.<tag>``, carried by exactly one node."""
    scope: range | None = None
    tag = name
    if "." in name:
        child, tag = name.rsplit(".", 1)
        scope = children.get(child)
        if scope is None:
            raise InputError(f"{path}: {where}: no substructure {child!r} (has {sorted(children)})")
    hits = [i for i in (scope if scope is not None else range(len(s.pos))) if tag in s.tags[i]]
    if not hits:
        raise InputError(f"{path}: {where}: no node {name!r}")
    if len(hits) > 1:
        raise InputError(f"{path}: {where}: {len(hits)} nodes carry the tag {name!r}")
    return hits[0]


def _structure(path: Path, seen: tuple[Path, ...] = ()) -> _Structure:
    """One file's nodes and pairs, its substructures placed, in NTRT units."""
    if path.resolve() in seen:
        raise InputError(f"{path}: includes itself through its substructures")
    doc = _load(path)
    s = _Structure([], [], [], {})
    children: dict[str, range] = {}
    for name, entry in (doc.get("substructures") or {}).items():
        where = f"substructure {name!r}"
        if not isinstance(entry, dict) or "path" not in entry:
            raise InputError(f"{path}: {where} needs a 'path'")
        extra = sorted(set(entry) - CHILD_KEYS)
        if extra or "/" in str(name):
            what = f"'{extra[0]}'" if extra else "several children in one key"
            raise InputError(f"{path}: {where}: {what} is not read (path, rotation, translation are)")
        child = _structure((path.parent / str(entry["path"])), (*seen, path.resolve()))
        pos = np.array(child.pos)
        rotation = entry.get("rotation")
        if rotation:
            if not isinstance(rotation, dict) or "axis" not in rotation or "angle" not in rotation:
                raise InputError(f"{path}: {where}: rotation needs 'axis' and 'angle' [deg]")
            axis = _vector(path, f"{where} rotation axis", rotation["axis"])
            if not np.linalg.norm(axis) > 0:
                raise InputError(f"{path}: {where}: rotation axis is zero")
            try:
                angle = np.deg2rad(float(rotation["angle"]))
            except (TypeError, ValueError):
                raise InputError(f"{path}: {where}: rotation angle {rotation['angle']!r} is not a number") from None
            ref = rotation.get("reference")
            centre = pos.mean(0) if ref is None else _vector(path, f"{where} rotation reference", ref)
            rot = np_quat_to_matrix(axis_angle_to_quat(axis, angle))
            pos = (pos - centre) @ rot.T + centre
        if entry.get("translation") is not None:
            pos = pos + _vector(path, f"{where} translation", entry["translation"])
        base = len(s.pos)
        s.pos += list(pos)
        s.tags += child.tags
        s.pairs += [(a + base, b + base, t) for a, b, t in child.pairs]
        s.builders.update(child.builders)
        children[str(name)] = range(base, len(s.pos))
    for key, xyz in (doc.get("nodes") or {}).items():
        s.pos.append(_vector(path, f"node {key!r}", xyz))
        s.tags.append(set(str(key).split()))
    for key, pairs in (doc.get("pair_groups") or {}).items():
        if not isinstance(pairs, list):
            raise InputError(f"{path}: pair group {key!r} is not a list of node pairs")
        for k, pair in enumerate(pairs):
            where = f"pair group {key!r}, pair {k + 1}"
            if not isinstance(pair, list) or len(pair) != 2:
                raise InputError(f"{path}: {where}: {pair!r} is not two node names")
            a, b = (_find(path, s, str(n), where, children) for n in pair)
            s.pairs.append((a, b, set(str(key).split())))
    for key, builder in (doc.get("builders") or {}).items():
        if not isinstance(builder, dict) or "class" not in builder:
            raise InputError(f"{path}: builder {key!r} needs a 'class'")
        if builder["class"] not in (ROD, CABLE, SPHERE):
            raise InputError(f"{path}: builder {key!r}: class {builder['class']!r} is not read "
                             f"({ROD}, {CABLE}, {SPHERE} are)")  # fmt: skip
        s.builders[str(key)] = {"class": builder["class"], "source": path,
                                "parameters": dict(builder.get("parameters") or {})}  # fmt: skip
    return s


def _parameter(b: dict[str, Any], key: str, name: str, default: float | None = None) -> float:
    value = b["parameters"].get(name, default)
    if value is None:
        raise InputError(f"{b['source']}: builder {key!r} ({b['class']}) needs '{name}'")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{b['source']}: builder {key!r}: {name} {value!r} is not a number") from None
    if not np.isfinite(v) or v < 0:
        raise InputError(f"{b['source']}: builder {key!r}: {name} {v:g} must be a finite number >= 0")
    return v


def _builder(path: Path, s: _Structure, tags: set[str], what: str) -> tuple[str, dict[str, Any]] | None:
    hits = [(k, b) for k, b in s.builders.items() if set(k.split()) <= tags]
    if len(hits) > 1:
        raise InputError(f"{path}: {what} matches builders {sorted(k for k, _ in hits)}: one expected")
    return hits[0] if hits else None


def from_ntrt(source: str | Path, length_unit: float = DECIMETRE) -> NtrtRobot:
    """Read an NTRT YAML model (``length_unit``: metres per model length unit).

    Raises :class:`InputError` with one line naming the file and the problem.
    """
    path = Path(source)
    s = _structure(path)
    up = TO_Z_UP["y"]
    pos = np.array(s.pos) @ up.T * length_unit  # (N, 3) [m], z up
    pieces: list[tuple[int, int, float, float]] = []  # node a, node b, mass [kg], radius [m]
    cables: list[tuple[int, int, str, dict[str, Any]]] = []
    friction: list[float] = []
    for a, b, tags in s.pairs:
        what = f"pair {sorted(s.tags[a])[0]}-{sorted(s.tags[b])[0]} ({' '.join(sorted(tags))})"
        hit = _builder(path, s, tags, what)
        if hit is None:
            raise InputError(f"{path}: {what}: no builder matches its tags")
        key, b_ = hit
        if b_["class"] == ROD:
            r = _parameter(b_, key, "radius") * length_unit
            rho = _parameter(b_, key, "density") / length_unit**3
            length = float(np.linalg.norm(pos[b] - pos[a]))
            if not length > 0:
                raise InputError(f"{path}: {what}: a rod of zero length")
            pieces.append((a, b, rho * np.pi * r**2 * length, r))
            friction.append(_parameter(b_, key, "friction", 1.0))
        elif b_["class"] == CABLE:
            cables.append((a, b, key, b_))
        else:
            raise InputError(f"{path}: {what}: builder {key!r} is a {SPHERE}, which goes on nodes")
    if not pieces:
        raise InputError(f"{path}: no rods (pairs built by a {ROD} builder)")
    # rigid bodies: rods joined by shared nodes
    group = list(range(len(pos)))

    def root(i: int) -> int:
        while group[i] != i:
            group[i] = group[group[i]]
            i = group[i]
        return i

    for a, b, _, _ in pieces:
        group[root(a)] = root(b)
    on_rod = {n for a, b, _, _ in pieces for n in (a, b)}
    bodies = sorted({root(a) for a, _, _, _ in pieces}, key=lambda g: min(a for a, _, _, _ in pieces if root(a) == g))
    spheres: list[tuple[int, float]] = []  # node, mass [kg]
    sphere_radius: dict[int, float] = {}  # node -> the largest sphere's radius there [m]
    for key, b_ in s.builders.items():
        if b_["class"] != SPHERE:
            continue
        r = _parameter(b_, key, "radius") * length_unit
        rho = _parameter(b_, key, "density") / length_unit**3
        for n, tags in enumerate(s.tags):
            if set(key.split()) <= tags:
                if n not in on_rod:
                    raise InputError(f"{path}: sphere {key!r} at node {sorted(tags)} is on no rod")
                spheres.append((n, rho * 4.0 / 3.0 * np.pi * r**3))
                sphere_radius[n] = max(r, sphere_radius.get(n, 0.0))
    tied = {n for a, b, _, _ in cables for n in (a, b)}  # nodes cables attach to
    rods, masses, inertias, caps, points, poses = [], [], [], [], [], []
    for k, g in enumerate(bodies):
        mine = [p for p in pieces if root(p[0]) == g]
        main = max(mine, key=lambda p: p[2])
        centres = [(pos[a] + pos[b]) / 2 for a, b, _, _ in mine]
        mass = sum(m for *_, m, _ in mine) + sum(m for n, m in spheres if root(n) == g)
        com = (sum(m * c for (_, _, m, _), c in zip(mine, centres, strict=True))
               + sum(m * pos[n] for n, m in spheres if root(n) == g)) / mass  # fmt: skip
        tensor = np.zeros((3, 3))
        for (a, b, m, r), c in zip(mine, centres, strict=True):
            axis = (pos[b] - pos[a]) / np.linalg.norm(pos[b] - pos[a])
            perp, _, along = cylinder_inertia(np.array([m]), float(np.linalg.norm(pos[b] - pos[a])), r)[0]
            d = c - com
            tensor += perp * np.eye(3) + (along - perp) * np.outer(axis, axis)
            tensor += m * (d @ d * np.eye(3) - np.outer(d, d))
        for n, m in spheres:
            if root(n) == g:
                d = pos[n] - com
                tensor += m * (d @ d * np.eye(3) - np.outer(d, d))
        inertia, frame = np.linalg.eigh(tensor)  # principal frame: columns, world coordinates
        if np.linalg.det(frame) < 0:
            frame[:, 2] *= -1.0  # a right-handed frame (a rotation)
        if not (mass > 0 and inertia.min() > 0):
            raise InputError(f"{path}: rod through node {sorted(s.tags[main[0]])[0]} has no mass or inertia "
                             "(density 0)")  # fmt: skip
        ends = (frame.T @ (pos[main[0]] - com), frame.T @ (pos[main[1]] - com))
        others = [n for n in range(len(pos)) if root(n) == g and n not in main[:2] and n in on_rod and n in tied]
        points.append({n: i for i, n in enumerate(others)})
        cap_r = tuple(max(main[3], sphere_radius.get(n, 0.0)) for n in main[:2])
        rods.append(Rod(
            name=f"rod{k}",
            length=float(np.linalg.norm(pos[main[1]] - pos[main[0]])),
            radius=main[3],
            end_offsets=(tuple(ends[0].tolist()), tuple(ends[1].tolist())),
            end_cap="capsule",
            attachments=tuple(tuple((frame.T @ (pos[n] - com)).tolist()) for n in others),
            cap_radius=cap_r if max(cap_r) > main[3] else None,  # type: ignore[arg-type]  # two radii
            axial_gyration=float(inertia[int(np.argmax(np.abs(ends[1] - ends[0])))] / mass),
        ))  # fmt: skip
        masses.append(mass)
        inertias.append(inertia)
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, frame.flatten())  # row-major 3x3
        poses.append((com, q))
        caps.append((main[0], main[1]))
    node_of: dict[int, int] = {}
    for k, (a, b) in enumerate(caps):
        node_of[a], node_of[b] = 2 * k, 2 * k + 1
    n_point = 2 * len(rods)
    for pts in points:
        for n in pts:
            node_of[n] = n_point
            n_point += 1
    springs, stiffness, damping, rest, actuated = [], [], [], [], []
    for i, (a, b, key, b_) in enumerate(cables):
        for n in (a, b):
            if n not in node_of:
                raise InputError(f"{path}: cable {key!r} ends at node {sorted(s.tags[n])}, which is on no rod")
        k_ = _parameter(b_, key, "stiffness")
        if not k_ > 0:
            raise InputError(f"{b_['source']}: builder {key!r}: stiffness must be > 0")
        length = float(np.linalg.norm(pos[b] - pos[a])) / length_unit
        l0 = (length - _parameter(b_, key, "pretension", 0.0) / k_) * length_unit
        if not l0 > 0:
            raise InputError(f"{b_['source']}: builder {key!r}: pretension leaves cable {i} a rest length "
                             f"{l0:.4g} m <= 0")  # fmt: skip
        springs.append(Spring(f"{key.split()[0]}{i}", node_of[a], node_of[b]))
        stiffness.append(k_)
        damping.append(_parameter(b_, key, "damping", 0.0))
        rest.append(l0)
        if key.split()[0].lower().startswith(ACTUATED):
            actuated.append(i)
    try:
        topology = Topology(rods=tuple(rods), springs=tuple(springs), name=path.stem,
                            cable_actuators=tuple(actuated))  # fmt: skip
    except TopologyError as e:
        raise InputError(f"{path}: {e}") from None
    params = Params.create(stiffness=stiffness, damping=damping, rest_length=rest, mass=masses,
                           inertia=np.array(inertias), gravity=(0.0, 0.0, -9.81),
                           cable_gain=[1.0] * len(actuated))  # fmt: skip
    rest_caps = np.array([pos[n] for pair in caps for n in pair])
    rest_p = np.array([p for p, _ in poses])
    rest_q = np.array([q for _, q in poses])
    return NtrtRobot(topology, params, rest_caps, rest_p, rest_q, friction[0], path)
