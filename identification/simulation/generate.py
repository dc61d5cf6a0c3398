"""Ground-truth datasets: many seeded, randomized MuJoCo rollouts of one assembly.

The pipeline, each stage a small function (stages 1 and 2 in
:mod:`identification.simulation.truth`):

1. :func:`~identification.simulation.truth.load_truth` builds the ground-truth MuJoCo
   model (a built-in assembly written with :func:`tensegrity_env.mjcf.to_mjcf`, or any
   user MJCF read by :func:`tensegrity_env.mjcf.from_mjcf`), with its nominal pose.
2. :func:`~identification.simulation.truth.sample_initial_conditions` draws the initial
   rod states of a split from the nominal pose: a random rigid rotation of the whole
   structure (free-floating assemblies only), per-rod position and orientation
   perturbations, and random linear and angular velocities (with some spin about each
   rod's axis) that put energy into the springs;
   :func:`~identification.simulation.truth.sample_controls` draws piecewise-constant
   random control commands.
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
from typing import Any

import mujoco
import numpy as np
from tqdm.auto import tqdm

from identification.data.dataset import SPLITS, Dataset, GroundTruth, Split
from identification.defaults import PRESETS
from identification.simulation.rollout import RodFrames, Roller, roll_and_convert
from identification.simulation.truth import (
    Truth,
    load_truth,
    sample_cable_commands,
    sample_controls,
    sample_initial_conditions,
)
from tensegrity_env import assemblies
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf_checks import check_ignore_names
from tensegrity_env.mujoco_state import rod_state_to_mj
from tensegrity_env.topology import Topology


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
            (names of :data:`tensegrity_env.defaults.FEATURES`; warned about).
        end_caps: the end-cap sites of ``mjcf``, two per rod (empty: by convention).
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
    end_caps: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "ignore", tuple(self.ignore))
        object.__setattr__(self, "end_caps", tuple(self.end_caps))
        if self.end_caps and self.mjcf is None:
            raise InputError("--end-caps: names sites of an MJCF file; pass --mjcf")
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


# ---------------------------------------------------------------------- rollout
def ctrl_vectors(
    truth: Truth, commands: np.ndarray, cables: np.ndarray | None = None
) -> np.ndarray:
    """MuJoCo ``ctrl`` arrays (n, T, nu) from per-rod commands (n, T, R, 3) and cable
    commands (n, T, C)."""
    act = truth.asm.actuators
    ctrl = np.zeros((*commands.shape[:2], truth.model.nu))
    has = act >= 0
    ctrl[:, :, act[has]] = commands[:, :, has]
    if cables is not None:
        ctrl[:, :, truth.asm.cable_actuators] = cables
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
    cables: np.ndarray | None = None,
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
        cables: cable commands (n, T, C), or None without cable actuators.
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
        return ctrl_vectors(truth, commands[lo:hi], None if cables is None else cables[lo:hi])

    roll_and_convert(roller, frames, init, controls, arrays, chunk, done, where)
    return Split(control=commands, cable_control=cables, **arrays)


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
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray | None]:
    """Initial rod states, control commands and cable commands (None without cable
    actuators) of one split, seeded by (seed, split)."""
    rng = split_rng(spec.seed, split)
    states = sample_initial_conditions(truth, n, rng, spec.initial)
    commands = sample_controls(truth, n, spec.steps, spec.control_std, spec.control_hold, rng)
    cables = sample_cable_commands(truth, n, spec.steps, spec.control_std, spec.control_hold, rng)
    return states, commands, cables


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
            states, commands, cables = split_inputs(truth, spec, name, n)
            splits[name] = rollout_split(
                truth, roller, states, commands, spec.chunk, bar, f"{spec.source_name} {name}",
                cables,
            )  # fmt: skip
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
