"""Motion-capture-like data of the icosahedron, written by its own MuJoCo script.

This module is deliberately independent of ``tensegrity-sr generate`` and ``plant``:
it writes its own MJCF (geometry and true parameters from
:func:`tensegrity_env.assemblies.icosahedron`), steps MuJoCo itself, and keeps what a
motion-capture system would see: the 12 end caps, sampled at a rate, with Gaussian
noise and dropped markers. Two settings:

* ``floor``: the structure dropped onto a floor with a horizontal throw and a spin,
  tumbling and rolling for 3 s (contact in every trajectory);
* ``flight``: thrown in free flight (no floor) for 0.6 s with random velocities and
  spins; every rod is also perturbed so the springs oscillate.

Effects are planted through MuJoCo features (:data:`PLANTED`); none of them is
declared to the identifier. MuJoCo steps at ``sample interval / n`` with
``n = ceil(sample interval / 1 ms)`` (so 1 ms at 1 kHz, 0.926 ms at 120 Hz), the
Euler integrator, and records every ``n``-th state.

Dropped markers: each end cap loses a fraction of its samples, in runs of 1-5
frames; the writer fills each gap by linear interpolation between the samples on
either side, as a motion-capture pipeline's gap filling would.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from identification.data.dataset import Dataset, GroundTruth, Split, write_dataset
from tensegrity_env import assemblies
from tensegrity_env.params import Params
from tensegrity_env.rotations import np_quat_to_matrix

SETTINGS = ("floor", "flight")
#: the matrix's other axes: sample rates [Hz], end-cap noise std [mm], dropped samples [%]
RATES, NOISES, DROPOUTS = (60.0, 120.0, 240.0, 1000.0), (0.5, 1.0, 2.0), (0.0, 2.0)
#: planted effect -> what MuJoCo feature plants it
PLANTED: dict[str, str] = {
    "none": "nothing (floor cells: the floor only)",
    "linear_drag": "option viscosity 0.5 Pa*s (inertia-box fluid model)",
    "quadratic_drag": "option density 100 kg/m^3 (inertia-box fluid model)",
    "slack_cables": "12 tendons with springlength '0 l0' (tension only), l0 the nominal length",
    "force_field": "xfrc_applied (0.4, -0.3, 0.5) N on every rod",
    "damaged_cable": "one tendon's stiffness at 30 %",
    "joint_damping": "free-joint damping 0.4 (N*s/m and N*m*s), implicit under Euler",
}
#: effect names of the library a correct identification adds for each plant
EXPECTED: dict[str, tuple[str, ...]] = {
    "none": (),
    "linear_drag": ("linear_drag",),
    "quadratic_drag": ("quadratic_drag",),
    "slack_cables": ("slack_springs",),
    "force_field": ("force_field",),
    "damaged_cable": (),
    "joint_damping": ("linear_drag",),
}
VISCOSITY = 0.5
DENSITY = 100.0
FORCE = (0.4, -0.3, 0.5)
N_CABLES = 12
DAMAGE = 0.3
JOINT_DAMPING = 0.4
FRICTION = 1.0
PHYSICS_DT = 1e-3
#: the plant's version, recorded with each cell: 2 records end caps at the same instant
#: as rod states (version 1 recorded them one physics step late)
PLANT_VERSION = 2
#: mean spring stiffness [N/m] and rest length as a fraction of the nominal spring
#: length: a prestressed structure that stands on a face under its own weight
STIFFNESS = 300.0
PRESTRESS = 0.9
#: the slack cables' rest length as a fraction of the nominal spring length: at
#: :data:`PRESTRESS` a cable went slack in at most 0.43 % of the flight cell's training
#: samples (seed 0); at the nominal length in 5-19 %
CABLE_REST = 1.0


@dataclass(frozen=True)
class Cell:
    """One cell of the measured benchmark.

    Attributes:
        setting: ``floor`` or ``flight``.
        rate: sample rate [Hz].
        noise: end-cap noise std [m].
        dropout: fraction of end-cap samples lost (filled by interpolation).
        effect: a key of :data:`PLANTED`.
        seed: seed of the initial states, noise, dropouts and plant choices.
    """

    setting: str
    rate: float
    noise: float
    dropout: float
    effect: str
    seed: int = 0

    def __post_init__(self) -> None:
        if self.setting not in SETTINGS:
            raise ValueError(f"setting must be one of {SETTINGS}, got {self.setting!r}")
        if self.effect not in PLANTED:
            raise ValueError(f"effect must be one of {sorted(PLANTED)}, got {self.effect!r}")
        if not (self.rate > 0 and self.noise >= 0 and 0 <= self.dropout < 0.5):
            raise ValueError(f"bad cell {self}")

    @property
    def label(self) -> str:
        return (f"{self.setting}/{self.rate:g}Hz/{self.noise * 1e3:g}mm/"
                f"drop{self.dropout * 100:g}%/{self.effect}/seed{self.seed}")  # fmt: skip

    @property
    def expected(self) -> tuple[str, ...]:
        """Library effects a correct identification names (the floor adds contact)."""
        return (("ground_contact",) if self.setting == "floor" else ()) + EXPECTED[self.effect]

    @property
    def durations(self) -> dict[str, float]:
        """Seconds per trajectory of each split (test trajectories last >= 1 s)."""
        if self.setting == "floor":
            return {"train": 3.0, "val": 3.0, "test": 3.0}
        return {"train": 0.6, "val": 0.6, "test": 1.0}

    @property
    def counts(self) -> dict[str, int]:
        """Trajectories per split."""
        n = 8 if self.setting == "floor" else 16
        return {"train": n, "val": 4, "test": 4}

    @property
    def substeps(self) -> int:
        """MuJoCo steps per sample interval (physics step <= 1 ms)."""
        return max(1, math.ceil(1.0 / (self.rate * PHYSICS_DT) - 1e-9))


@dataclass
class Truth:
    """What the plant simulated (never given to an identifier)."""

    params: Params
    xml: str
    effects: list[dict[str, Any]]
    sim: dict[str, Any] = field(default_factory=dict)


def true_model(cell: Cell) -> Truth:
    """The ground-truth MJCF text, parameters and planted-effect records of ``cell``.

    The icosahedron of :func:`tensegrity_env.assemblies.icosahedron` with stiffer,
    prestressed springs (:data:`STIFFNESS`, :data:`PRESTRESS`), rod-rod collisions off,
    capsules touching the floor (``floor`` setting, MuJoCo's default soft contact,
    friction :data:`FRICTION`).
    """
    a = assemblies.icosahedron(stiffness=STIFFNESS)
    p = a.params.numpy()
    rng = np.random.default_rng([cell.seed, 7])
    S = a.topology.n_springs
    stiffness, rest = p["stiffness"].copy(), PRESTRESS * p["rest_length"]
    effects: list[dict[str, Any]] = []
    sim: dict[str, Any] = {"plant": cell.effect, "mujoco": PLANTED[cell.effect]}
    cables: list[int] = []
    if cell.effect == "damaged_cable":
        k = int(rng.integers(S))
        stiffness[k] *= DAMAGE
        sim["damaged_spring"] = k
    elif cell.effect == "slack_cables":
        cables = sorted(int(i) for i in rng.choice(S, N_CABLES, replace=False))
        rest[cables] = CABLE_REST * p["rest_length"][cables]
        effects.append({"name": "slack_springs", "params": {"springs": cables}})
    elif cell.effect == "linear_drag":
        effects.append({"name": "linear_drag", "mujoco": {"viscosity": VISCOSITY}})
    elif cell.effect == "quadratic_drag":
        effects.append({"name": "quadratic_drag", "mujoco": {"density": DENSITY}})
    elif cell.effect == "force_field":
        effects.append({"name": "force_field", "params": {"force": list(FORCE)}})
    elif cell.effect == "joint_damping":
        effects.append({"name": "linear_drag", "form": "implicit",
                        "mujoco": {"joint_damping": JOINT_DAMPING}})  # fmt: skip
    if cell.setting == "floor":
        effects.insert(0, {"name": "ground_contact",
                           "params": {"friction": FRICTION, "height": 0.0}})  # fmt: skip
    dt = 1.0 / cell.rate / cell.substeps
    sim.update({"timestep": dt, "integrator": "Euler", "substeps": cell.substeps,
                "floor": cell.setting == "floor"})  # fmt: skip

    root = ET.Element("mujoco", model="icosahedron_measured")
    opt = ET.SubElement(root, "option", timestep=repr(dt), integrator="Euler",
                        gravity="0 0 -9.81")  # fmt: skip
    if cell.effect == "linear_drag":
        opt.set("viscosity", repr(VISCOSITY))
    if cell.effect == "quadratic_drag":
        opt.set("density", repr(DENSITY))
    world = ET.SubElement(root, "worldbody")
    if cell.setting == "floor":
        ET.SubElement(world, "geom", name="floor", type="plane", size="0 0 1",
                      contype="1", conaffinity="2", friction=f"{FRICTION!r} 0.005 0.0001")  # fmt: skip
    L = a.topology.rods[0].length
    for r, rod in enumerate(a.topology.rods):
        body = ET.SubElement(world, "body", name=rod.name)
        joint = ET.SubElement(body, "joint", name=f"{rod.name}_free", type="free")
        if cell.effect == "joint_damping":
            joint.set("damping", repr(JOINT_DAMPING))
        inertia = p["inertia"][r]
        ET.SubElement(body, "inertial", pos="0 0 0", mass=repr(float(p["mass"][r])),
                      diaginertia=" ".join(repr(float(x)) for x in inertia))  # fmt: skip
        ET.SubElement(body, "geom", type="capsule", size=repr(rod.radius),
                      fromto=f"0 0 {-L / 2!r} 0 0 {L / 2!r}", contype="2", conaffinity="1",
                      friction=f"{FRICTION!r} 0.005 0.0001", mass="0")  # fmt: skip
        for k, z in enumerate((-L / 2, L / 2)):
            ET.SubElement(body, "site", name=f"{rod.name}_end{k}", pos=f"0 0 {z!r}")
    tendon = ET.SubElement(root, "tendon")
    for s, sp in enumerate(a.topology.springs):
        low = "0" if s in cables else repr(float(rest[s]))
        t = ET.SubElement(tendon, "spatial", name=sp.name, stiffness=repr(float(stiffness[s])),
                          damping=repr(float(p["damping"][s])),
                          springlength=f"{low} {float(rest[s])!r}")  # fmt: skip
        for node in (sp.node_a, sp.node_b):
            ET.SubElement(t, "site", site=f"{a.topology.rods[node // 2].name}_end{node % 2}")
    ET.indent(root)
    params = Params.create(stiffness=stiffness, damping=p["damping"], rest_length=rest,
                           mass=p["mass"], inertia=p["inertia"],
                           control_gain=p["control_gain"], gravity=p["gravity"])  # fmt: skip
    return Truth(params, ET.tostring(root, encoding="unicode"), effects, sim)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2],
                    axis=-1)  # fmt: skip


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _turned_pose(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The nominal pose turned about its centre by ``n`` random rotations: rod centres
    p (n, R, 3) [m] and orientations q (n, R, 4)."""
    a = assemblies.icosahedron()
    R = a.topology.n_rods
    rot = _unit(rng.normal(size=(n, 4)))
    p = np.einsum("nij,rj->nri", np_quat_to_matrix(rot), a.pose_p - a.pose_p.mean(axis=0))
    q = _quat_mul(np.repeat(rot[:, None], R, axis=1), np.broadcast_to(a.pose_q, (n, R, 4)))
    return p, q


