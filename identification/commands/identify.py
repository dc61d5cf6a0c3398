"""``tensegrity-sr identify``: fit K, c, l0, M, I, h to a dataset and write params.json."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from identification.commands.declared import add_params_option, declared_model
from identification.commands.durations import samples_of, seconds
from identification.commands.effort import add_effort_option, apply_effort
from tensegrity_env.defaults import PHYSICS_DT
from tensegrity_env.io_utils import (
    InputError,
    StageError,
    add_force_option,
    check_number,
    check_output_file,
)


def register(sub: Any) -> None:
    p = sub.add_parser(
        "identify",
        help="identify spring and rod parameters from a dataset by linear regression",
        description=(
            "Identify per-spring stiffness K, damping c and rest length l0, per-rod mass M "
            "and principal inertia I, and the control gain h by linear regression on the "
            "training split. From motion alone M, I, K, c, h share one scale: pass an "
            "--anchor (e.g. a weighed rod mass) or the result is reported as ratios to the "
            "first rod's mass. Prints the parameter table (with the relative error of each "
            "where the dataset carries ground truth) and one-step and rollout errors on the "
            "test split; writes a versioned params.json. A dataset of end caps only "
            "(motion capture) is identified by trajectory fits through the engine; its sample "
            "times are put on the nominal grid first (dropped frames become gaps). Spans "
            "are times: 0.1s, 100ms or a bare number of seconds."
        ),
    )
    p.add_argument("dataset", type=Path, help="HDF5 dataset written by 'generate' or by the API")
    p.add_argument(
        "-o", "--output", type=Path, default=Path("params.json"),
        help="params file to write (default params.json)",
    )  # fmt: skip
    add_force_option(p)
    p.add_argument(
        "--anchor", action="append", default=[], metavar="NAME=VALUE",
        help="a known parameter value fixing the scale, e.g. mass[rod0]=1.95 (repeatable)",
    )  # fmt: skip
    p.add_argument("--solver", choices=("lstsq", "network"), default="lstsq",
                   help="exact least squares (default) or the paper's linear layer trained on MSE")  # fmt: skip
    p.add_argument("--shared", action="store_true", help="one K, c, l0 and one M, I for all")
    add_params_option(p, "the model to start from: a params.json or the robot's MJCF (.xml); "
                      "with rod states, the fields --freeze keeps; on end caps, where the "
                      "trajectory fit starts (its floor contact too)")  # fmt: skip
    p.add_argument(
        "--freeze", default="", metavar="FIELDS",
        help="comma-separated fields kept from --params, of stiffness, damping, rest_length, "
        "mass, inertia and control_gain (all but control_gain: fit only control_gain)",
    )  # fmt: skip
    p.add_argument("--fraction", type=float, help="fit on this random fraction of training steps")
    p.add_argument("--seed", type=int, default=0, help="seed of the random subset")
    p.add_argument("--split", default="train", help="split to fit on (default train)")
    p.add_argument("--winch-lag", default=None, metavar="SECONDS|auto",
                   help="the winch motors' lag [s] (a robot with winches): a value, or 'auto' to "
                        "search it on the regression's residual; default: the lag of --params, else 0")  # fmt: skip
    p.add_argument("--horizon", type=seconds, default=2.0,
                   help="rollout horizon of the test-split error, e.g. 2s (default 2s)")  # fmt: skip
    q = p.add_argument_group("end-cap-only data (trajectory identification through the engine)")
    q.add_argument("--window", type=seconds, default=1.0,
                   help="longest window of the trajectory fit (default 1s)")  # fmt: skip
    q.add_argument("--smoothing", type=seconds, default=0.1,
                   help="Savitzky-Golay span of the starting regression (default 0.1s)")  # fmt: skip
    q.add_argument("--physics-dt", type=seconds, default=PHYSICS_DT,
                   help=f"longest physics step; the engine substeps between samples (default "
                   f"{PHYSICS_DT:g}s)")  # fmt: skip
    add_effort_option(q, {"--floor-windows": int, "--first-window": seconds})
    p.set_defaults(func=run)


def winch_lag_option(text: str | None, dataset: Any) -> float | str | None:
    """``--winch-lag``: None (not given), ``"auto"`` or a lag >= 0 [s]; one-line errors."""
    if text is None:
        return None
    if not dataset.topology.n_winches:
        raise InputError(f"--winch-lag: the robot of {dataset.path} has no winches")
    if text == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"--winch-lag: {text!r} is neither a time in seconds nor 'auto'") from None
    check_number("--winch-lag", value, 0)
    return value


def run(args: argparse.Namespace) -> int:
    from identification.commands.identify_end_caps import run_end_caps
    from identification.data.dataset import read_dataset, read_ground_truth
    from identification.data.sample_grid import on_nominal_grid
    from identification.linear.anchors import parse_anchor
    from identification.linear.regression import SpringRodIdentifier
    from identification.linear.winch_lag import fit_winch_lag
    from identification.report.tables import (
        error_text,
        group_errors,
        parameter_table,
        relative_errors,
    )
    from identification.trajectory.open_loop_check import check_open_loop, open_loop_check
    from identification.trajectory.stage_check import noise_level
    from tensegrity_env.model import Model

    check_output_file(args.output, args.force, inputs=[args.dataset, args.params])
    check_number("--horizon", args.horizon, 0, strict=True)
    check_number("--seed", args.seed, 0)
    counts = apply_effort(args)
    args.max_iter = counts["max_iter"]
    if args.first_window is None:
        args.first_window = 0.1  # the free-flight fit's first stage [s]
    check_number("--floor-windows", args.floor_windows, 1)
    raw = read_dataset(args.dataset)
    if raw.topology.n_winches and not raw.split(args.split).has_states:
        from identification.commands.identify_winches import run_winch_end_caps

        return run_winch_end_caps(args, raw)  # at the samples' own times, no grid
    dataset, grid = on_nominal_grid(raw)
    if grid.changed:
        print(grid.text(dataset.dt))
    anchors = dict(parse_anchor(a) for a in args.anchor)
    if not dataset.split(args.split).has_states:
        return run_end_caps(args, dataset, anchors)
    init = None
    if args.params is not None:
        init = declared_model(args.params, dataset, args.dataset).params
    freeze = tuple(f for f in args.freeze.split(",") if f)
    if args.fraction is not None and not 0 < args.fraction <= 1:
        raise InputError(f"--fraction must be in (0, 1], got {args.fraction}")
    lag = winch_lag_option(args.winch_lag, dataset)
    t0 = time.perf_counter()

    def identifier(tau: float | None) -> SpringRodIdentifier:
        return SpringRodIdentifier(
            solver=args.solver, shared=args.shared, anchors=anchors, init_params=init,
            freeze=freeze, fraction=args.fraction, seed=args.seed, progress=lag != "auto",
            winch_lag=tau,
        )  # fmt: skip

    if lag == "auto":
        est = fit_winch_lag(dataset, identifier, args.split)
        print(f"winch lag {float(est.winch_lag_[0]):.4g} s: the smallest residual of "
              f"{len(est.lag_search_)} lags tried")  # fmt: skip
    else:
        assert not isinstance(lag, str)  # the one string form, "auto", is handled above
        est = identifier(lag).fit(dataset, args.split)
    fit_time = time.perf_counter() - t0
    try:  # nothing outside the physical domain is written
        est.params_.validate(dataset.topology, source="identified parameters")
    except InputError as e:
        raise StageError("the regression", f"{e} (not written; {est.n_transitions_} "
                         f"transitions of '{args.split}')",
                         "more or longer trajectories in which every spring stretches and every "
                         "rod turns, or --shared") from None  # fmt: skip
    ratios = est.mode_ == "ratios"
    model = Model(dataset.topology, est.params_, dt=dataset.dt)
    # ratios roll out as absolute values do: M, I, K, c and h scaled alike leave every
    # acceleration, gravity's included, unchanged
    check = open_loop_check(model, dataset, noise_level(dataset.split(args.split).nodes, rods=True))
    check_open_loop("the regression", check, "more or longer trajectories in which every "
                    "spring stretches and every rod turns, or --shared")  # fmt: skip
    truth = read_ground_truth(args.dataset)
    truth_params = truth.params if truth is not None else None
    print(f"\nIdentified from {est.n_transitions_} transitions of '{args.split}' in {fit_time:.2f} s "
          f"(solver {args.solver}, condition number {est.condition_number_:.3g}).")  # fmt: skip
    if ratios:
        print("No anchor given: M, I, K, c, h share one unknown scale; values are RATIOS to "
              f"{est.layout_.names[0]} (pass --anchor {est.layout_.names[0]}=<kg> for absolute values).")  # fmt: skip
    print(parameter_table(est.table_, truth_params, ratios))
    if est.unidentifiable():
        print(f"\nNot identifiable from this data: {', '.join(est.unidentifiable())}")
    if truth_params is not None:
        worst = group_errors(est.table_, truth_params, ratios)
        print("\nLargest relative error per group: "
              + ", ".join(f"{k} {v:.2e}" for k, v in worst.items()))  # fmt: skip
    scores: dict[str, Any] = {}
    if "test" in dataset.splits and dataset.split("test").has_states and not ratios:
        try:
            scores = est.score(dataset, "test", horizon=samples_of(args.horizon, dataset.dt))
        except InputError as e:
            print(f"\n(no test errors: {e})")
        else:
            print(
                f"\nTest split: one-step position error "
                f"{error_text(scores['one_step_position_error'], '.3e')}; rollout over "
                f"{scores['horizon_steps']} steps: mean "
                f"{error_text(scores['rollout_mean_position_error'], '.3e')}, final "
                f"{error_text(scores['rollout_final_position_error'], '.3e')}"
            )
    extra: dict[str, Any] = {
        "identifiability": {
            "mode": est.mode_,
            "scale": "absolute (anchored)" if not ratios else f"ratios to {est.layout_.names[0]}",
            "anchors": anchors,
            "frozen": list(freeze),
            "condition_number": est.condition_number_,
            "not_identifiable": est.unidentifiable(),
        },
        "uncertainty": {r.name: r.stderr for r in est.table_ if np.isfinite(r.stderr)},
        "provenance": {
            "dataset": str(args.dataset),
            "split": args.split,
            "transitions": est.n_transitions_,
            "solver": args.solver,
            "fit_seconds": fit_time,
        },
    }
    if scores:
        extra["test_errors"] = {k: v for k, v in scores.items() if k != "rollout_curve"}
    if truth_params is not None:
        errs = relative_errors(est.table_, truth_params, ratios)
        extra["relative_error_vs_ground_truth"] = {
            r.name: e for r, e in zip(est.table_, errs, strict=True) if np.isfinite(e)
        }
    if check is not None:
        print(check.line())
        extra["provenance"]["open_loop_check"] = check.as_dict()
    model.save(args.output, extra)
    print(f"\nwrote {args.output}")
    return 0
