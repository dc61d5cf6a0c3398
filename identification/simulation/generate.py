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

import time
import warnings
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from tqdm.auto import tqdm

from identification.data.dataset import SPLITS, Dataset, GroundTruth, Split
from identification.simulation.rollout import RodFrames, Roller, roll_and_convert
from identification.simulation.spec import PRESETS as PRESETS  # re-exported
from identification.simulation.spec import GenerateSpec
from identification.simulation.spec import InitialConditions as InitialConditions  # re-exported
from identification.simulation.truth import (
    Truth,
    load_truth,
    sample_cable_commands,
    sample_controls,
    sample_initial_conditions,
    sample_winch_commands,
)
from tensegrity_env import assemblies
from tensegrity_env.mujoco_state import rod_state_to_mj
from tensegrity_env.topology import Topology


# ---------------------------------------------------------------------- rollout
def ctrl_vectors(
    truth: Truth,
    commands: np.ndarray,
    cables: np.ndarray | None = None,
    winches: np.ndarray | None = None,
) -> np.ndarray:
    """MuJoCo ``ctrl`` arrays (n, T, nu) from per-rod commands (n, T, R, 3) and cable
    commands (n, T, C); with winch commands (n, T, W), those follow: (n, T, nu + W) (what
    :meth:`~identification.simulation.rollout.Roller.run` takes)."""
    act = truth.asm.actuators
    nu = truth.model.nu
    W = 0 if winches is None else winches.shape[-1]
    ctrl = np.zeros((*commands.shape[:2], nu + W))
    has = act >= 0
    ctrl[:, :, act[has]] = commands[:, :, has]
    if cables is not None:
        ctrl[:, :, truth.asm.cable_actuators] = cables
    if winches is not None:
        ctrl[:, :, nu:] = winches
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
    winches: np.ndarray | None = None,
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
        winches: winch commands (n, T, W), or None without winches (then ``roller``
            needs the model's winch plant).
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
        return ctrl_vectors(
            truth, commands[lo:hi], None if cables is None else cables[lo:hi],
            None if winches is None else winches[lo:hi],
        )  # fmt: skip

    roll_and_convert(roller, frames, init, controls, arrays, chunk, done, where)
    return Split(control=commands, cable_control=cables, winch_control=winches, **arrays)


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
            if s.has_states and s.p is not None and s.q is not None
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
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Initial rod states, control commands, cable commands (None without cable
    actuators) and winch commands (None without winches) of one split, seeded by
    (seed, split)."""
    rng = split_rng(spec.seed, split)
    states = sample_initial_conditions(truth, n, rng, spec.initial)
    commands = sample_controls(truth, n, spec.steps, spec.control_std, spec.control_hold, rng)
    cables = sample_cable_commands(truth, n, spec.steps, spec.control_std, spec.control_hold, rng)
    winches = sample_winch_commands(truth, n, spec.steps, spec.control_std, spec.control_hold, rng)
    return states, commands, cables, winches


def generate(spec: GenerateSpec, progress: bool = False) -> GenerateResult:
    """Roll out every split of ``spec`` in MuJoCo; see the module docstring."""
    t0 = time.perf_counter()
    truth = load_truth(spec)
    counts = spec.counts
    total = sum(counts.values()) * spec.steps
    splits: dict[str, Split] = {}
    with (
        Roller(truth.model, spec.threads, truth.asm.mj_winches() if truth.topology.n_winches
               else None) as roller,
        tqdm(total=total, unit="step", unit_scale=True, disable=None if progress else True) as bar,
    ):
        for name, n in counts.items():
            bar.set_description(name)
            states, commands, cables, winches = split_inputs(truth, spec, name, n)
            splits[name] = rollout_split(
                truth, roller, states, commands, spec.chunk, bar, f"{spec.source_name} {name}",
                cables, winches,
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
