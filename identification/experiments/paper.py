"""The paper's experiments in one run: ours against three baselines, parameters, data efficiency.

For the one-rod element and the icosahedron (:data:`ASSEMBLIES`), :func:`run_paper`

1. generates MuJoCo ground truth (train / val / test splits, no control forces);
2. identifies the parameters with our engine
   (:class:`~identification.linear.regression.SpringRodIdentifier`, rod 0 weighed as the scale
   anchor) and tabulates them against the truth;
3. trains the baselines of :mod:`identification.experiments.baselines` (Interaction,
   Interaction+Int, Koopman+Int) on the same training split, early-stopping on val;
4. measures every model on the same test split: one-step errors and the mean rod
   position error of fed-back rollouts against horizon (the paper's error figures);

then runs the data-efficiency sweep of :mod:`identification.experiments.efficiency` on the
icosahedron (10 %, 1 %, 0.1 %, 0.01 % of the training transitions), and fits both Koopman
models on the same fractions (:func:`koopman_requirement`): the baseline's generic
polynomial dictionary, and the ablation whose dictionary contains the spring law (it
can express the physics exactly, so what separates it from ours is the data it needs).
:mod:`identification.experiments.paper_report` writes the figures and ``results.md``.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from identification.data.dataset import Dataset
from identification.experiments.baselines import (
    ConstantVelocity,
    EnginePredictor,
    Interaction,
    InteractionInt,
    KoopmanConfig,
    KoopmanInt,
    Predictor,
    TrainConfig,
)
from identification.experiments.baselines.evaluate import one_step_errors, rollout_error_curve
from identification.experiments.baselines.koopman import BASES
from identification.experiments.efficiency import EfficiencyResult, run_efficiency
from identification.linear.regression import ParameterRow, SpringRodIdentifier
from identification.report.tables import group_errors
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params

ASSEMBLIES: tuple[str, ...] = ("element", "icosahedron")
#: The paper's baselines (the targets are measured against these).
BASELINES: tuple[str, ...] = ("Interaction", "Interaction+Int", "Koopman+Int")
#: Koopman+Int with the spring law in its dictionary: shows what the basis contributes.
ABLATION = BASES["spring_law"]
MODELS: tuple[str, ...] = ("Ours", *BASELINES, ABLATION)
REFERENCE = "constant velocity"
EFFICIENCY_FRACTIONS: tuple[float, ...] = (0.1, 0.01, 0.001, 0.0001)


@dataclass(frozen=True)
class Scale:
    """How big one run is.

    Attributes:
        name: ``small`` (CI-sized) or ``full`` (the paper's data).
        preset: the :data:`identification.defaults.PRESETS` entry of both assemblies.
        train: hyperparameters of the two MLP baselines.
        koopman: hyperparameters of Koopman+Int (the ablation uses them with the
            spring-law basis at degree 2).
        efficiency_seeds: random subsets per fraction in the efficiency sweep.
        one_step: test transitions for the one-step errors.
    """

    name: str
    preset: str
    train: TrainConfig
    koopman: KoopmanConfig
    efficiency_seeds: int
    one_step: int


SCALES: dict[str, Scale] = {
    "small": Scale(
        name="small",
        preset="small",
        train=TrainConfig(hidden=64, layers=2, lr=3e-3, batch=128, epochs=12, patience=4,
                          max_train=None, max_val=None),
        koopman=KoopmanConfig(max_train=None, max_val=None),
        efficiency_seeds=1,
        one_step=5_000,
    ),
    "full": Scale(
        name="full",
        preset="paper",
        train=TrainConfig(hidden=128, layers=2, lr=2e-3, batch=128, epochs=30, patience=5,
                          max_train=100_000, max_val=20_000),
        koopman=KoopmanConfig(max_train=200_000, max_val=20_000),
        efficiency_seeds=3,
        one_step=20_000,
    ),
}  # fmt: skip


@dataclass
class AssemblyResult:
    """Everything measured on one assembly.

    Attributes:
        name: ``element`` or ``icosahedron``.
        counts: trajectories per split and transitions per trajectory.
        dt: time step [s].
        curves: model -> mean rod position error against horizon, (T+1,) [m].
        one_step: model -> one-step errors (position [m], velocity [m/s],
            angular_velocity [rad/s]).
        training: baseline -> its training curve and hyperparameters.
        parameters: our identified parameter rows.
        truth: the ground-truth parameters.
        group_errors: largest relative error per parameter group (ours).
        seconds: stage -> wall time [s].
    """

    name: str
    counts: dict[str, int]
    dt: float
    curves: dict[str, np.ndarray]
    one_step: dict[str, dict[str, float]]
    training: dict[str, dict[str, Any]]
    parameters: list[ParameterRow]
    truth: Params
    group_errors: dict[str, float]
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def horizon(self) -> int:
        return len(next(iter(self.curves.values()))) - 1


@dataclass
class ExperimentResult:
    """The whole run: per-assembly results, the efficiency sweep and provenance."""

    scale: Scale
    assemblies: dict[str, AssemblyResult]
    efficiency: EfficiencyResult | None
    koopman_requirement: dict[str, list[dict[str, float]]]
    seconds: float
    machine: str
    seed: int


def load_average() -> float:
    """The 1-minute load average (NaN where the OS has none)."""
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def machine_description(load_start: float) -> str:
    """Cores, CPU, library versions and load (start and end of the run), one line."""
    cpu = platform.processor() or platform.machine()
    return (
        f"{os.cpu_count()}-core CPU ({cpu}), {platform.system()}, Python "
        f"{platform.python_version()}, torch {torch.__version__} (CPU), no GPU; 1-minute "
        f"load average {load_start:.1f} at the start and {load_average():.1f} at the end "
        "(other jobs share the cores)"
    )


def baselines(scale: Scale) -> list[Any]:
    """Fresh, unfitted baselines (and the Koopman ablation) with the settings of ``scale``."""
    return [
        Interaction(scale.train),
        InteractionInt(scale.train),
        KoopmanInt(scale.koopman),
        KoopmanInt(spring_law_config(scale.koopman)),
    ]


def spring_law_config(config: KoopmanConfig) -> KoopmanConfig:
    """The ablation's settings: the spring-law dictionary at degree 2, else ``config``."""
    return replace(config, basis="spring_law", degree=2)


def _training_record(model: Any) -> dict[str, Any]:
    cfg = model.config.to_dict()
    return {"config": cfg, "history": model.history_.to_dict()}


def run_assembly(
    name: str, scale: Scale, seed: int, step: Callable[[str], None]
) -> tuple[AssemblyResult, Dataset, Params]:
    """Steps 1–4 of the module docstring for one assembly; ``step`` reports progress."""
    seconds: dict[str, float] = {}
    t = time.perf_counter()
    step(f"{name}: generate")
    dataset, gt = generate_dataset(GenerateSpec.from_preset(scale.preset, assembly=name, seed=seed))
    seconds["generate"] = time.perf_counter() - t
    split_counts = {s: dataset.split(s).n_trajectories for s in ("train", "val", "test")}
    counts = {**split_counts, "steps": dataset.split("train").n_transitions}

    t = time.perf_counter()
    step(f"{name}: identify (ours)")
    anchors = {"mass[rod0]": float(gt.params.mass[0])}  # a weighed rod fixes the scale
    est = SpringRodIdentifier(anchors=anchors).fit(dataset)
    seconds["Ours"] = time.perf_counter() - t
    models: list[Predictor] = [EnginePredictor(est.engine(), est.params_, "Ours")]
    training: dict[str, dict[str, Any]] = {}
    for model in baselines(scale):
        step(f"{name}: train {model.name}")
        t = time.perf_counter()
        model.fit(dataset)
        seconds[model.name] = time.perf_counter() - t
        training[model.name] = _training_record(model)
        models.append(model)
    models.append(ConstantVelocity(dataset.dt))

    step(f"{name}: evaluate")
    t = time.perf_counter()
    test = dataset.split("test")
    curves, one_step = {}, {}
    for model in models:
        one_step[model.name] = one_step_errors(model, test, n=scale.one_step, seed=seed)
        curves[model.name] = rollout_error_curve(model, test)
    seconds["evaluate"] = time.perf_counter() - t
    result = AssemblyResult(
        name=name,
        counts=counts,
        dt=float(dataset.dt),
        curves=curves,
        one_step=one_step,
        training=training,
        parameters=list(est.table_),
        truth=gt.params,
        group_errors=group_errors(est.table_, gt.params),
        seconds=seconds,
    )
    return result, dataset, gt.params


def koopman_requirement(
    dataset: Dataset, scale: Scale, fractions: tuple[float, ...], seed: int
) -> dict[str, list[dict[str, float]]]:
    """Both Koopman models fitted on random fractions of the training transitions.

    Returns, per model name and fraction: ``fraction``, ``n_transitions``, the test
    one-step velocity error [m/s] and the rollout position error at the end of the test
    trajectories and its mean over the horizon [m].
    """
    total = dataset.split("train").n_trajectories * dataset.split("train").n_transitions
    test = dataset.split("test")
    out: dict[str, list[dict[str, float]]] = {}
    for config in (scale.koopman, spring_law_config(scale.koopman)):
        rows = []
        for f in fractions:
            n = max(1, round(f * total))
            model = KoopmanInt(replace(config, max_train=n, seed=seed)).fit(dataset)
            curve = rollout_error_curve(model, test)
            rows.append(
                {
                    "fraction": f,
                    "n_transitions": n,
                    "one_step_velocity": one_step_errors(model, test, scale.one_step, seed)[
                        "velocity"
                    ],
                    "rollout_final": float(curve[-1]),
                    "rollout_mean": float(np.mean(curve)),
                }
            )
        out[BASES[config.basis]] = rows
    return out


def run_paper(
    scale: str | Scale = "small", seed: int = 0, progress: bool = True
) -> ExperimentResult:
    """Run every experiment of the paper at ``scale`` (see the module docstring)."""
    if isinstance(scale, str):
        if scale not in SCALES:
            raise InputError(f"--scale: unknown scale '{scale}' (choose from {sorted(SCALES)})")
        scale = SCALES[scale]
    t0, load0 = time.perf_counter(), load_average()
    assert ASSEMBLIES[-1] == "icosahedron"
    per_assembly = 2 + len(MODELS) - 1 + 1  # generate, ours, baselines, evaluate
    total = len(ASSEMBLIES) * per_assembly + 2
    results: dict[str, AssemblyResult] = {}
    with tqdm(total=total, desc="experiment", unit="stage", disable=not progress) as bar:
        first = [True]

        def step(label: str) -> None:
            if not first[0]:
                bar.update(1)
            first[0] = False
            bar.set_postfix_str(label)

        for name in ASSEMBLIES:  # the icosahedron last: its data serve the sweeps below
            results[name], dataset, truth = run_assembly(name, scale, seed, step)
        step("icosahedron: data efficiency (ours)")
        efficiency = run_efficiency(
            dataset,
            truth,
            anchors={"mass[rod0]": float(truth.mass[0])},
            fractions=EFFICIENCY_FRACTIONS,
            seeds=scale.efficiency_seeds,
        )
        step("icosahedron: data requirement (Koopman models)")
        koopman = koopman_requirement(dataset, scale, EFFICIENCY_FRACTIONS, seed)
        bar.update(1)
        bar.set_postfix_str("done")
    return ExperimentResult(
        scale=scale,
        assemblies=results,
        efficiency=efficiency,
        koopman_requirement=koopman,
        seconds=time.perf_counter() - t0,
        machine=machine_description(load0),
        seed=seed,
    )