def lift(
    p: np.ndarray, q: np.ndarray, rng: np.random.Generator, lo: float, hi: float,
    offsets: np.ndarray | None = None, radius: float | None = None,
) -> None:  # fmt: skip
    """Raise each pose (in place) so its lowest end cap's surface is ``lo``-``hi`` [m]
    above the floor (uniform at random). ``offsets`` (R, 2, 3) [m]: the end caps in the
    principal frames, ``radius`` [m] theirs (None: the icosahedron's)."""
    topo = assemblies.icosahedron().topology
    offsets = topo.end_offsets if offsets is None else offsets
    radius = topo.rods[0].radius if radius is None else radius
    caps = p[:, :, None] + np.einsum("nrij,rkj->nrki", np_quat_to_matrix(q), offsets)
    low = caps[..., 2].reshape(len(p), -1).min(axis=1) - radius
    p[..., 2] += (rng.uniform(lo, hi, len(p)) - low)[:, None]


def initial_states(cell: Cell, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` random initial rod states: p, v, omega (n, R, 3) [m, m/s, rad/s], q (n, R, 4).

    A random rigid rotation of the nominal pose, per-rod perturbations (2 cm, 0.05 rad,
    0.3 m/s, 1 rad/s) so the springs oscillate, and a rigid throw: ``floor``: 0.3-1.2 m/s
    horizontal, 1-3 rad/s about a horizontal axis, lowest cap 2-20 cm above the floor;
    ``flight``: 0.5-2 m/s in any direction, 1-5 rad/s about any axis.
    """
    R = assemblies.icosahedron().topology.n_rods
    p, q = _turned_pose(n, rng)
    p = p + rng.normal(0.0, 0.02, (n, R, 3))
    axis = _unit(rng.normal(size=(n, R, 3)))
    half = 0.5 * rng.normal(0.0, 0.05, (n, R, 1))
    q = _unit(_quat_mul(np.concatenate([np.cos(half), np.sin(half) * axis], -1), q))
    if cell.setting == "floor":
        heading = rng.uniform(0, 2 * np.pi, n)
        dirs = np.stack([np.cos(heading), np.sin(heading), np.zeros(n)], -1)
        V = dirs * rng.uniform(0.3, 1.2, (n, 1))
        spin_axis = np.cross(np.array([0.0, 0.0, 1.0]), dirs)  # rolls along the throw
        W = spin_axis * rng.uniform(1.0, 3.0, (n, 1))
    else:
        V = _unit(rng.normal(size=(n, 3))) * rng.uniform(0.5, 2.0, (n, 1))
        W = _unit(rng.normal(size=(n, 3))) * rng.uniform(1.0, 5.0, (n, 1))
    v = V[:, None] + np.cross(W[:, None], p) + rng.normal(0.0, 0.3 / np.sqrt(3), (n, R, 3))
    omega = W[:, None] + rng.normal(0.0, 1.0 / np.sqrt(3), (n, R, 3))
    if cell.setting == "floor":
        lift(p, q, rng, 0.02, 0.2)
    else:
        p[..., 2] += 1.0
    return {"p": p, "v": v, "q": q, "omega": omega}


def drop_states(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` drops from rest: the nominal shape turned at random, its lowest end cap
    0.1-0.5 m above the floor, every velocity zero (same layout as :func:`initial_states`)."""
    p, q = _turned_pose(n, rng)
    lift(p, q, rng, 0.1, 0.5)
    zero = np.zeros(p.shape)
    return {"p": p, "v": zero, "q": q, "omega": zero.copy()}


def simulate(cell: Cell, truth: Truth, init: dict[str, np.ndarray], duration: float) -> Split:
    """Roll MuJoCo from ``init`` and record clean states and end caps at the sample times.

    Returns a :class:`Split` with ``nodes`` (n, T+1, 12, 3) [m] and rod states
    (centre of mass = body origin, principal frame = body frame, world ω).
    """
    model = mujoco.MjModel.from_xml_string(truth.xml)
    data = mujoco.MjData(model)
    n, R = init["p"].shape[:2]
    T = round(duration * cell.rate)
    out = {k: np.empty((n, T + 1, R, 3)) for k in ("p", "v", "omega")}
    out["q"] = np.empty((n, T + 1, R, 4))
    nodes = np.empty((n, T + 1, 2 * R, 3))
    sites = [model.site(f"rod{r}_end{k}").id for r in range(R) for k in (0, 1)]
    bodies = [model.body(f"rod{r}").id for r in range(R)]

    def record(i: int, t: int) -> None:
        # mj_step leaves site positions at the start of its last step: recompute them at
        # the state it ends in, so end caps and rod states are of the same instant
        mujoco.mj_kinematics(model, data)
        qpos, qvel = data.qpos.reshape(R, 7), data.qvel.reshape(R, 6)
        out["p"][i, t], out["q"][i, t], out["v"][i, t] = qpos[:, :3], qpos[:, 3:], qvel[:, :3]
        out["omega"][i, t] = np.einsum("rij,rj->ri", np_quat_to_matrix(qpos[:, 3:]), qvel[:, 3:])
        nodes[i, t] = data.site_xpos[sites]

    for i in range(n):
        mujoco.mj_resetData(model, data)
        q = init["q"][i]
        rot = np_quat_to_matrix(q)
        w_local = np.einsum("rji,rj->ri", rot, init["omega"][i])
        data.qpos[:] = np.concatenate([init["p"][i], q], -1).ravel()
        data.qvel[:] = np.concatenate([init["v"][i], w_local], -1).ravel()
        if cell.effect == "force_field":
            data.xfrc_applied[bodies, :3] = FORCE
        mujoco.mj_forward(model, data)
        record(i, 0)
        for t in range(1, T + 1):
            mujoco.mj_step(model, data, nstep=cell.substeps)
            if data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number:
                raise RuntimeError(f"{cell.label}: MuJoCo diverged in trajectory {i}")
            record(i, t)
    if not all(np.isfinite(x).all() for x in (*out.values(), nodes)):
        raise RuntimeError(f"{cell.label}: MuJoCo diverged")
    return Split(nodes=nodes, control=np.zeros((n, T, R, 3)), **out)


def clean_rolling(seed: int, duration: float = 1.0) -> tuple[Truth, Split]:
    """One clean trajectory of the floor cell of ``seed`` (120 Hz, no planted effect):
    the true model and the split, whose ``nodes`` are the end caps (1, T+1, 12, 3) [m]."""
    cell = Cell("floor", 120.0, 0.0, 0.0, "none", seed=seed)
    truth = true_model(cell)
    init = initial_states(cell, 1, np.random.default_rng([seed, 0, 3]))
    return truth, simulate(cell, truth, init, duration)


def measure(
    nodes: np.ndarray, cell: Cell, rng: np.random.Generator, fill: bool = True
) -> np.ndarray:
    """End caps as motion capture sees them: noise, then dropped markers, each gap
    filled by linear interpolation (``fill``) or left as NaN."""
    seen = nodes + cell.noise * rng.standard_normal(nodes.shape)
    if cell.dropout <= 0:
        return seen
    n, S, C = nodes.shape[:3]
    for i in range(n):
        for c in range(C):
            lost, target = np.zeros(S, bool), max(1, round(cell.dropout * S))
            while lost.sum() < target:
                run = min(int(rng.integers(1, 6)), target - int(lost.sum()))
                start = int(rng.integers(1, S - 1 - run))
                lost[start : start + run] = True
            if not fill:
                seen[i, lost, c] = np.nan
                continue
            t = np.arange(S)
            for ax in range(3):
                seen[i, lost, c, ax] = np.interp(t[lost], t[~lost], seen[i, ~lost, c, ax])
    return seen


@dataclass
class CellData:
    """The files of one cell: what a user measures and the clean reference."""

    measured: Path
    clean: Path
    truth: Truth
    cell: Cell


def write_cell(cell: Cell, directory: Path) -> CellData:
    """Simulate ``cell`` and write ``measured.h5`` (end caps only) and ``clean.h5``.

    ``clean.h5`` has the same trajectories without noise, with rod states, for
    evaluation; both carry the ground truth (parameters, MJCF, planted effects).
    """
    directory.mkdir(parents=True, exist_ok=True)
    truth = true_model(cell)
    topology = assemblies.icosahedron().topology
    rng = np.random.default_rng([cell.seed, int(cell.rate), int(cell.noise * 1e6), 11])
    clean, seen = {}, {}
    for k, (name, n) in enumerate(cell.counts.items()):
        init = initial_states(cell, n, np.random.default_rng([cell.seed, k, 3]))
        clean[name] = simulate(cell, truth, init, cell.durations[name])
        nodes = measure(clean[name].nodes, cell, rng)
        seen[name] = Split(nodes=nodes, control=clean[name].control.copy())
    attrs = {"assembly": "icosahedron", "source": f"bench_measured {cell.label}",
             "measurement_noise_std": cell.noise, "dropout": cell.dropout}  # fmt: skip
    gt = GroundTruth(params=truth.params, sim={**truth.sim, "cell": asdict(cell)},
                     mjcf=truth.xml, effects=truth.effects)  # fmt: skip
    dt = 1.0 / cell.rate
    measured = write_dataset(directory / "measured.h5", Dataset(topology, dt, seen, attrs), gt)
    clean_path = write_dataset(directory / "clean.h5", Dataset(topology, dt, clean, attrs), gt)
    return CellData(measured, clean_path, truth, cell)
