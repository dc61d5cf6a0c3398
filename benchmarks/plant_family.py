"""Drawn plants: the measured benchmark's icosahedron written in file conventions and
with physics drawn at random from a seed.

A plant written in the code's own conventions cannot find a convention bug. Each draw
(:func:`draw`) chooses, per rod, which end the file lists first (end cap 0), which way
its capsule's ``fromto`` runs, the principal axis (and its direction) the rod lies on,
where the body frame sits (at or off the centre of mass) and how it is turned against
the principal frame, the centre of mass off the middle of the rod; for the structure,
sphere or capsule end caps, the rod length, masses, stiffness, spring damping,
prestress and floor friction; for the measurement, the sample rate, noise and dropouts,
left as NaN gaps. The MJCF is written here; the topology the dataset carries is what
:func:`tensegrity_env.mjcf.reader.from_mjcf` reads from it, as a user's would be.

Stable on a floor: MuJoCo's Euler step at the 1 ms physics step
(:data:`measured_plant.PHYSICS_DT`) needs a contact ``solref`` time constant of at least
twice the step (drawn from :data:`MIN_SOLREF_STEPS` steps up) and a rod whose axial moment
of inertia is not vanishingly small against its perpendicular one: a solid cylinder's
``m r^2 / 2`` (0.06-0.5 % of the perpendicular moment at the drawn radii) let 8 of the
first 8 floor draws diverge within 3 s, as a rod rolling on its thin side spins about its
axis. Rods carry end-cap housings wider than the rod, so the axial moment is drawn
:data:`AXIAL_RATIO` of the perpendicular one. Should a draw still diverge,
:func:`simulate_family` raises, naming it.

Floor trajectories start thrown (rolling along the floor), dropped from rest, or resting
on a face of the structure's hull, one of the three at random per trajectory.

Recorded rod states are those of the principal frame at the centre of mass (the
dataset's convention), whatever the body frame. The initial states are the measured
benchmark's (:func:`measured_plant.initial_states`), scaled to the drawn rod length and
carried into the drawn frames.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from measured_plant import (
    PHYSICS_DT,
    Cell,
    CellData,
    Truth,
    initial_states,
    lift,
    measure,
)
from scipy.spatial import ConvexHull

from identification.data.dataset import Dataset, GroundTruth, Split, write_dataset
from tensegrity_env import assemblies
from tensegrity_env.mjcf.reader import from_mjcf
from tensegrity_env.params import Params
from tensegrity_env.rotations import (
    np_quat_conj,
    np_quat_mul,
    np_quat_to_matrix,
    random_quaternions,
    shortest_arc,
)
from tensegrity_env.topology import Topology

#: sample rates drawn [Hz] (what capture systems export)
FAMILY_RATES = (60.0, 100.0, 120.0, 200.0, 240.0, 500.0, 1000.0)
#: the icosahedron's spring stiffness is drawn at least this many rod weights per rod
#: length (the measured benchmark's plant has 16): softer structures fold on a floor
MIN_STIFFNESS_WEIGHTS = 8.0
#: and at most this many N/m per kg of rod: the fastest rod mode then turns by at most
#: 0.25 rad per 1 ms physics step (Euler stays accurate to the plant's own round-off)
MAX_STIFFNESS_PER_KG = 2000.0
GRAVITY = 9.81
#: the floor contact's solref time constant is drawn at least this many physics steps:
#: MuJoCo's soft contact is stable only above 2 steps, and the draw keeps a margin
MIN_SOLREF_STEPS = 5.0
#: range of a rod's axial moment of inertia over its perpendicular one: end-cap housings
#: wider than the rod (a solid rod's m r^2 / 2 is 0.06-0.5 % and diverges on a floor)
AXIAL_RATIO = (0.01, 0.05)
#: how floor trajectories start (one at random per trajectory)
FLOOR_STARTS = ("thrown", "dropped", "resting")


@dataclass(frozen=True)
class Draw:
    """One drawn plant (see the module docstring); arrays are per rod (R,) or spring (S,).

    Attributes:
        seed: the seed it was drawn from.
        setting: ``floor`` or ``flight`` (as :class:`measured_plant.Cell`).
        rate: sample rate [Hz]; noise: end-cap noise std [m]; dropout: fraction of
            end-cap samples lost, left as NaN.
        length: rod length [m]; radius: rod and end-cap radius [m].
        mass: [kg]; stiffness: [N/m]; damping: spring damping [N s/m].
        prestress: rest length = (1 - prestress) x the nominal spring length.
        friction: floor and end-cap sliding friction.
        solref: the floor contact's MuJoCo ``solref`` (time constant [s], damping ratio).
        solimp: its ``solimp`` (d_min, d_max, width [m]; midpoint 0.5 and power 2).
        end_cap: ``capsule`` (a capsule geom between the end caps) or ``sphere``.
        site_reversed: the file lists the rod's upper-end site first (end cap 0 is the
            nominal cap 1).
        fromto_reversed: the capsule's ``fromto`` runs from the nominal cap 1.
        axis: principal axis (0, 1, 2) the rod lies on; axis_sign: +1 or -1, the
            direction of nominal cap 0 -> cap 1 along it.
        com_shift: the centre of mass this far [m] from the rod's middle towards the
            nominal cap 1.
        frame_origin: the body frame's origin in the principal frame [m], (R, 3).
        frame_turn: the principal frame's orientation in the body frame (w, x, y, z),
            (R, 4).
        axial_ratio: each rod's axial moment of inertia over its perpendicular one, (R,).
    """

    seed: int
    setting: str
    rate: float
    noise: float
    dropout: float
    length: float
    radius: float
    mass: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    prestress: float
    friction: float
    end_cap: str
    site_reversed: np.ndarray
    fromto_reversed: np.ndarray
    axis: np.ndarray
    axis_sign: np.ndarray
    com_shift: np.ndarray
    frame_origin: np.ndarray
    frame_turn: np.ndarray
    solref: tuple[float, float] = (0.02, 1.0)
    solimp: tuple[float, float, float] = (0.9, 0.95, 0.001)
    axial_ratio: np.ndarray = field(default_factory=lambda: np.full(6, AXIAL_RATIO[0]))

    @property
    def cell(self) -> Cell:
        """The measured benchmark's cell of this draw (its splits, durations, physics
        step and measurement), no planted effect."""
        return Cell(self.setting, self.rate, self.noise, self.dropout, "none", self.seed)

    @property
    def label(self) -> str:
        return (f"family{self.seed}/{self.setting}/{self.rate:g}Hz/{self.noise * 1e3:.2g}mm/"
                f"drop{self.dropout * 100:.2g}%")  # fmt: skip

    def summary(self) -> dict[str, Any]:
        """JSON-ready fields."""
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self).items()}


def draw(seed: int, setting: str = "flight", **fixed: Any) -> Draw:
    """A plant drawn from ``seed``; ``fixed`` sets fields instead (e.g. ``rate=120.0``,
    ``site_reversed=np.ones(6, bool)``).

    Ranges: rod length 0.3-2 m, mass 0.05-5 kg per rod (±10 % between rods),
    stiffness 20-5000 N/m (±10 % between springs; bounded by
    :data:`MIN_STIFFNESS_WEIGHTS` and :data:`MAX_STIFFNESS_PER_KG`), damping ratio
    0.5-5 %, prestress 0-60 %, friction 0.5-1.5, floor ``solref`` 5-40 ms and damping
    ratio 0.5-2 (the time constant at least :data:`MIN_SOLREF_STEPS` physics steps),
    ``solimp`` d_min 0.8-0.95, d_max up to 0.99 and width 0.5-5 mm (MuJoCo's
    defaults: 20 ms, 1, 0.9, 0.95, 1 mm), 0.1-2 mm noise, 0-2 % dropouts, rates of
    :data:`FAMILY_RATES`; every convention either way with equal odds; a body frame off
    the centre of mass by up to 20 % of the rod length and turned at random, each in half
    of the rods; the centre of mass up to 15 % of the rod length off its middle; the axial
    moment of inertia :data:`AXIAL_RATIO` of the perpendicular one (log-uniform per rod).
    """
    rng = np.random.default_rng([seed, 64])
    topo = nominal().topology
    R, S = topo.n_rods, topo.n_springs
    log_uniform = lambda lo, hi: float(np.exp(rng.uniform(np.log(lo), np.log(hi))))  # noqa: E731
    length = log_uniform(0.3, 2.0)
    mass = log_uniform(0.05, 5.0) * rng.uniform(0.9, 1.1, R)
    weights = MIN_STIFFNESS_WEIGHTS * float(mass.max()) * GRAVITY / length
    k_lo = max(20.0, weights)
    k_hi = max(k_lo, min(5000.0, MAX_STIFFNESS_PER_KG * float(mass.min())))
    stiffness = log_uniform(k_lo, k_hi) * rng.uniform(0.9, 1.1, S)
    zeta = log_uniform(0.005, 0.05)
    damping = zeta * 2 * np.sqrt(stiffness * float(mass.mean()))
    off = rng.random(R) < 0.5
    turned = rng.random(R) < 0.5
    turn = np.where(turned[:, None], random_quaternions(rng, R), [1.0, 0.0, 0.0, 0.0])
    d = Draw(
        seed=seed, setting=setting, rate=float(rng.choice(FAMILY_RATES)),
        noise=log_uniform(1e-4, 2e-3), dropout=float(rng.uniform(0.0, 0.02)),
        length=length, radius=length * float(rng.uniform(0.01, 0.03)), mass=mass,
        stiffness=stiffness, damping=damping, prestress=float(rng.uniform(0.0, 0.6)),
        friction=float(rng.uniform(0.5, 1.5)),
        end_cap=str(rng.choice(["capsule", "sphere"])),
        site_reversed=rng.random(R) < 0.5, fromto_reversed=rng.random(R) < 0.5,
        axis=rng.integers(0, 3, R), axis_sign=rng.choice([-1.0, 1.0], R),
        com_shift=length * rng.uniform(-0.15, 0.15, R),
        frame_origin=np.where(off[:, None], length * 0.2 * rng.uniform(-1, 1, (R, 3)), 0.0),
        frame_turn=turn,
        solref=(max(log_uniform(0.005, 0.04), MIN_SOLREF_STEPS * PHYSICS_DT),
                log_uniform(0.5, 2.0)),
        solimp=(d_min := float(rng.uniform(0.8, 0.95)), float(rng.uniform(d_min + 0.01, 0.99)),
                log_uniform(5e-4, 5e-3)),
        axial_ratio=np.exp(rng.uniform(*np.log(AXIAL_RATIO), R)),
    )  # fmt: skip
    return replace(d, **fixed)


def principal_caps(d: Draw) -> np.ndarray:
    """The nominal caps 0 and 1 of each rod in its principal frame [m], (R, 2, 3)."""
    u = np.eye(3)[d.axis] * d.axis_sign[:, None]  # nominal cap 0 -> cap 1
    half = d.length / 2
    return np.stack([(-half - d.com_shift)[:, None] * u, (half - d.com_shift)[:, None] * u], 1)


def principal_inertia(d: Draw) -> np.ndarray:
    """Principal inertia (R, 3) [kg m^2]: the perpendicular moments a solid cylinder's
    about its centre of mass, the axial one (on the rod's axis) ``axial_ratio`` of them."""
    perp = d.mass * (d.length**2 / 12 + d.com_shift**2 + d.radius**2 / 4)
    axial = d.axial_ratio * perp
    out = np.repeat(perp[:, None], 3, axis=1)
    out[np.arange(len(d.mass)), d.axis] = axial
    return out


def nominal() -> assemblies.Assembly:
    """The icosahedron the drawn plants scale (nominal rod length, pose, springs)."""
    return assemblies.icosahedron()


def true_params(d: Draw) -> Params:
    """The drawn plant's parameters (inertia in the principal frame of :func:`principal_caps`)."""
    a = nominal()
    scale = d.length / a.topology.rods[0].length
    rest = (1 - d.prestress) * scale * a.params.numpy()["rest_length"]
    return Params.create(stiffness=d.stiffness, damping=d.damping, rest_length=rest,
                         mass=d.mass, inertia=principal_inertia(d), control_gain=1.0,
                         gravity=[0.0, 0.0, -GRAVITY])  # fmt: skip


def site_order(d: Draw, r: int) -> tuple[str, str]:
    """Rod ``r``'s end-cap site names in file order (``_a``: nominal cap 0)."""
    a, b = f"rod{r}_a", f"rod{r}_b"
    return (b, a) if d.site_reversed[r] else (a, b)


def _vec(x: np.ndarray) -> str:
    return " ".join(repr(float(v)) for v in x)


def write_mjcf(d: Draw) -> str:
    """The drawn plant's MJCF text (Euler at the measured benchmark's physics step)."""
    a, params = nominal(), true_params(d)
    cell = d.cell
    dt = 1.0 / d.rate / cell.substeps
    root = ET.Element("mujoco", model=f"icosahedron_family{d.seed}")
    ET.SubElement(root, "option", timestep=repr(dt), integrator="Euler", gravity="0 0 -9.81")
    world = ET.SubElement(root, "worldbody")
    fric = f"{d.friction!r} 0.005 0.0001"
    sol = {"solref": _vec(np.array(d.solref)), "solimp": _vec(np.array([*d.solimp, 0.5, 2.0]))}
    if d.setting == "floor":
        ET.SubElement(world, "geom", name="floor", type="plane", size="0 0 1", contype="1",
                      conaffinity="2", friction=fric, **sol)  # fmt: skip
    caps = principal_caps(d)
    inertia = params.numpy()["inertia"]
    for r in range(a.topology.n_rods):
        rot = np_quat_to_matrix(d.frame_turn[r])  # principal -> body
        com = -rot @ d.frame_origin[r]  # the centre of mass in the body frame
        body_caps = com + caps[r] @ rot.T  # (2, 3) nominal caps 0, 1 in the body frame
        body = ET.SubElement(world, "body", name=f"rod{r}")
        ET.SubElement(body, "joint", name=f"rod{r}_free", type="free")
        ET.SubElement(body, "inertial", pos=_vec(com), quat=_vec(d.frame_turn[r]),
                      mass=repr(float(d.mass[r])), diaginertia=_vec(inertia[r]))  # fmt: skip
        geom = {"contype": "2", "conaffinity": "1", "friction": fric, "mass": "0", **sol}
        if d.end_cap == "capsule":
            ends = body_caps[::-1] if d.fromto_reversed[r] else body_caps
            ET.SubElement(body, "geom", type="capsule", size=repr(d.radius),
                          fromto=_vec(ends.ravel()), **geom)  # fmt: skip
        else:
            for k in (0, 1):
                ET.SubElement(body, "geom", type="sphere", size=repr(d.radius),
                              pos=_vec(body_caps[k]), **geom)  # fmt: skip
        names = {f"rod{r}_a": body_caps[0], f"rod{r}_b": body_caps[1]}
        for name in site_order(d, r):
            ET.SubElement(body, "site", name=name, pos=_vec(names[name]))
    tendon = ET.SubElement(root, "tendon")
    p = params.numpy()
    for s, sp in enumerate(a.topology.springs):
        t = ET.SubElement(tendon, "spatial", name=sp.name, stiffness=repr(float(p["stiffness"][s])),
                          damping=repr(float(p["damping"][s])),
                          springlength=repr(float(p["rest_length"][s])))  # fmt: skip
        for node in (sp.node_a, sp.node_b):
            ET.SubElement(t, "site", site=f"rod{node // 2}_{'ab'[node % 2]}")
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def truth_of(d: Draw) -> tuple[Truth, Topology]:
    """The true model (parameters, MJCF, floor) and the topology a user reads from the MJCF."""
    xml = write_mjcf(d)
    read = from_mjcf(f"family{d.seed}.xml", xml=xml)
    topology = read.topology
    effects: list[dict[str, Any]] = []
    if d.setting == "floor":  # MuJoCo's solref and solimp as the contact model's parameters
        effects.append({"name": "ground_contact", "params": {**read.contact, "height": 0.0}})
    cell = d.cell
    sim = {"plant": "family", "draw": d.summary(), "timestep": 1.0 / d.rate / cell.substeps,
           "integrator": "Euler", "substeps": cell.substeps, "floor": d.setting == "floor"}  # fmt: skip
    return Truth(true_params(d), xml, effects, sim), topology


def family_initial_states(d: Draw, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` initial states of the measured benchmark (:func:`measured_plant.initial_states`)
    in the drawn plant: scaled to its rod length, each rod's centre of mass and principal
    frame where the draw puts them. p, v, omega (n, R, 3) [m, m/s, rad/s], q (n, R, 4)."""
    a = nominal()
    st = initial_states(d.cell, n, rng)
    scale = d.length / a.topology.rods[0].length
    centre = st["p"].mean(axis=1, keepdims=True)
    p = centre + scale * (st["p"] - centre)
    v = st["v"].mean(axis=1, keepdims=True) + scale * (st["v"] - st["v"].mean(axis=1, keepdims=True))
    u_world = np_quat_to_matrix(st["q"])[..., 2]  # nominal cap 0 -> cap 1
    shift = d.com_shift[None, :, None] * u_world
    p = p + shift
    v = v + np.cross(st["omega"], shift)
    u = np.eye(3)[d.axis] * d.axis_sign[:, None]
    align = shortest_arc(u, np.broadcast_to([0.0, 0.0, 1.0], u.shape))  # (R, 4): u onto z
    q = np_quat_mul(st["q"], np.broadcast_to(align, st["q"].shape))
    omega = st["omega"].copy()
    if d.setting == "floor":
        caps = principal_caps(d)
        lift(p, q, rng, 0.02, 0.2, caps, d.radius)
        for i, how in enumerate(rng.choice(FLOOR_STARTS, n)):
            if how == "thrown":
                continue
            v[i], omega[i] = 0.0, 0.0
            if how == "dropped":  # from rest, lowest end cap 0.1-0.5 m up
                lift(p[i : i + 1], q[i : i + 1], rng, 0.1, 0.5, caps, d.radius)
            else:
                p[i], q[i] = face_down(p[i], q[i], caps, rng)
                lift(p[i : i + 1], q[i : i + 1], rng, 0.0, 1e-3, caps, d.radius)
    return {"p": p, "v": v, "q": q, "omega": omega}


def face_down(
    p: np.ndarray, q: np.ndarray, caps: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The pose ``p`` (R, 3) [m], ``q`` (R, 4) turned rigidly about its centre so that a
    face of its end caps' convex hull, drawn at random, faces straight down. ``caps``
    (R, 2, 3) [m]: the end caps in the principal frames."""
    world = p[:, None] + np.einsum("rij,rkj->rki", np_quat_to_matrix(q), caps)
    hull = ConvexHull(world.reshape(-1, 3))
    normal = hull.equations[rng.integers(len(hull.equations)), :3]  # outward, unit
    turn = shortest_arc(normal, np.array([0.0, 0.0, -1.0]))
    centre = p.mean(axis=0)
    rot = np_quat_to_matrix(turn)
    return centre + (p - centre) @ rot.T, np_quat_mul(np.broadcast_to(turn, q.shape), q)


def simulate_family(d: Draw, xml: str, init: dict[str, np.ndarray], duration: float) -> Split:
    """Roll the drawn plant's MuJoCo model from ``init`` (principal-frame states at the
    centres of mass) for ``duration`` [s]; record the same at every sample and the end
    caps in the file's order (the node order the MJCF reader gives)."""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    n, R = init["p"].shape[:2]
    cell = d.cell
    T = round(duration * d.rate)
    out = {k: np.empty((n, T + 1, R, 3)) for k in ("p", "v", "omega")}
    out["q"] = np.empty((n, T + 1, R, 4))
    nodes = np.empty((n, T + 1, 2 * R, 3))
    sites = [model.site(name).id for r in range(R) for name in site_order(d, r)]
    bodies = np.array([model.body(f"rod{r}").id for r in range(R)])
    iquat = model.body_iquat[bodies]

    def record(i: int, t: int) -> None:
        mujoco.mj_kinematics(model, data)
        qvel = data.qvel.reshape(R, 6)
        rot_b = data.xmat[bodies].reshape(R, 3, 3)
        omega = np.einsum("rij,rj->ri", rot_b, qvel[:, 3:])
        out["p"][i, t] = data.xipos[bodies]
        out["q"][i, t] = np_quat_mul(data.xquat[bodies], iquat)
        out["v"][i, t] = qvel[:, :3] + np.cross(omega, data.xipos[bodies] - data.xpos[bodies])
        out["omega"][i, t] = omega
        nodes[i, t] = data.site_xpos[sites]

    for i in range(n):
        mujoco.mj_resetData(model, data)
        q_body = np_quat_mul(init["q"][i], np_quat_conj(iquat))
        arm = np.einsum("rij,rj->ri", np_quat_to_matrix(init["q"][i]), d.frame_origin)
        origin = init["p"][i] + arm
        v_origin = init["v"][i] + np.cross(init["omega"][i], arm)
        w_local = np.einsum("rji,rj->ri", np_quat_to_matrix(q_body), init["omega"][i])
        data.qpos[:] = np.concatenate([origin, q_body], -1).ravel()
        data.qvel[:] = np.concatenate([v_origin, w_local], -1).ravel()
        mujoco.mj_forward(model, data)
        record(i, 0)
        for t in range(1, T + 1):
            mujoco.mj_step(model, data, nstep=cell.substeps)
            if data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number:
                raise RuntimeError(f"{d.label}: MuJoCo diverged in trajectory {i}")
            record(i, t)
    return Split(nodes=nodes, control=np.zeros((n, T, R, 3)), **out)


def write_family_cell(d: Draw, directory: Path, share: float = 1.0) -> CellData:
    """Simulate the drawn plant and write ``measured.h5`` (end caps only, gaps as NaN)
    and ``clean.h5`` (no noise, no gaps, rod states), both with the ground truth.
    ``share``: this fraction of the measured benchmark's trajectories per split (at
    least one each)."""
    directory.mkdir(parents=True, exist_ok=True)
    truth, topology = truth_of(d)
    cell = d.cell
    rng = np.random.default_rng([d.seed, 64, 11])
    clean, seen = {}, {}
    for k, (name, n_all) in enumerate(cell.counts.items()):
        n = max(1, round(share * n_all))
        init = family_initial_states(d, n, np.random.default_rng([d.seed, 64, k, 3]))
        clean[name] = simulate_family(d, truth.xml, init, cell.durations[name])
        nodes = measure(clean[name].nodes, cell, rng, fill=False)
        seen[name] = Split(nodes=nodes, control=clean[name].control.copy())
    attrs = {"assembly": topology.name, "source": f"plant family {d.label}",
             "measurement_noise_std": d.noise, "dropout": d.dropout}  # fmt: skip
    gt = GroundTruth(params=truth.params, sim={**truth.sim, "cell": asdict(cell)},
                     mjcf=truth.xml, effects=truth.effects)  # fmt: skip
    dt = 1.0 / d.rate
    measured = write_dataset(directory / "measured.h5", Dataset(topology, dt, seen, attrs), gt)
    clean_path = write_dataset(directory / "clean.h5", Dataset(topology, dt, clean, attrs), gt)
    (directory / "true.xml").write_text(truth.xml)
    return CellData(measured, clean_path, truth, cell)

