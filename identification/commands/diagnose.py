"""``tensegrity-sr diagnose``: find what the model is missing, name it, add it, report.

Also ``tensegrity-sr plant``: MuJoCo data with an effect the identifier is not told
about (:mod:`identification.simulation.planted`), to try the loop on.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from identification.commands.declared import (
    add_params_option,
    declared_model,
    declared_start,
)
from identification.commands.durations import describe, samples_of, seconds
from identification.commands.effort import (
    COUNTS,
    add_effort_option,
    apply_effort,
    effort_line,
    two_starts,
)
from identification.defaults import (
    FLOOR_WINDOW_S,
    PLANTS,
    STRENGTH_UNITS,
)
from identification.trajectory.forked import usable_cores, window_workers
from tensegrity_env.defaults import EFFECT_NAMES, PHYSICS_DT
from tensegrity_env.io_utils import (
    InputError,
    add_force_option,
    atomic_dir,
    check_number,
    check_output_dir,
    check_output_file,
)

if TYPE_CHECKING:  # the commands import torch, MuJoCo and SciPy when they run, not for --help
    from identification.data.dataset import Dataset
    from identification.discovery.multi_step import MultiStepScorer
    from identification.discovery.one_step import OneStepScorer
    from identification.trajectory.end_cap_data import TrajectorySettings
    from identification.trajectory.fitted_model import FittedModel
    from tensegrity_env.params import Params

#: default window lengths of the trajectory method [s]: selection (``--window``) and the
#: accepted models' fits (``--fit-window``). A fitted initial state absorbs the linear part
#: of a missing constant acceleration, so what selection sees of it grows as the window's
#: length squared (measured in docs/decisions.md)
WINDOW_S = 0.2
FIT_WINDOW_S = 0.3
#: default random selection windows per split of the trajectory method (``--effort default``)
WINDOWS = COUNTS["windows"]


def register(sub: Any) -> None:
    p = sub.add_parser(
        "diagnose",
        help="residual loop: find the missing effect, name it, add it, report errors before/after",
        description=(
            "Fit the declared model, look at what it cannot explain per element (springs, rods, "
            "end caps), try every candidate effect whose physical gate the data passes, keep the "
            "one that lowers the held-out error and the BIC against 'nothing is missing', refit "
            "jointly, repeat. Writes DIR/report.md (with residual PNGs) and DIR/params.json with "
            "an 'effects' section that the engine and the environments load. Every span "
            "(window, horizon, smoothing, physics step) is a time: 0.1s, 100ms or a bare "
            "number of seconds."
        ),
    )
    p.add_argument("dataset", type=Path, help="HDF5 dataset (rod states, or end caps only)")
    add_params_option(p, "the declared model: a params.json, the robot's MJCF (.xml; its "
                      "floor contact, tension-only cables and actuator filter are declared "
                      "effects) or an NTRT YAML model (.yaml; a floor and tension-only cables); "
                      "its rod0 mass fixes the scale, its effects start the model")  # fmt: skip
    p.add_argument("--anchor", action="append", default=[], metavar="NAME=VALUE",
                   help="a known value fixing the scale, e.g. mass[rod0]=1.95 (repeatable)")  # fmt: skip
    p.add_argument("-o", "--output", type=Path, default=Path("diagnose_out"), help="report folder")
    p.add_argument("--max-effects", type=int, default=3, help="most effects to add (default 3)")
    p.add_argument("--horizon", type=seconds, default=1.0, help="rollout horizon (default 1s)")
    p.add_argument("--candidates", default="", metavar="NAMES",
                   help=f"comma-separated subset of the effects (default: all of them: "
                   f"{', '.join(EFFECT_NAMES)})")  # fmt: skip
    p.add_argument("--smoothing", type=seconds, default=0.01,
                   help="Gaussian smoothing std for --method regression on end-cap-only "
                   "data (default 0.01s)")  # fmt: skip
    p.add_argument("--method", choices=("auto", "regression", "trajectory"), default="auto",
                   help="regression: one-step regressions on rod states (exact on clean data); "
                   "trajectory: multi-step fits through the engine on end-cap windows (noisy "
                   "motion capture); auto: trajectory when the dataset holds end caps only")  # fmt: skip
    p.add_argument("--window", type=seconds, default=None,
                   help=f"trajectory method: length of each window (default {WINDOW_S:g}s); on "
                   f"data that never leaves the floor, given, also of the floor fits' windows "
                   f"(default there: up to {FLOOR_WINDOW_S:g}s, shortened where the data shows "
                   "the windows' states cannot be fitted that long)")  # fmt: skip
    add_effort_option(p, {"--windows": int, "--fit-windows": int, "--floor-windows": int,
                          "--final-floor-windows": int, "--final-floor-window": seconds,
                          "--final-iterations": int, "--fit-window": seconds})  # fmt: skip
    p.add_argument("--physics-dt", type=seconds, default=PHYSICS_DT,
                   help=f"trajectory method: longest physics step; the engine substeps between "
                   f"samples (default {PHYSICS_DT:g}s)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed of the window draws (default 0)")
    cores = usable_cores()
    p.add_argument("--jobs", type=int, default=cores,
                   help="worker processes: candidates fitted at once, and the window groups of "
                   f"a large fit (default: the cores this process may use, here {cores}; 1: one "
                   "after the other); the results do not depend on it")  # fmt: skip
    add_force_option(p)
    p.set_defaults(func=run)

    q = sub.add_parser(
        "plant",
        help="MuJoCo data with an undeclared effect (contact, drag, slack cables, joint damping) to diagnose",
        description="Write a MuJoCo dataset of the icosahedron with one effect the model "
        "does not declare, the effect and its strength recorded in the ground truth. "
        "Strengths: " + "; ".join(
            f"{k}: {STRENGTH_UNITS[k] or 'clean control'}"
            + "".join(f", {name} {value:g}" for name, value in v.items() if k != "none")
            for k, v in PLANTS.items()) + ".",
    )  # fmt: skip
    q.add_argument("effect", choices=list(PLANTS), metavar="EFFECT",
                   help=f"the planted effect: {', '.join(PLANTS)}")  # fmt: skip
    q.add_argument("--strength", default="moderate",
                   help="weak, moderate, strong or a number in the effect's unit (default "
                   "moderate)")  # fmt: skip
    q.add_argument("--noise", type=float, default=0.0, help="end-cap noise std [m] (e.g. 0.001)")
    q.add_argument("--seed", type=int, default=0,
                   help="seed of the initial conditions and the noise (default 0)")  # fmt: skip
    q.add_argument("--n-train", type=int, default=8, help="train trajectories (default 8)")
    q.add_argument("--n-val", type=int, default=4, help="val trajectories (default 4)")
    q.add_argument("--n-test", type=int, default=4, help="test trajectories (default 4)")
    q.add_argument("--steps", type=int, default=1000,
                   help="samples per trajectory (default 1000)")  # fmt: skip
    q.add_argument("-o", "--output", type=Path, required=True, help="dataset file to write")
    add_force_option(q)
    q.set_defaults(func=run_plant)


def run_plant(args: argparse.Namespace) -> int:
    from identification.data.dataset import write_dataset
    from identification.simulation.planted import PlantSpec, planted_dataset

    check_output_file(args.output, args.force)
    try:
        strength: str | float = float(args.strength)
    except ValueError:
        strength = args.strength
    spec = PlantSpec(effect=args.effect, strength=strength, noise=args.noise, seed=args.seed,
                     n_train=args.n_train, n_val=args.n_val, n_test=args.n_test, steps=args.steps)  # fmt: skip
    data = planted_dataset(spec)
    write_dataset(args.output, data.dataset, data.ground_truth)
    print(f"wrote {args.output} ({spec.label}; planted effect recorded in ground_truth)")
    return 0


def run(args: argparse.Namespace) -> int:
    import torch

    from identification.commands.two_starts import two_starts_report
    from identification.data.dataset import read_dataset, read_ground_truth
    from identification.data.end_caps import check_caps_seen
    from identification.data.sample_grid import on_nominal_grid
    from identification.discovery.choose import choose_scorer, uses_trajectories
    from identification.discovery.loop import EffectDiscovery
    from identification.discovery.multi_step import MultiStepScorer
    from identification.discovery.open_loop import (
        check_against_start,
        keep_not_diverged,
        keep_predicting,
    )
    from identification.discovery.report import fmt_unit, ratio, write_params, write_report
    from identification.trajectory.floor_evidence import floor_evidence
    from identification.trajectory.slack_in_data import spring_names

    check_output_dir(args.output, args.force, inputs=[args.dataset, args.params])
    apply_effort(args)
    check_number("--max-effects", args.max_effects, 0)
    check_number("--horizon", args.horizon, 0, strict=True)
    check_number("--smoothing", args.smoothing, 0, strict=True)
    check_number("--seed", args.seed, 0)
    check_number("--jobs", args.jobs, 1)
    check_number("--floor-windows", args.floor_windows, 1)
    check_number("--final-floor-windows", args.final_floor_windows, 0)
    check_number("--final-iterations", args.final_iterations, 0)
    torch.set_num_threads(1)  # small tensors: threads only add overhead
    raw, grid = on_nominal_grid(read_dataset(args.dataset))
    if grid.changed:
        print(grid.text(raw.dt))
    for name, split in raw.splits.items():
        check_caps_seen(split.nodes, raw.topology, f"{args.dataset}: split '{name}'")
    multi_step = uses_trajectories(raw, args.method)
    if multi_step and any(s.has_cable_commands for s in raw.splits.values()):
        raise InputError(f"{args.dataset}: cable actuator commands: the trajectory method of "
                         "diagnose does not apply them (identify does, in free flight)")  # fmt: skip
    names = [n for n in args.candidates.split(",") if n] or None
    bad = [n for n in names or [] if n not in EFFECT_NAMES]
    if bad:
        raise InputError(
            f"--candidates: unknown effect(s) {bad} (known: {', '.join(EFFECT_NAMES)})"
        )
    dataset, scorer = choose_scorer(raw, args.method, lambda d: one_step_scorer(args, d),
                                    lambda d: multi_step_scorer(args, d), args.smoothing)  # fmt: skip
    t0 = time.perf_counter()
    slack: dict[str, str] = {}  # parameter -> why, for the springs slack throughout
    # the report is assembled in a temporary folder, moved to --output only when complete
    with atomic_dir(args.output) as out:
        loop = EffectDiscovery(scorer, args.max_effects, names, plots=out, jobs=args.jobs)
        # candidates may fit badly (judged); a large fit's window groups use the --jobs workers
        with np.errstate(invalid="ignore", divide="ignore"), window_workers(args.jobs):
            result = loop.fit(dataset).result_
            # nothing is written for a model that leaves the data open-loop
            result = keep_not_diverged(result, scorer, dataset, args.physics_dt)
            # nor one that predicts held-out motion worse than a model before it
            result = keep_predicting(result, scorer, dataset, args.physics_dt)
            # nor one that predicts it worse at every horizon than the model it started from
            if args.params is not None:
                declared = declared_model(args.params, dataset, args.dataset)
                check_against_start(result, scorer, dataset, args.physics_dt, declared)
                slack = settle_slack_springs(result, declared.params, dataset)
        # nothing outside the physical domain is written (one line naming the field)
        result.model.model.params.validate(dataset.topology, "diagnose's model")
        truth = read_ground_truth(args.dataset)
        floors = [h for e in result.model.effects if (h := e.floor_height()) is not None]
        evidence = [floor_evidence(dataset.split("train").nodes, dataset.dt, dataset.topology,
                                   h) for h in floors]  # fmt: skip
        sections = [e.markdown() for e in evidence]
        if slack:
            sections.append(slack_markdown(result.model, slack))
        report = write_report(result, out, str(args.dataset),
                              None if truth is None else truth.effects, sections)  # fmt: skip
        extra: dict[str, Any] = {"dataset": str(args.dataset)}
        if slack:
            extra["slack_springs"] = slack
        if evidence:
            extra["floor_evidence"] = evidence[0].as_dict()
        if multi_step:
            extra["method"] = "trajectory"
            assert isinstance(scorer, MultiStepScorer)  # narrowing: multi_step says so
            if scorer.data.on_floor and args.params is None:
                extra["two_starts"] = two_starts_report(scorer.data.starts)
        extra["seconds"] = time.perf_counter() - t0
        params = write_params(result, out / "params.json", extra)
    report, params = args.output / report.name, args.output / params.name
    if slack:
        slack_names = ", ".join(spring_names(slack))
        print(f"tension-only springs slack throughout the training data: {slack_names} "
              "(the report's notes say what is written for them)")  # fmt: skip
    print(f"\nadded: {', '.join(result.model.names) or 'nothing'}")
    for e in result.model.effects:
        print(f"  {e.describe()}")
    b, f = result.baseline_test, result.final_test
    print("test errors: " + "; ".join(
        f"{label} {fmt_unit(b[k], unit)} -> {fmt_unit(f[k], unit)} ({ratio(b[k], f[k])})"
        for k, (label, unit) in result.test_labels.items() if k in b and k in f))  # fmt: skip
    if result.unexplained:
        print(f"unexplained: {result.unexplained}")
    print(f"wrote {report} and {params}")
    return 0


def settle_slack_springs(result: Any, declared: Params, dataset: Dataset) -> dict[str, str]:
    """``result``'s model (a :class:`~identification.discovery.loop.DiscoveryResult`) with
    its tension-only springs that are slack throughout the training split settled
    (:func:`~identification.trajectory.slack_in_data.settle_slack`) and their standard
    errors dropped; returns the notes (parameter name -> why)."""
    from identification.trajectory.slack_in_data import settle_slack

    fitted = result.model
    recorded = [s.nodes for name, s in dataset.splits.items() if name != "train"]
    params, notes = settle_slack(fitted.params, declared, dataset.split("train").nodes,
                                 dataset.topology, fitted.effects, recorded)  # fmt: skip
    if notes:
        result.model = replace(fitted, model=fitted.model.replace(params=params),
                               uncertainty={k: v for k, v in fitted.uncertainty.items()
                                            if k not in notes})  # fmt: skip
    return notes


def slack_markdown(fitted: FittedModel, notes: dict[str, str]) -> str:
    """The report's section on the springs :func:`settle_slack_springs` settled
    (``notes``: its notes), with the values written."""
    index = {s.name: i for i, s in enumerate(fitted.model.topology.springs)}
    rows = []
    for name, why in notes.items():
        group, _, spring = name.partition("[")
        value = float(getattr(fitted.params, group)[index[spring[:-1]]])
        rows.append(f"| {name} | {value:.6g} | {why} |")
    return "\n".join(["### Tension-only springs slack throughout the data", "",
                      "| parameter | written | why |", "|---|---|---|", *rows])  # fmt: skip


def one_step_scorer(args: argparse.Namespace, dataset: Dataset) -> OneStepScorer:
    """Regressions on rod states, from ``--params``' effects if given."""
    from identification.discovery.library import FitSettings
    from identification.discovery.one_step import OneStepScorer
    from identification.linear.anchors import parse_anchor
    from tensegrity_env.effects.base import PhysicalEffect

    anchors = dict(parse_anchor(a) for a in args.anchor)
    start: list[PhysicalEffect] = []
    if args.params is not None:
        model = declared_model(args.params, dataset, args.dataset)
        anchors.setdefault(f"mass[{model.topology.rods[0].name}]", float(model.params.mass[0]))
        start = list(model.effects)
    return OneStepScorer(FitSettings(anchors=anchors), args.horizon, start)


