"""Ground-truth datasets: many seeded, randomized MuJoCo rollouts of one assembly.

The pipeline, each stage a small function:

1. :func:`load_truth` builds the ground-truth MuJoCo model (a built-in assembly written
   with :func:`tensegrity_env.mjcf.to_mjcf`, or any user MJCF read by
   :func:`tensegrity_env.mjcf.from_mjcf`), with its nominal pose.
2. :func:`sample_initial_conditions` draws the initial rod states of a split from the
   nominal pose: a random rigid rotation of the whole structure (free-floating
   assemblies only), per-rod position and orientation perturbations, and random
   linear and angular velocities (with some spin about each rod's axis) that put
   energy into the springs. :func:`sample_controls` draws piecewise-constant random
   control commands.
3. :func:`rollout_split` rolls the split out with MuJoCo's own multi-threaded batched
   rollout (:mod:`mujoco.rollout`) in chunks of trajectories, and converts (qpos,
   qvel) to rod states and end caps in parallel while the next chunk simulates
   (:func:`identification.simulation.rollout.roll_and_convert`).
4. :func:`generate` checks the result (no MuJoCo reset, finite, springs within
   bounds) and returns it; :func:`generate_dataset` is the bare ``(Dataset,
   GroundTruth)`` version. Nothing is written here: the caller writes the file once
   at the end with :func:`identification.data.dataset.write_dataset` (atomic), so an
   interrupted run never leaves a file that looks complete.

Everything is seeded from ``spec.seed`` with :func:`numpy.random.default_rng`, one
independent stream per split, so the same spec gives bit-identical arrays, and
changing ``n_train`` does not change the validation or test trajectories.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from tqdm.auto import tqdm

from identification.data.dataset import SPLITS, Dataset, GroundTruth, Split
from identification.simulation.rollout import RodFrames, Roller, roll_and_convert
from tensegrity_env import assemblies
from tensegrity_env.effects.ground_contact import GroundContact
from tensegrity_env.effects.springs import SlackSprings
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import MjcfAssembly, SimOptions, from_mjcf, to_mjcf
from tensegrity_env.mjcf_checks import IgnoredFeatureWarning, check_ignore_names
from tensegrity_env.mujoco_state import mj_to_rod_state, rod_state_to_mj
from tensegrity_env.rotations import (
    np_quat_mul,
    np_quat_to_matrix,
    random_quaternions,
    rod_axes,
    unit,
)
from tensegrity_env.topology import Topology

#: Trajectory counts and length (transitions) of each preset.
PRESETS: dict[str, dict[str, Any]] = {
    "small": {"n_train": 16, "n_val": 4, "n_test": 4, "steps": 300},
    "paper": {"n_train": 1000, "n_val": 200, "n_test": 100, "steps": 736},
    # the paper's generalization data: 20,000-step trajectories under random directed
    # perturbation forces h * f_u at each rod's arm r_u
    "perturbed": {"n_train": 4, "n_val": 0, "n_test": 4, "steps": 20000, "control_std": 1.0},
}

#: How far above its nominal pose the built-in element is lifted when a floor is on [m].
ELEMENT_GROUND_LIFT = 0.5


@dataclass(frozen=True)
class InitialConditions:
    """How initial states are randomized around the nominal pose.

    Attributes:
        rotate: apply a uniformly random rigid rotation to the whole structure
            (ignored for assemblies tied to world anchors).
        position_std: per-rod position perturbation, std per axis [m].
        rotation_std: per-rod rotation perturbation about a random axis, std [rad].
        speed: range of each rod's linear speed, random direction [m/s].
        tumble: range of each rod's angular speed perpendicular to its axis [rad/s].
        spin: maximum spin about each rod's own axis, uniform in ``[-spin, spin]`` [rad/s].
        lift: with a floor, range of the lowest rod surface's initial height [m].
    """

    rotate: bool = True
    position_std: float = 0.02
    rotation_std: float = 0.05
    speed: tuple[float, float] = (0.3, 1.0)
    tumble: tuple[float, float] = (1.0, 3.0)
    spin: float = 2.0
    lift: tuple[float, float] = (0.02, 0.3)


@dataclass(frozen=True)
class GenerateSpec:
    """What to generate. Build from a preset with :meth:`preset`.

    Attributes:
        assembly: built-in assembly, ``"icosahedron"`` or ``"element"``.
        mjcf: a user MJCF file instead of a built-in assembly (see
            :func:`tensegrity_env.mjcf.from_mjcf` for the conventions it must follow).
        n_train, n_val, n_test: trajectories per split (val/test may be 0: omitted).
        steps: transitions per trajectory T (T + 1 samples).
        seed: seed of every random draw.
        ground: add a floor at z = 0 and lift the structure above it.
        control_std: std of the random control commands f_u per rod and axis
            [command units]; 0 gives no control.
        control_hold: how long each random command is held [s].
        preset: the preset name recorded in the file (``"custom"`` if none).
        initial: initial-condition randomization.
        threads: MuJoCo rollout threads (None: all CPU cores).
        chunk: trajectories per rollout call (None: automatic).
        ignore: MJCF features the model leaves out that the user accepts anyway
            (names of :data:`tensegrity_env.mjcf_checks.FEATURES`; warned about).
    """

    assembly: str = "icosahedron"
    mjcf: str | None = None
    n_train: int = 16
    n_val: int = 4
    n_test: int = 4
    steps: int = 300
    seed: int = 0
    ground: bool = False
    control_std: float = 0.0
    control_hold: float = 0.05
    preset: str = "custom"
    initial: InitialConditions = field(default_factory=InitialConditions)
    threads: int | None = None
    chunk: int | None = None
    ignore: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "ignore", tuple(self.ignore))
        check_ignore_names(self.ignore)
        if self.mjcf is None and self.assembly not in assemblies.ASSEMBLIES:
            raise InputError(
                f"--assembly: unknown assembly '{self.assembly}' "
                f"(choose from {sorted(assemblies.ASSEMBLIES)})"
            )
        if self.n_train < 1:
            raise InputError(f"--n-train: need at least 1 training trajectory, got {self.n_train}")
        for name in ("n_val", "n_test"):
            if getattr(self, name) < 0:
                raise InputError(f"--{name.replace('_', '-')}: must be >= 0")
        if self.steps < 1:
            raise InputError(f"--steps: need at least 1 step, got {self.steps}")
        if not np.isfinite(self.control_std) or self.control_std < 0:
            raise InputError(f"--control-std: must be >= 0, got {self.control_std}")
        if not self.control_hold > 0:
            raise InputError(f"control_hold: must be positive, got {self.control_hold}")
        if self.threads is not None and self.threads < 1:
            raise InputError(f"--threads: must be >= 1, got {self.threads}")
        if self.seed < 0:
            raise InputError(f"--seed: must be >= 0, got {self.seed}")

    @classmethod
    def from_preset(cls, name: str, **overrides: Any) -> GenerateSpec:
        """The preset ``name`` with ``overrides`` (None values are ignored)."""
        if name not in PRESETS:
            raise InputError(f"--preset: unknown preset '{name}' (choose from {sorted(PRESETS)})")
        kw: dict[str, Any] = {**PRESETS[name], "preset": name}
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**kw)

    @property
    def counts(self) -> dict[str, int]:
        """Trajectories per non-empty split."""
        n = {"train": self.n_train, "val": self.n_val, "test": self.n_test}
        return {s: n[s] for s in SPLITS if n[s] > 0}

    @property
    def source_name(self) -> str:
        return str(self.mjcf) if self.mjcf is not None else self.assembly

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d.pop("threads")  # how fast, not what: keep files identical across machines
        d.pop("chunk")
        return d


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
        solimp; tension-only springs), in their ``to_dict`` form."""
        effects = []
        if self.ground:
            contact = self.asm.contact or {"friction": self.asm.options.friction}
            effects.append(GroundContact(self.topology, height=0.0, **contact).to_dict())
        if self.asm.slack_springs:
            cables = list(self.asm.slack_springs)
            effects.append(SlackSprings(self.topology, springs=cables).to_dict())
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
    asm = from_mjcf(path, ignore=spec.ignore)
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
            asm = from_mjcf(path, xml=xml, ignore=spec.ignore)
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
    array is exactly what was applied.
    """
    R = truth.topology.n_rods
    if std == 0:
        return np.zeros((n, steps, R, 3))
    act = truth.asm.actuators
    if np.all(act < 0):
        raise InputError(
            f"{truth.name}: --control-std needs control actuators and the model has none"
        )
    hold_steps = max(1, round(hold / truth.dt))
    n_holds = -(-steps // hold_steps)
    cmd = rng.normal(0.0, std, (n, n_holds, R, 3))
    cmd = np.repeat(cmd, hold_steps, axis=1)[:, :steps]
    m = truth.model
    for r, k in zip(*np.nonzero(act >= 0), strict=True):
        a = act[r, k]
        if m.actuator_ctrllimited[a]:
            lo, hi = m.actuator_ctrlrange[a]
            cmd[:, :, r, k] = np.clip(cmd[:, :, r, k], lo, hi)
    cmd[:, :, act < 0] = 0.0
    return cmd


# ---------------------------------------------------------------------- rollout
def ctrl_vectors(truth: Truth, commands: np.ndarray) -> np.ndarray:
    """MuJoCo ``ctrl`` arrays (n, T, nu) from per-rod commands (n, T, R, 3)."""
    act = truth.asm.actuators
    ctrl = np.zeros((*commands.shape[:2], truth.model.nu))
    has = act >= 0
    ctrl[:, :, act[has]] = commands[:, :, has]
    return ctrl


def initial_state_vectors(
    truth: Truth, roller: Roller, rod_states: dict[str, np.ndarray]
) -> np.ndarray:
    """MuJoCo ``mjSTATE_FULLPHYSICS`` initial states (n, nstate) from rod states."""
    return roller.initial_states(*rod_state_to_mj(truth.asm, **rod_states))


def rollout_split(
    truth: Truth,
    roller: Roller,
    rod_states: dict[str, np.ndarray],
    commands: np.ndarray,
    chunk: int | None = None,
    bar: Any = None,
    where: str = "",
) -> Split:
    """Roll out one split and convert it to rod states and end caps.

    Args:
        truth: the ground-truth model.
        roller: the MuJoCo rollout pool.
        rod_states: initial rod states, p, v, omega (n, R, 3), q (n, R, 4).
        commands: control commands f_u, (n, T, R, 3).
        chunk: trajectories per rollout call (None: automatic).
        bar: a tqdm bar updated with the steps done.
        where: label for error messages.
    """
    n, steps = commands.shape[:2]
    R = truth.topology.n_rods
    init = initial_state_vectors(truth, roller, rod_states)
    frames = RodFrames(truth.asm)
    arrays = {k: np.empty((n, steps + 1, R, 3)) for k in ("p", "v", "omega")}
    arrays["q"] = np.empty((n, steps + 1, R, 4))
    arrays["nodes"] = np.empty((n, steps + 1, 2 * R, 3))

    def done(k: int) -> None:
        if bar is not None:
            bar.update(k * steps)

    def controls(lo: int, hi: int) -> np.ndarray:
        return ctrl_vectors(truth, commands[lo:hi])

    roll_and_convert(roller, frames, init, controls, arrays, chunk, done, where)
    return Split(control=commands, **arrays)


# ---------------------------------------------------------------------- checks
def spring_lengths(topology: Topology, nodes: np.ndarray) -> np.ndarray:
    """Spring lengths (..., S) [m] from all nodes (..., n_nodes, 3) [m], or from the end
    caps (..., 2R, 3) and the topology's anchors when no spring uses another point."""
    x = nodes
    if nodes.shape[-2] == 2 * topology.n_rods and topology.n_points == 0:
        lead = nodes.shape[:-2]
        anchors = np.broadcast_to(topology.anchor_positions, (*lead, topology.n_anchors, 3))
        x = np.concatenate([nodes, anchors], axis=-2)
    # node -> spring difference operator (S, n_nodes): one small matmul per sample
    sn = topology.spring_nodes
    diff = np.zeros((topology.n_springs, topology.n_nodes))
    diff[np.arange(topology.n_springs), sn[:, 1]] = 1.0
    diff[np.arange(topology.n_springs), sn[:, 0]] -= 1.0
    d = np.matmul(diff, x)  # (..., S, 3)
    return np.sqrt(np.sum(d * d, axis=-1))


