"""Trials per hour of a hyperparameter search with 1 and 2 worker processes on one study.

For each worker count, a fresh journal-file study in a temporary folder runs
``--trials`` PPO trials of ``--timesteps`` env steps on ``IcosahedronSR-v0`` (each
evaluated ``--evaluations`` times; nothing is pruned, so every trial costs the same),
each worker on one PyTorch thread and one physics thread. Prints the wall time and the
trials per hour of each, and the speed-up of 2 workers over 1. The scaling depends on
the free cores: on a machine shared with other jobs it is a lower bound.

    python benchmarks/bench_tune.py --trials 6 --timesteps 16384
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from policies.tuning.objective import TrialSettings, base_entry
from policies.tuning.study import StudyConfig, make_study, start_workers


def trials_per_hour(workers: int, args: argparse.Namespace) -> tuple[float, float]:
    """(wall time [s], trials per hour) of ``args.trials`` trials with ``workers`` workers."""
    with tempfile.TemporaryDirectory(prefix="bench_tune_") as tmp:
        base = base_entry("ppo", "IcosahedronSR-v0", None)
        base["n_envs"] = args.n_envs
        settings = TrialSettings(
            "ppo", "IcosahedronSR-v0", base, Path(tmp), args.timesteps,
            n_evaluations=args.evaluations, eval_episodes=args.eval_episodes,
            tensorboard=False,
        )  # fmt: skip
        # the pruner waits for n_startup finished trials: none is pruned here
        cfg = StudyConfig(settings, "bench", None, args.trials, n_startup=args.trials)
        make_study(cfg)
        t0 = time.perf_counter()
        procs = start_workers(cfg, workers)
        for p in procs:
            p.join()
        wall = time.perf_counter() - t0
        if any(p.exitcode != 0 for p in procs):
            raise SystemExit(f"a worker failed (exit codes {[p.exitcode for p in procs]})")
    return wall, 3600.0 * args.trials / wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=6, help="trials per measurement (default 6)")
    ap.add_argument("--timesteps", type=int, default=16_384, help="env steps per trial")
    ap.add_argument("--n-envs", type=int, default=32, help="environments per trial (default 32)")
    ap.add_argument("--evaluations", type=int, default=2, help="evaluations per trial")
    ap.add_argument("--eval-episodes", type=int, default=2, help="episodes per evaluation")
    ap.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    args = ap.parse_args()
    rows = {}
    for workers in (1, 2):
        wall, rate = trials_per_hour(workers, args)
        rows[workers] = {"wall_s": wall, "trials_per_hour": rate}
        print(f"{workers} worker(s): {args.trials} trials in {wall:.1f} s = {rate:.0f} trials/hour")
    speedup = rows[2]["trials_per_hour"] / rows[1]["trials_per_hour"]
    print(f"2 workers / 1 worker: {speedup:.2f}x")
    if args.json is not None:
        doc = {
            "settings": vars(args) | {"json": str(args.json)},
            "workers": rows,
            "speedup_2_over_1": speedup,
        }
        args.json.write_text(json.dumps(doc, indent=2) + "\n")


if __name__ == "__main__":
    main()
