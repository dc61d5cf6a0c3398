"""``tensegrity-sr identify`` on end caps of a robot driven by winches.

The winding is fitted to the wound cables' lengths measured between their end caps at
the samples' own times, the motors integrated from the take's start as the command log
says (:func:`~identification.trajectory.winch_fit.fit_winding`): ``v_max``, the motor
lag and each wound cable's rest length at the start. Everything else is the declared
model's (``--params``: its rod mass, cables' stiffness and damping, floor contact). The
split's one trajectory must start at the take's start (the first piece of a take, as
``import-mocap --split`` writes it).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from identification.data.dataset import Dataset
from identification.trajectory.winch_fit import LAGS, fit_winding
from tensegrity_env.io_utils import InputError, StageError
from tensegrity_env.model import Model


def run_winch_end_caps(args: argparse.Namespace, dataset: Dataset) -> int:
    """Identify a winch-driven robot from end caps and its command log; write params.json."""
    if args.params is None:
        raise InputError(f"{args.dataset}: end caps of a robot with winches: give the declared "
                         "model (--params robot.xml): its rod mass fixes the scale")  # fmt: skip
    split = dataset.split(args.split)
    if split.n_trajectories != 1 or split.time is None:
        raise InputError(f"{args.dataset}: split '{args.split}' has {split.n_trajectories} "
                         "trajectories; the winch fit takes one, from the take's start, with its "
                         "sample times")  # fmt: skip
    if split.winch_control is None or not split.has_winch_commands:
        raise InputError(f"{args.dataset}: split '{args.split}' has no winch commands (import the "
                         "take with --commands)")  # fmt: skip
    declared = Model.read(args.params)
    if declared.topology.n_winches != dataset.topology.n_winches:
        raise InputError(f"{args.params}: {declared.topology.n_winches} winches, the dataset's "
                         f"robot {dataset.topology.n_winches}")  # fmt: skip
    steps = np.diff(split.time[0])
    print(f"{args.dataset}: end caps at their own times (median step {np.median(steps) * 1e3:.3g} ms, "
          f"{steps.min() * 1e3:.3g}-{steps.max() * 1e3:.4g} ms), {dataset.topology.n_winches} winches "
          f"commanded: the winding fitted to the wound cables' measured lengths, motor lags "
          f"{', '.join(f'{x:g}' for x in LAGS)} s tried, physics step <= {args.physics_dt:g} s")  # fmt: skip
    t0 = time.perf_counter()
    fit = fit_winding(declared, split.nodes[0], split.time[0], split.winch_control[0], args.physics_dt)
    seconds = time.perf_counter() - t0
    try:
        fit.params.validate(dataset.topology, source="identified parameters")
    except InputError as e:
        raise StageError("the winding fit", f"{e} (not written)", "a longer take") from None
    names = [dataset.topology.springs[s].name for s in dataset.topology.winches]
    print(f"\nIdentified from {np.isfinite(split.nodes[0]).all((-1, -2)).sum()} samples of "
          f"'{args.split}' in {seconds:.1f} s: wound-cable lengths about the winding RMS "
          f"{fit.rms * 1e3:.2f} mm (declared winding {fit.declared_rms * 1e3:.1f} mm)")  # fmt: skip
    print(f"  winch_speed {fit.winch_speed:.5g} m/s (declared {float(declared.params.winch_speed.mean()):.5g}), "
          f"winch_lag {fit.winch_lag:g} s (RMS by lag: "
          + ", ".join(f"{k:g} s {v * 1e3:.2f} mm" for k, v in fit.lag_rms.items()) + ")")  # fmt: skip
    for n, x in zip(names, fit.start_rest, strict=True):
        print(f"  rest_length[{n}] at the start {x:.4g} m")
    lo, hi = declared.params.winch_min.numpy(), declared.params.winch_max.numpy()
    reached = (fit.winding_range[:, 0] <= lo + 1e-9) | (fit.winding_range[:, 1] >= hi - 1e-9)
    unseen = {"stiffness, damping": "the winding fit sees lengths, not forces"}
    if not reached.any():
        why = (f"the fitted winding stays within {fit.winding_range[:, 0].min():.4g}-"
               f"{fit.winding_range[:, 1].max():.4g} m, inside the declared range: no limit is reached")  # fmt: skip
        unseen |= {"winch_min": why, "winch_max": why}
        print(f"  winch range: not identifiable ({why}); kept as declared")
    extra = {
        "identifiability": {"mode": "absolute", "not_identifiable": unseen},
        "provenance": {
            "dataset": str(args.dataset), "split": args.split,
            "method": "winding fitted to measured cable lengths at the sample times",
            "physics_dt_s": args.physics_dt, "cable_length_rms_m": fit.rms,
            "declared_cable_length_rms_m": fit.declared_rms, "fit_seconds": seconds,
            "lag_rms_m": {f"{k:g}": v for k, v in fit.lag_rms.items()},
            "winding_range_m": fit.winding_range.tolist(),
        },
    }  # fmt: skip
    Model(dataset.topology, fit.params, declared.effects, dt=args.physics_dt).save(args.output, extra)
    print(f"\nwrote {args.output}")
    return 0