def spring_excitation(
    truth: Truth, splits: dict[str, Split], every: float = 0.01
) -> tuple[float, tuple[float, float]]:
    """How much the springs move, sampled every ``every`` seconds (a cheap check).

    Returns the median over trajectories and springs of the spring-length std over
    time [m], and the min and max spring length relative to the nominal pose.
    """
    topo = truth.topology
    nominal = spring_lengths(topo, assemblies.node_positions(topo, truth.pose_p, truth.pose_q))
    stride = max(1, round(every / truth.dt))
    stds, lo, hi = [], np.inf, -np.inf
    for s in splits.values():
        nodes = (
            assemblies.node_positions(topo, s.p[:, ::stride], s.q[:, ::stride])
            if s.has_states
            else np.ascontiguousarray(s.nodes[:, ::stride])
        )
        lengths = spring_lengths(topo, nodes)
        stds.append(lengths.std(axis=1).ravel())
        ratio = lengths / nominal
        lo, hi = min(lo, float(ratio.min())), max(hi, float(ratio.max()))
    return float(np.median(np.concatenate(stds))), (lo, hi)


@dataclass
class GenerateResult:
    """What :func:`generate` returns.

    Attributes:
        dataset: the trajectories (not yet written).
        ground_truth: the true model behind them.
        seconds: wall time of the whole generation [s].
        rollout_seconds: wall time inside MuJoCo's rollout [s] (included in ``seconds``).
        threads: MuJoCo rollout threads used.
        spring_std: per-trajectory, per-spring length std over time, median [m].
        spring_ratio: min and max spring length over the nominal length, all data.
    """

    dataset: Dataset
    ground_truth: GroundTruth
    seconds: float
    rollout_seconds: float
    threads: int
    spring_std: float
    spring_ratio: tuple[float, float]

    @property
    def steps_per_second(self) -> float:
        return self.dataset.n_steps / self.seconds if self.seconds > 0 else float("inf")