def window_header(dataset: Dataset, s: TrajectorySettings) -> str:
    """The windows the trajectory fits use on ``dataset``, as they will be cut (one line)."""
    from identification.trajectory.floor_declared import floor_steps, on_floor

    dt = dataset.dt
    if on_floor(dataset):
        floor = floor_steps(dt, s)
        final = s.final_floor_window or floor
        up_to = "" if s.floor_window > 0 else "up to "
        how = (f"on the floor: windows of {up_to}{describe(floor * dt, dt)}; final refit on "
               f"windows of {up_to}{describe(final * dt, dt)}")  # fmt: skip
    else:
        how = (f"windows of {describe(s.window * dt, dt)}; final fit on windows of "
               f"{describe((s.fit_window or s.window) * dt, dt)}")  # fmt: skip
    return f"{how}; physics step <= {s.physics_dt:g} s"


def multi_step_scorer(args: argparse.Namespace, dataset: Dataset) -> MultiStepScorer:
    """Windowed trajectory fits on end caps, from ``--params``' declared model if given."""
    from identification.discovery.multi_step import MultiStepScorer
    from identification.linear.anchors import parse_anchor
    from identification.trajectory.end_cap_data import TrajectorySettings

    anchors = dict(parse_anchor(a) for a in args.anchor)
    start, contact = None, None
    others: list[Any] = []
    if args.params is not None:
        start, contact, others = declared_start(args.params, dataset, args.dataset, anchors)
    dt = dataset.dt
    apply_effort(args)
    fit_span = FIT_WINDOW_S if args.fit_window is None else args.fit_window
    final_span = 0.0 if args.final_floor_window is None else args.final_floor_window
    span = WINDOW_S if args.window is None else args.window
    if span < 2 * dt or args.windows < 1 or args.fit_windows < 1:
        raise InputError(f"--window must span >= 2 samples ({2 * dt:.4g} s at {1 / dt:g} Hz), "
                         "--windows and --fit-windows >= 1")  # fmt: skip
    if 0 < final_span < 2 * dt:
        raise InputError(f"--final-floor-window must span >= 2 samples ({2 * dt:.4g} s at "
                         f"{1 / dt:g} Hz), or be 0 (as the joint fit's)")  # fmt: skip
    if 0 < fit_span < 2 * dt:
        raise InputError(f"--fit-window must span >= 2 samples ({2 * dt:.4g} s at {1 / dt:g} "
                         "Hz), or be 0 (the --window)")  # fmt: skip
    if not 0 < args.physics_dt:
        raise InputError("--physics-dt must be > 0")
    window = samples_of(span, dt, 2)
    fit_window = samples_of(fit_span, dt, 2) if fit_span > 0 else 0
    final_floor_window = samples_of(final_span, dt, 2) if final_span > 0 else 0
    floor_window = 0 if args.window is None else window
    settings = TrajectorySettings(anchors=anchors, window=window, train_windows=args.windows,
                                  val_windows=args.windows, test_windows=args.windows,
                                  fit_windows=args.fit_windows, fit_window=fit_window,
                                  floor_windows=args.floor_windows,
                                  final_floor_windows=args.final_floor_windows,
                                  final_floor_window=final_floor_window,
                                  floor_window=floor_window, final_iter=args.final_iterations,
                                  seed=args.seed, physics_dt=args.physics_dt,
                                  second_start=two_starts(args.effort))  # fmt: skip
    print(window_header(dataset, settings))
    print(effort_line(args, ("windows", "fit_windows", "floor_windows", "final_floor_windows",
                             "final_iterations")))  # fmt: skip
    return MultiStepScorer(settings, args.horizon, start, contact=contact, jobs=args.jobs,
                           effects=others)  # fmt: skip
