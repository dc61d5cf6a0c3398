"""``tensegrity-sr identify`` on end-cap-only data: the trajectory identification.

Stage 1 smooths the end caps and solves the one-step regression for a start (or takes
the start from ``--params``: a params file or the robot's MJCF); stage 2
fits the parameters and every window's initial state through the engine
(:class:`~identification.trajectory.identifier.TrajectoryIdentifier`), the engine
substepping at ``--physics-dt`` between the measured samples. Parameters are fitted as
logarithms, so masses, inertias, stiffnesses, damping and rest lengths stay positive;
the result is checked against the noise level of the data and against the physical
domain (:meth:`tensegrity_env.params.Params.validate`) before anything is printed as
identified or written.

End caps that reach a floor (:func:`~identification.trajectory.airborne.contact_gate`)
are fitted with ground contact in the model (the floor fit,
:func:`~identification.trajectory.floor_declared.identify_on_floor`), whether or not the data
also hold airborne stretches: the declared model alone, fitted through the impacts,
can diverge.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from identification.commands.declared import declared_model, declared_start, no_other_effects
from identification.commands.durations import describe, samples_of
from identification.commands.effort import two_starts
from identification.commands.two_starts import two_starts_report
from identification.data.dataset import Dataset, read_ground_truth
from identification.data.end_caps import check_caps_seen
from identification.linear.regression import ParameterRow
from identification.report.tables import group_errors, parameter_table, relative_errors
from identification.trajectory.airborne import contact_gate
from identification.trajectory.end_cap_data import TrajectorySettings
from identification.trajectory.floor_declared import (
    FloorIdentification,
    floor_steps,
    identify_on_floor,
)
from identification.trajectory.floor_evidence import FloorEvidence, contact_evidence
from identification.trajectory.identifier import TrajectoryIdentifier
from identification.trajectory.open_loop_check import (
    check_not_worse_than_start,
    check_open_loop,
    open_loop_check,
)
from identification.trajectory.slack_in_data import settle_slack, spring_names
from identification.trajectory.stage_check import (
    POORLY_DETERMINED,
    check_determined,
    check_stage,
    noise_level,
    undetermined,
)
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import substeps_for
from tensegrity_env.io_utils import InputError, StageError
from tensegrity_env.model import Model
from tensegrity_env.params import Params

#: what to try when the fitted model leaves the data open-loop
OPEN_LOOP_ADVICE = ("shorter windows (--window), a smaller --physics-dt, a fit on the free stretches "
                    "only (import-mocap --segments), or 'diagnose'")  # fmt: skip

#: what to try when the fit leaves a parameter undetermined by the data
UNDETERMINED_ADVICE = ("a start near the robot (--params with its MJCF or a params file), "
                       "--effort thorough, or longer trajectories that move every rod")  # fmt: skip

UNITS = {"mass": "kg", "inertia": "kg*m^2", "stiffness": "N/m", "damping": "N*s/m",
         "rest_length": "m", "control_gain": "1", "cable_gain": "N/unit"}  # fmt: skip


#: what the standard errors of a fit on the floor mean (docs/discovery.md measures them)
FLOOR_STDERR_NOTE = (
    "on the floor they come from the error's local curvature, which impacts make "
    "unreliable: they understate the error (read them as lower bounds)"
)


def parameter_rows(
    est: TrajectoryIdentifier | FloorIdentification, anchors: dict[str, float]
) -> list[ParameterRow]:
    """The identify table's rows from a fitted trajectory identifier.

    ``stderr_`` of the fit is relative (the parameters are fitted as logarithms):
    absolute standard errors are ``|value| * relative``. Both perpendicular inertias of a
    rod are one fitted value; the axial one is assumed (``notes_``).
    """
    p = est.params_.numpy()
    topo = est.topology_
    rel = est.stderr_
    ratio = est.mode_ == "ratios"
    rows: list[ParameterRow] = []

    def row(name: str, group: str, el: int, value: float, key: str) -> None:
        if name in est.notes_:
            rows.append(ParameterRow(name, group, el, value, float("nan"), UNITS[group],
                                     "not identifiable", est.notes_[name]))  # fmt: skip
            return
        status = "anchored" if name in anchors else ("ratio" if ratio else "identified")
        se = abs(value) * rel[key] if key in rel else float("nan")
        rows.append(ParameterRow(name, group, el, value, se, UNITS[group], status))

    for r, rod in enumerate(topo.rods):
        row(f"mass[{rod.name}]", "mass", r, float(p["mass"][r]), f"mass[{rod.name}]")
    for r, rod in enumerate(topo.rods):
        for k, ax in enumerate("xyz"):
            row(f"inertia[{rod.name},{ax}]", "inertia", 3 * r + k, float(p["inertia"][r, k]),
                f"inertia_perp[{rod.name}]")  # fmt: skip
    for group in ("stiffness", "damping", "rest_length"):
        for s, spring in enumerate(topo.springs):
            name = f"{group}[{spring.name}]"
            row(name, group, s, float(p[group][s]), name)
    row("control_gain", "control_gain", -1, float(p["control_gain"]), "control_gain")
    for c, s in enumerate(topo.cable_actuators):
        name = f"cable_gain[{topo.springs[s].name}]"
        row(name, "cable_gain", c, float(p["cable_gain"][c]), name)
    return rows


def keep_declared(
    est: TrajectoryIdentifier | FloorIdentification,
    start: Params,
    nodes: np.ndarray,
    effects: list[PhysicalEffect],
    recorded: list[np.ndarray] | None = None,
) -> list[str]:
    """``est`` with its tension-only springs that are slack throughout ``nodes``
    (N, T, 2R, 3) [m], the fitted split (``recorded``: the other splits' end caps)
    settled (:func:`~identification.trajectory.slack_in_data.settle_slack`)
    and each changed parameter noted as not identifiable; returns the springs' names."""
    topo = est.topology_
    est.params_, notes = settle_slack(est.params_, start, nodes, topo, effects, recorded or [])
    est.notes_.update(notes)
    return spring_names(notes)


def run_end_caps(args: argparse.Namespace, dataset: Dataset, anchors: dict[str, float]) -> int:
    """Identify from end caps only, print the table, write params.json."""
    used = [o for o, v in (("--solver network", args.solver == "network"),
                           ("--shared", args.shared), ("--freeze", bool(args.freeze)),
                           ("--fraction", args.fraction is not None),
                           ("--winch-lag", args.winch_lag is not None)) if v]  # fmt: skip
    if dataset.topology.n_winches:
        raise InputError(f"{args.dataset}: the robot has winches; identify takes them from rod "
                         "states only (end caps: identification.linear.smoothed_regression "
                         "with the winding of the command log)")  # fmt: skip
    if used:
        raise InputError(f"{args.dataset}: end caps only; {', '.join(used)} need rod states "
                         "(the trajectory identification fits end caps directly)")  # fmt: skip
    dt = dataset.dt
    split = dataset.split(args.split)
    check_caps_seen(split.nodes, dataset.topology, f"{args.dataset}: split '{args.split}'")
    span = split.n_transitions * dt
    if not (0 < args.physics_dt and args.first_window >= 2 * dt and args.smoothing > 0):
        raise InputError(f"--first-window must span >= 2 samples ({2 * dt:.4g} s), "
                         "--smoothing and --physics-dt must be > 0")  # fmt: skip
    window = min(args.window, span)
    floor, why = contact_gate(split, dataset.topology)
    settings = TrajectorySettings(
        anchors=anchors, smoothing=args.smoothing, seed=args.seed, physics_dt=args.physics_dt,
        fit_window=samples_of(window, dt, 2), floor_windows=args.floor_windows,
        second_start=two_starts(args.effort),
    )  # fmt: skip
    if floor:
        how = (f"the declared model and ground contact fitted on {args.floor_windows} or more "
               f"windows of up to {describe(floor_steps(dt, settings) * dt, dt)}")  # fmt: skip
    else:
        how = (f"trajectory identification on windows growing from "
               f"{describe(args.first_window, dt)} to {describe(window, dt)}")  # fmt: skip
    print(f"{args.dataset}: end caps only at {1 / dt:g} Hz: {how}, physics step "
          f"<= {args.physics_dt:g} s; effort {args.effort}")  # fmt: skip
    start, contact = None, None
    others: list[PhysicalEffect] = []
    if args.params is not None:
        start, contact, others = declared_start(args.params, dataset, args.dataset, anchors)
        print(f"starting from the model in {args.params}"
              + (f", keeping its {', '.join(e.name for e in others)}" if others else ""))  # fmt: skip
    noise = noise_level(split.nodes, rods=True)
    print(f"noise level estimated from the end caps: {noise * 1e3:.3g} mm")
    t0 = time.perf_counter()
    est: TrajectoryIdentifier | FloorIdentification
    effects: list[PhysicalEffect] = []
    evidence: FloorEvidence | None = None
    if floor and split.has_cable_commands:
        raise InputError(f"{args.dataset}: end caps on a floor with cable actuator commands: the "
                         "joint fit with ground contact does not apply cable commands; identify "
                         "from free flight, or from rod states")  # fmt: skip
    if floor:
        print(f"end caps reach a floor ({why}): ground contact is fitted with the declared "
              "model")  # fmt: skip
        est = identify_on_floor(dataset, settings, args.split, start=start, contact=contact,
                                effects=others)  # fmt: skip
        effects = [*est.effects_, est.contact_]
        evidence = contact_evidence(split.nodes, dt, dataset.topology, est.contact_)
    else:
        no_other_effects(args.params, others, "the trajectory fit off the floor")
        est = TrajectoryIdentifier(
            anchors=anchors, window=samples_of(window, dt, 2),
            first_window=samples_of(args.first_window, dt, 2), smoothing=args.smoothing,
            seed=args.seed, progress=True, physics_dt=args.physics_dt, start=start,
            max_iter=args.max_iter,
        ).fit(dataset, args.split)  # fmt: skip
    fit_time = time.perf_counter() - t0
    if start is not None:
        recorded = [s.nodes for name, s in dataset.splits.items() if name != args.split]
        slack = keep_declared(est, start, split.nodes, others, recorded)
        if slack:
            print(f"{len(slack)} tension-only springs are slack throughout the data "
                  f"({', '.join(slack)}): the table's rows say what is written for them")  # fmt: skip
    check_stage("the trajectory fit", est.rms_, noise,
                "shorter windows (--window), a smaller --physics-dt, or 'diagnose' if the data "
                "holds an effect the declared model lacks (contact, drag)")  # fmt: skip
    try:
        est.params_.validate(dataset.topology, source="identified parameters")
    except InputError as e:
        raise StageError("the trajectory fit", f"{e} (not written)",
                         "an --anchor on the parameter, or longer trajectories") from None  # fmt: skip
    rows = parameter_rows(est, anchors)
    check_determined("the trajectory fit", rows, UNDETERMINED_ADVICE)
    check = open_loop_check(Model(dataset.topology, est.params_, tuple(effects), dt=dt), dataset,
                            noise, args.physics_dt)  # fmt: skip
    check_open_loop("the trajectory fit", check, OPEN_LOOP_ADVICE)
    if args.params is not None:
        check_not_worse_than_start("the trajectory fit", Model(dataset.topology, est.params_,
                                   tuple(effects), dt=dt), declared_model(args.params, dataset,
                                   args.dataset), dataset, noise, args.physics_dt)  # fmt: skip
    ratios = est.mode_ == "ratios"
    truth = read_ground_truth(args.dataset)
    truth_params = truth.params if truth is not None else None
    print(f"\nIdentified from the end caps of '{args.split}' in {fit_time:.1f} s: end-cap RMS "
          f"{est.rms_ * 1e3:.3f} mm (noise level {noise * 1e3:.3g} mm)"
          + ("" if est.converged_ else "; the last stage stopped at its iteration limit"))  # fmt: skip
    if ratios:
        print("No anchor given: M, I, K, c, h share one unknown scale; values are RATIOS to "
              f"mass[{dataset.topology.rods[0].name}].")  # fmt: skip
    print(parameter_table(rows, truth_params, ratios))
    if truth_params is not None:
        worst = group_errors(rows, truth_params, ratios)
        print("\nLargest relative error per group: "
              + ", ".join(f"{k} {v:.2e}" for k, v in worst.items()))  # fmt: skip
    extra: dict[str, Any] = {
        "identifiability": {
            "mode": est.mode_, "anchors": anchors, "not_identifiable": est.notes_,
        },
        "uncertainty": {r.name: r.stderr for r in rows if np.isfinite(r.stderr)},
        "provenance": {
            "dataset": str(args.dataset), "split": args.split, "method": "trajectory",
            "window_s": window, "first_window_s": args.first_window,
            "smoothing_s": args.smoothing, "physics_dt_s": args.physics_dt,
            "effort": args.effort,
            "floor_windows": est.stages_[-1]["windows"] if floor else None,
            "floor_window_steps": est.stages_[-1]["window"] if floor else None,
            "end_cap_rms_m": est.rms_, "noise_level_m": noise, "converged": est.converged_,
            "stages": est.stages_, "fit_seconds": fit_time,
        },
    }  # fmt: skip
    if truth_params is not None:
        errs = relative_errors(rows, truth_params, ratios)
        extra["relative_error_vs_ground_truth"] = {
            r.name: e for r, e in zip(rows, errs, strict=True) if np.isfinite(e)
        }
    if check is not None:
        print(check.line())
        extra["provenance"]["open_loop_check"] = check.as_dict()
    poor = undetermined(rows, POORLY_DETERMINED)
    if poor:
        print(f"warning: {len(poor)} parameters poorly determined by the data (standard error "
              f"{POORLY_DETERMINED:g} times the value or more), the worst {poor[0][0]} at "
              f"{poor[0][1]:.3g} times: read their values with care")  # fmt: skip
        extra["provenance"]["poorly_determined"] = dict(poor)
    if isinstance(est, FloorIdentification) and start is None:
        extra["provenance"]["two_starts"] = two_starts_report(est.starts_)
    physics = dt / substeps_for(dt, args.physics_dt)  # the step the fit integrated at
    if effects:
        print("\n" + "\n".join(e.describe() for e in effects))
    if evidence is not None:
        print("what the floor data shows: " + "; ".join(evidence.lines()))
        unseen = {f"ground_contact.{k}": why for k, why in evidence.unseen().items()}
        for name, why in unseen.items():
            print(f"  {name}: {why}")
        extra["identifiability"]["not_identifiable"] = {**est.notes_, **unseen}
        extra["floor_evidence"] = evidence.as_dict()
        print(f"  standard errors: {FLOOR_STDERR_NOTE}")
        extra["identifiability"]["standard_errors"] = FLOOR_STDERR_NOTE
    Model(dataset.topology, est.params_, tuple(effects), dt=physics).save(args.output, extra)
    print(f"\nwrote {args.output}")
    return 0