#: Spring length bounds, relative to the nominal pose, beyond which data counts as violent.
SPRING_RATIO_BOUNDS = (0.3, 1.5)


def split_rng(seed: int, split: str) -> np.random.Generator:
    """The independent random stream of one split."""
    return np.random.default_rng([seed, SPLITS.index(split)])


def split_inputs(
    truth: Truth, spec: GenerateSpec, split: str, n: int
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Initial rod states and control commands of one split, seeded by (seed, split)."""
    rng = split_rng(spec.seed, split)
    states = sample_initial_conditions(truth, n, rng, spec.initial)
    commands = sample_controls(truth, n, spec.steps, spec.control_std, spec.control_hold, rng)
    return states, commands


def generate(spec: GenerateSpec, progress: bool = False) -> GenerateResult:
    """Roll out every split of ``spec`` in MuJoCo; see the module docstring."""
    t0 = time.perf_counter()
    truth = load_truth(spec)
    counts = spec.counts
    total = sum(counts.values()) * spec.steps
    splits: dict[str, Split] = {}
    with (
        Roller(truth.model, spec.threads) as roller,
        tqdm(total=total, unit="step", unit_scale=True, disable=None if progress else True) as bar,
    ):
        for name, n in counts.items():
            bar.set_description(name)
            states, commands = split_inputs(truth, spec, name, n)
            splits[name] = rollout_split(
                truth, roller, states, commands, spec.chunk, bar, f"{spec.source_name} {name}"
            )
        threads, rollout_s = roller.threads, roller.seconds
    spring_std, spring_ratio = spring_excitation(truth, splits)
    if spring_ratio[0] < SPRING_RATIO_BOUNDS[0] or spring_ratio[1] > SPRING_RATIO_BOUNDS[1]:
        warnings.warn(
            f"{spec.source_name}: spring lengths reach {spring_ratio[0]:.2f}.."
            f"{spring_ratio[1]:.2f} x their nominal length (outside {SPRING_RATIO_BOUNDS[0]}.."
            f"{SPRING_RATIO_BOUNDS[1]}): the initial states are violent for this model",
            stacklevel=2,
        )
    dataset = Dataset(
        topology=truth.topology,
        dt=truth.dt,
        splits=splits,
        attrs={
            "assembly": truth.name,
            "preset": spec.preset,
            "seed": int(spec.seed),
            "source": f"mujoco {mujoco.__version__}",
            "generate": spec.to_dict(),
        },
    )
    return GenerateResult(
        dataset=dataset,
        ground_truth=truth.ground_truth(),
        seconds=time.perf_counter() - t0,
        rollout_seconds=rollout_s,
        threads=threads,
        spring_std=spring_std,
        spring_ratio=spring_ratio,
    )


def generate_dataset(spec: GenerateSpec, progress: bool = False) -> tuple[Dataset, GroundTruth]:
    """Roll out ``spec`` in MuJoCo: the dataset and its ground truth (nothing written)."""
    result = generate(spec, progress=progress)
    return result.dataset, result.ground_truth
