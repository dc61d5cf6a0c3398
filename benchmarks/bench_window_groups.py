"""Speed of a large windowed fit's linearization with its window groups in worker
processes, against the same groups one after the other.

``diagnose``'s final refit on the floor linearizes many windows at once (forward-
difference Jacobians through the engine, :func:`~identification.trajectory.windowed_fit.linearize`).
Above one group's worth of windows the windows are split into groups of equal size;
with ``--jobs`` (the CLI's, default the usable cores) the groups run in forked workers.
This script times one linearization of ``--windows`` floor windows of 0.3 s of the
measured benchmark's floor plant (``measured_plant.py``, 120 Hz, 1 mm noise, the true
model with its contact, every parameter and the contact free), float64, one thread per process. The reference is the same
linearization with the groups one after the other, timed in the same run and in
alternation (best of ``--repeats`` per side); the ratio is printed, never asserted, and
the two results are checked to be identical. ``--states-only``: every parameter held,
as in the fit of the windows' initial states that starts the final refit. ``--trial``:
the windows' errors at a trial point (:func:`~identification.trajectory.window_errors.window_sses`,
one rollout per window) instead of a linearization. ``--steps``: samples per window
(default 0.3 s); ``--calls``: each timing is of that many calls (a trial point's errors
take milliseconds). Each side's CPU time (user + system, the workers' included) is
printed too: forking a worker costs CPU that one process does not spend. The groups go
to the workers whatever their size (the fits keep small ones in-process,
:data:`~identification.trajectory.forked.MIN_FORKED_WORK`: this script measures what a
fork costs against the work of a group)::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_window_groups.py
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_window_groups.py --states-only
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_window_groups.py --windows 96 --jobs 4
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_window_groups.py --windows 94 --steps 4 --trial --calls 20
"""

from __future__ import annotations

import argparse
import resource
import time
import warnings
from dataclasses import replace

import numpy as np
import torch
from measured_plant import Cell, initial_states, simulate, true_model

from identification.trajectory import forked
from identification.trajectory.floor_fit import with_floor
from identification.trajectory.forked import usable_cores, window_groups, window_workers
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.window_errors import window_sses
from identification.trajectory.windowed_fit import group_size, linearize
from identification.trajectory.windows import STATE_KEYS, cut_windows, local_basis
from tensegrity_env.effects import GroundContact
from tensegrity_env.engine import Engine
from tensegrity_env.mjcf import from_mjcf
from tensegrity_env.mjcf_checks import IgnoredFeatureWarning


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--windows", type=int, default=48, help="floor windows (default 48)")
    ap.add_argument("--jobs", type=int, default=usable_cores(),
                    help="worker processes (default: the usable cores)")  # fmt: skip
    ap.add_argument("--repeats", type=int, default=2, help="timings per side (best kept)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the plant's trajectories")
    ap.add_argument("--states-only", action="store_true",
                    help="every parameter held: only the windows' initial states")  # fmt: skip
    ap.add_argument("--trial", action="store_true",
                    help="the windows' errors at a trial point instead of a linearization")
    ap.add_argument("--steps", type=int, default=0,
                    help="samples per window (default: 0.3 s of samples)")  # fmt: skip
    ap.add_argument("--calls", type=int, default=1, help="calls per timing (default 1)")
    args = ap.parse_args(argv)
    if min(args.windows, args.jobs, args.repeats, args.calls) < 1 or args.steps < 0:
        ap.error("--windows, --jobs, --repeats and --calls must be >= 1, --steps >= 0")
    forked.MIN_FORKED_WORK = 0  # every group to the workers: what a fork costs
    torch.set_num_threads(1)
    cell = Cell("floor", 120.0, 1e-3, 0.0, "none", seed=args.seed)
    truth = true_model(cell)
    rng = np.random.default_rng([args.seed, 5])
    clean = simulate(cell, truth, initial_states(cell, 8, rng), 3.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IgnoredFeatureWarning)
        asm = from_mjcf("<plant>", xml=truth.xml)
    contact = next(e for e in asm.declared_effects() if isinstance(e, GroundContact))
    steps = args.steps or round(0.3 * cell.rate)
    noisy = clean.nodes + rng.normal(0.0, cell.noise, clean.nodes.shape)
    grid = {k: getattr(clean, k) for k in STATE_KEYS}
    control = np.zeros((*clean.nodes.shape[:2], asm.topology.n_rods, 3))
    windows = cut_windows(noisy, control, grid, steps)
    windows = windows.take(np.resize(np.arange(windows.size), args.windows))
    declared = ParamVector.at(asm.topology, asm.params)
    declared = replace(declared, free=torch.ones_like(declared.free))  # every parameter fitted
    vec = with_floor(declared, [], contact, None)
    engine = Engine(asm.topology, 1 / cell.rate, substeps=cell.substeps, native=True)  # as the fits
    if args.states_only:  # the contact in the engine, nothing fitted
        vec = replace(declared, free=torch.zeros_like(declared.free))
        engine = engine.with_effects([contact])
    basis = local_basis(vec.axes, True)
    theta = vec.theta0()
    chunk = group_size(basis, theta, windows.size)  # as the fits choose it
    groups = len(window_groups(windows.size, chunk))

    def timed(jobs: int) -> tuple[float, float, torch.Tensor]:
        """Wall and CPU seconds (user + system, finished workers included) and the result."""
        c0, t0 = cpu_seconds(), time.perf_counter()
        with window_workers(jobs):
            for _ in range(args.calls):
                if args.trial:
                    out = torch.as_tensor(window_sses(engine, vec, windows, basis, theta, chunk)[0])
                else:
                    out = linearize(engine, vec, windows, basis, theta, chunk).H_gg
        return time.perf_counter() - t0, cpu_seconds() - c0, out

    serial, parallel, cpu_serial, cpu_parallel = [], [], [], []
    for _ in range(args.repeats):  # alternate, so background load hits both sides alike
        t, c, h_serial = timed(1)
        serial.append(t)
        cpu_serial.append(c)
        t, c, h_parallel = timed(args.jobs)
        parallel.append(t)
        cpu_parallel.append(c)
    same = bool(torch.equal(h_serial, h_parallel))
    what = "states only" if args.states_only else f"{len(theta)} fitted coordinates"
    what += ", trial errors" if args.trial else ", linearization"
    print(f"floor plant, {what} ({args.calls} calls), {windows.size} windows of {steps} samples at {cell.rate:g} Hz "
          f"({cell.substeps} physics steps each), {groups} groups of at most {chunk}")  # fmt: skip
    print(f"  groups one after the other (reference) {min(serial):7.3f} s wall, "
          f"{min(cpu_serial):7.3f} s CPU")  # fmt: skip
    print(f"  groups in {args.jobs} workers              {min(parallel):7.3f} s wall, "
          f"{min(cpu_parallel):7.3f} s CPU  ratios {min(parallel) / min(serial):5.2f} wall, "
          f"{min(cpu_parallel) / min(cpu_serial):5.2f} CPU  identical results: {same}")  # fmt: skip
    return 0 if same else 1


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and its finished children."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


if __name__ == "__main__":
    raise SystemExit(main())
