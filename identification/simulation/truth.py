"""The ground-truth MuJoCo plant of a dataset: the model, its nominal pose and random starts.

:func:`load_truth` builds the model (a built-in assembly written with
:func:`tensegrity_env.mjcf.to_mjcf`, or any user MJCF read by
:func:`tensegrity_env.mjcf.from_mjcf`); :func:`sample_initial_conditions` and
:func:`sample_controls` draw a split's initial rod states and control commands
(see :mod:`identification.simulation.generate` for the pipeline).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from identification.data.dataset import GroundTruth
from tensegrity_env import assemblies
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import MjcfAssembly, SimOptions, from_mjcf, to_mjcf
from tensegrity_env.mjcf_checks import IgnoredFeatureWarning
from tensegrity_env.mujoco_state import mj_to_rod_state
from tensegrity_env.rotations import (
    np_quat_mul,
    np_quat_to_matrix,
    random_quaternions,
    rod_axes,
    unit,
)
from tensegrity_env.topology import Topology

if TYPE_CHECKING:
    from identification.simulation.spec import GenerateSpec, InitialConditions

#: How far above its nominal pose the built-in element is lifted when a floor is on [m].
ELEMENT_GROUND_LIFT = 0.5


# ---------------------------------------------------------------------- the model
@dataclass(frozen=True)
class Truth:
    """The ground-truth model and its nominal pose.

    Attributes:
        asm: the MJCF read back (topology, params, MuJoCo model and maps).
        xml: the MJCF text of the model that is simulated.
        pose_p: nominal rod centres, (R, 3) [m].
        pose_q: nominal rod orientations (w, x, y, z), (R, 4).
        ground: whether the model has a floor (plane at z = 0).
        name: the assembly name recorded in the dataset.
    """

    asm: MjcfAssembly
    xml: str
    pose_p: np.ndarray
    pose_q: np.ndarray
    ground: bool
    name: str

    @property
    def topology(self) -> Topology:
        return self.asm.topology

    @property
    def radius(self) -> float:
        """How far rod geometry reaches beyond the end-cap centres [m] (largest radius)."""
        m = self.asm.model
        round_types = {int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_SPHERE)}
        rods = set(self.asm.rod_bodies.tolist())
        sizes = [
            float(m.geom_size[g, 0])
            for g in range(m.ngeom)
            if m.geom_bodyid[g] in rods and int(m.geom_type[g]) in round_types
        ]
        return max(sizes, default=0.0)

    @property
    def model(self) -> mujoco.MjModel:
        return self.asm.model

    @property
    def dt(self) -> float:
        return float(self.asm.model.opt.timestep)

    def ground_truth(self) -> GroundTruth:
        """The true model: params, simulation options, MJCF and the effects the file has
        beyond linear springs (floor contact with the file's friction, solref and
        solimp; tension-only springs; the cable actuators' filter as ``control_lag``), in
        their ``to_dict`` form."""
        effects = [e.to_dict() for e in self.asm.declared_effects(self.ground)]
        return GroundTruth(
            params=self.asm.params,
            sim=dataclasses.asdict(dataclasses.replace(self.asm.options, ground=self.ground)),
            mjcf=self.xml,
            effects=effects,
        )


def _floor_height_check(truth: Truth, where: str) -> None:
    """With a floor, an assembly tied to world anchors must start above it."""
    nodes = assemblies.node_positions(truth.topology, truth.pose_p, truth.pose_q)
    if nodes[: 2 * truth.topology.n_rods, 2].min() - truth.radius <= 0:
        raise InputError(
            f"{where}: with a floor at z = 0, this assembly (tied to world anchors, so it "
            "cannot be lifted) must start above the floor"
        )


def load_truth(spec: GenerateSpec) -> Truth:
    """The ground-truth model for ``spec``. Raises :class:`InputError` on a bad MJCF."""
    if spec.mjcf is not None:
        return _load_user_mjcf(spec)
    a = assemblies.ASSEMBLIES[spec.assembly]()
    topology, pose_p = a.topology, a.pose_p
    if spec.ground and topology.n_anchors:
        # tied to the world: lift anchors and pose together, once, above the floor
        lift = np.array([0.0, 0.0, ELEMENT_GROUND_LIFT])
        topology = Topology(
            rods=topology.rods,
            springs=topology.springs,
            anchors=tuple(tuple(np.add(x, lift)) for x in topology.anchors),
            name=topology.name,
        )
        pose_p = pose_p + lift
    xml = to_mjcf(topology, a.params, SimOptions(ground=spec.ground), pose_p, a.pose_q)
    asm = from_mjcf(f"<{spec.assembly}>", xml=xml)
    truth = Truth(asm, xml, pose_p.copy(), a.pose_q.copy(), spec.ground, spec.assembly)
    if spec.ground and topology.n_anchors:
        _floor_height_check(truth, spec.assembly)
    return truth


def _load_user_mjcf(spec: GenerateSpec) -> Truth:
    path = Path(str(spec.mjcf))
    asm = from_mjcf(path, ignore=spec.ignore, end_caps=spec.end_caps)
    xml = path.read_text()
    ground = asm.options.ground
    if spec.ground and not ground:
        # add the floor the user asked for; it collides with any rod collision bit
        m, rods = asm.model, set(asm.rod_bodies.tolist())
        if not any(
            (m.geom_contype[g] & 3) or (m.geom_conaffinity[g] & 1)
            for g in range(m.ngeom)
            if m.geom_bodyid[g] in rods
        ):
            raise InputError(
                f"{path}: --ground: no rod geom can touch a floor (their contype and "
                "conaffinity are 0); give the rods collision bits or drop --ground"
            )
        mspec = mujoco.MjSpec.from_file(str(path))
        floor = mspec.worldbody.add_geom()
        floor.name, floor.type = "tensegrity_sr_floor", mujoco.mjtGeom.mjGEOM_PLANE
        floor.size = [0.0, 0.0, 0.05]
        floor.contype, floor.conaffinity = 1, 3
        xml = mspec.to_xml()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IgnoredFeatureWarning)  # said once, above
            asm = from_mjcf(path, xml=xml, ignore=spec.ignore, end_caps=spec.end_caps)
        ground = True
    nominal = mj_to_rod_state(asm, asm.model.qpos0.copy(), np.zeros(asm.model.nv))
    truth = Truth(asm, xml, nominal["p"], nominal["q"], ground, path.stem)
    if ground and asm.topology.n_anchors:
        _floor_height_check(truth, str(path))
    return truth


# ---------------------------------------------------------------------- initial states
def sample_initial_conditions(
    truth: Truth, n: int, rng: np.random.Generator, ic: InitialConditions
) -> dict[str, np.ndarray]:
    """``n`` randomized initial rod states: p, v, omega (n, R, 3), q (n, R, 4)."""
    topo = truth.topology
    R = topo.n_rods
    p = np.broadcast_to(truth.pose_p, (n, R, 3)).copy()
    q = np.broadcast_to(truth.pose_q, (n, R, 4)).copy()
    # a rigid rotation of the whole structure about its centre (free-floating only)
    if ic.rotate and topo.n_anchors == 0:
        rot_q = random_quaternions(rng, n)  # (n, 4)
        centre = truth.pose_p.mean(axis=0)
        p = centre + np.einsum("nij,nrj->nri", np_quat_to_matrix(rot_q), p - centre)
        q = np_quat_mul(np.repeat(rot_q[:, None], R, axis=1), q)
    # per-rod perturbations of position and orientation
    p = p + rng.normal(0.0, ic.position_std, (n, R, 3))
    axis = unit(rng.normal(size=(n, R, 3)))
    half = 0.5 * rng.normal(0.0, ic.rotation_std, (n, R, 1))
    q = unit(np_quat_mul(np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1), q))
    # linear velocity: random direction and speed
    v = unit(rng.normal(size=(n, R, 3))) * rng.uniform(*ic.speed, (n, R, 1))
    # angular velocity: tumbling perpendicular to the rod axis plus spin about it
    a_world = np.einsum("nrij,rj->nri", np_quat_to_matrix(q), rod_axes(topo.end_offsets))
    w = rng.normal(size=(n, R, 3))
    w_perp = unit(w - np.sum(w * a_world, axis=-1, keepdims=True) * a_world)
    omega = w_perp * rng.uniform(*ic.tumble, (n, R, 1))
    omega = omega + a_world * rng.uniform(-ic.spin, ic.spin, (n, R, 1))
    # with a floor, lift each free-floating structure so its lowest point is above it
    if truth.ground and topo.n_anchors == 0:
        rot = np_quat_to_matrix(q)
        caps = p[:, :, None] + np.einsum("nrij,rkj->nrki", rot, topo.end_offsets)
        low = caps[..., 2].reshape(n, -1).min(axis=1) - truth.radius
        p[..., 2] += (rng.uniform(*ic.lift, n) - low)[:, None]
    return {"p": p, "v": v, "q": q, "omega": omega}


def sample_controls(
    truth: Truth, n: int, steps: int, std: float, hold: float, rng: np.random.Generator
) -> np.ndarray:
    """Piecewise-constant random commands f_u, (n, steps, R, 3), held ``hold`` seconds.

    Each command is Gaussian (a random direction and size per rod). Axes without an
    actuator get 0, and commands are clipped to actuator control ranges, so the
    array is exactly what was applied. A model whose only actuators are cable
    actuators or winches gets zero f_u (its commands come from
    :func:`sample_cable_commands` and :func:`sample_winch_commands`).
    """
    R = truth.topology.n_rods
    act = truth.asm.actuators
    if std == 0 or (np.all(act < 0) and (truth.topology.n_cables or truth.topology.n_winches)):
        return np.zeros((n, steps, R, 3))
    if np.all(act < 0):
        raise InputError(
            f"{truth.name}: --control-std needs control actuators and the model has none"
        )
    cmd = held_normal(truth, (n, steps, R, 3), std, hold, rng)
    clip_to_ctrlrange(truth.model, cmd, act)
    cmd[:, :, act < 0] = 0.0
    return cmd


def sample_cable_commands(
    truth: Truth, n: int, steps: int, std: float, hold: float, rng: np.random.Generator
) -> np.ndarray | None:
    """Piecewise-constant random cable commands, (n, steps, C), like :func:`sample_controls`
    (Gaussian, held ``hold`` seconds, clipped to the actuators' control ranges); None
    without cable actuators."""
    C = truth.topology.n_cables
    if C == 0:
        return None
    if std == 0:
        return np.zeros((n, steps, C))
    cmd = held_normal(truth, (n, steps, C), std, hold, rng)
    clip_to_ctrlrange(truth.model, cmd, truth.asm.cable_actuators)
    return cmd


def sample_winch_commands(
    truth: Truth, n: int, steps: int, std: float, hold: float, rng: np.random.Generator
) -> np.ndarray | None:
    """Piecewise-constant random winch commands, (n, steps, W), like
    :func:`sample_cable_commands`, clipped to the motors' range [-1, 1]; None without
    winches (no random numbers drawn then)."""
    W = truth.topology.n_winches
    if W == 0:
        return None
    if std == 0:
        return np.zeros((n, steps, W))
    return np.clip(held_normal(truth, (n, steps, W), std, hold, rng), -1.0, 1.0)


def held_normal(
    truth: Truth, shape: tuple[int, ...], std: float, hold: float, rng: np.random.Generator
) -> np.ndarray:
    """Gaussian values of ``shape`` (n, steps, ...), each held ``hold`` seconds."""
    n, steps = shape[:2]
    hold_steps = max(1, round(hold / truth.dt))
    n_holds = -(-steps // hold_steps)
    cmd = rng.normal(0.0, std, (n, n_holds, *shape[2:]))
    return np.repeat(cmd, hold_steps, axis=1)[:, :steps]


def clip_to_ctrlrange(m: mujoco.MjModel, cmd: np.ndarray, act: np.ndarray) -> None:
    """Clip commands (n, steps, *act.shape) in place to each actuator's control range
    (``act`` holds actuator ids, -1 where none)."""
    for idx in zip(*np.nonzero(act >= 0), strict=True):
        a = act[idx]
        if m.actuator_ctrllimited[a]:
            lo, hi = m.actuator_ctrlrange[a]
            cmd[(slice(None), slice(None), *idx)] = np.clip(
                cmd[(slice(None), slice(None), *idx)], lo, hi
            )
