"""``tensegrity-sr tune``: hyperparameter search for PPO or SAC with Optuna (rl-zoo3 style)."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from tensegrity_env.io_utils import InputError, protect_inputs

#: the algorithms of :data:`policies.artifacts.ALGOS` (not imported here: SB3 is slow to import)
ALGO_NAMES = ("ppo", "sac")


def register(sub: Any) -> None:
    p = sub.add_parser(
        "tune",
        help="search PPO/SAC hyperparameters with Optuna (TPE, median pruning), local or distributed",
        description=(
            "Search hyperparameters on ENV with Optuna as rl-zoo3 does: TPE sampler, median "
            "pruner on periodic deterministic evaluations, rl-zoo3's PPO/SAC search spaces. "
            "W worker processes (one thread each) share the study, by default in the journal "
            "file OUT/study.journal; with --storage postgresql://... workers on several "
            "machines share one study (run the same command on each). Running the command "
            "again resumes the study. Each trial is a training run in "
            "OUT/trials/trial_<n> (as `train` writes it, TensorBoard included). Writes "
            "OUT/best_<algo>.yml (train --hyperparams), OUT/study.json and the plots "
            "OUT/optimization_history.png, OUT/param_importances.png."
        ),
    )
    p.add_argument("algo", choices=ALGO_NAMES, help="algorithm")
    p.add_argument("--env", default="IcosahedronSR-v0", help="environment id (default %(default)s)")
    p.add_argument("--trials", type=int, default=20,
                   help="stop when the study holds N complete + pruned + running trials (default 20)")  # fmt: skip
    p.add_argument("--workers", type=int, default=1,
                   help="worker processes on this machine (default 1)")  # fmt: skip
    p.add_argument("--storage", default=None,
                   help="database URL (postgresql://user:pass@host/db) or journal file "
                        "(default OUT/study.journal)")  # fmt: skip
    p.add_argument("--study", default=None, help="study name (default <algo>_<env>)")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default runs/tune_<algo>_<env>)")  # fmt: skip
    p.add_argument("--timesteps", type=int, default=200_000,
                   help="training budget per trial in env steps (default %(default)s)")  # fmt: skip
    p.add_argument("--evaluations", type=int, default=4,
                   help="evaluations per trial, where it may be pruned (default %(default)s)")  # fmt: skip
    p.add_argument("--eval-episodes", type=int, default=10,
                   help="episodes per evaluation (default %(default)s)")  # fmt: skip
    p.add_argument("--startup-trials", type=int, default=5,
                   help="random trials before TPE and before pruning (default %(default)s)")  # fmt: skip
    p.add_argument("--hyperparams", type=Path, default=None,
                   help="base YAML the search draws over (default: the shipped one)")  # fmt: skip
    p.add_argument("--enqueue", type=Path, action="append", default=[], metavar="YAML",
                   help="run the settings of this hyperparameter file (its ENV entry) as one "
                        "trial of the study, beside the sampled ones; repeatable")  # fmt: skip
    p.add_argument("--n-envs", type=int, default=None,
                   help="environments stepped together (default: the base hyperparameters')")  # fmt: skip
    p.add_argument("--seed", type=int, default=0,
                   help="trial n trains with seed SEED+n; worker i samples with SEED+i; use "
                        "another SEED on each machine (default 0)")  # fmt: skip
    p.add_argument("--heartbeat", type=int, default=60,
                   help="database heartbeat period in s; a silent trial fails after twice it")  # fmt: skip
    p.add_argument("--no-tensorboard", action="store_true", help="no TensorBoard logs per trial")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def check(args: argparse.Namespace) -> None:
    """One-line errors for values no search can run with."""
    for name in ("workers", "timesteps", "evaluations", "eval_episodes", "heartbeat"):
        if getattr(args, name) < 1:
            raise InputError(f"--{name.replace('_', '-')} must be >= 1")
    for name in ("trials", "startup_trials"):
        if getattr(args, name) < 0:
            raise InputError(f"--{name.replace('_', '-')} must be >= 0")
    if args.n_envs is not None and args.n_envs < 1:
        raise InputError("--n-envs must be >= 1")
    if args.timesteps < args.evaluations:
        raise InputError("--timesteps must be at least --evaluations")
    if args.study is not None and not args.study.strip():
        raise InputError("--study must not be empty")


def run(args: argparse.Namespace) -> int:
    check(args)
    from policies.tuning.objective import TrialSettings, base_entry
    from policies.tuning.report import write_report
    from policies.tuning.study import StudyConfig, make_study, start_workers, storage_label, watch
    from policies.vec import env_spec

    env_spec(args.env)
    out = args.out or Path("runs") / f"tune_{args.algo}_{args.env}"
    protect_inputs(args.hyperparams, args.enqueue)
    base = base_entry(args.algo, args.env, args.hyperparams)
    if args.n_envs is not None:
        base["n_envs"] = args.n_envs
    settings = TrialSettings(
        args.algo, args.env, base, out, args.timesteps, n_evaluations=args.evaluations,
        eval_episodes=args.eval_episodes, seed=args.seed, tensorboard=not args.no_tensorboard,
    )  # fmt: skip
    cfg = StudyConfig(
        settings, args.study or f"{args.algo}_{args.env}", args.storage, args.trials,
        args.startup_trials, args.seed, args.heartbeat,
    )  # fmt: skip
    queued = [enqueued_params(args.algo, args.env, path, base) for path in args.enqueue]
    study = make_study(cfg)  # created once here (fails early on a bad storage)
    label = storage_label(cfg)
    held = len(study.trials)
    if held == 0 and any((out / "trials").glob("trial_*/model.zip")):
        raise InputError(
            f"{out / 'trials'}: holds trials of another study (choose another --out, or the "
            "--storage and --study they belong to)"
        )
    for q in queued:
        for note in q["notes"]:
            print(f"--enqueue {q['file']}: {note}")
        # skip_if_exists: running the command again does not queue the same trial twice
        study.enqueue_trial(q["params"], user_attrs={"enqueued": q["file"]}, skip_if_exists=True)
    print(
        f"study {cfg.study_name!r} in {label}: {held} trial(s) held, running up to "
        f"{args.trials} with {args.workers} worker(s), {args.timesteps:,} env steps each"
    )
    try:
        study = watch(cfg, start_workers(cfg, args.workers), progress=not args.no_progress)
    except KeyboardInterrupt:
        print("interrupted: run the same command again to resume the study")
    record = {
        "algo": args.algo, "env_id": args.env, "timesteps": args.timesteps,
        "n_evaluations": args.evaluations, "eval_episodes": args.eval_episodes,
        "eval_seed": settings.eval_seed, "startup_trials": args.startup_trials,
        "base_hyperparams": base, "sampler": "TPESampler(multivariate=True)",
        "pruner": "MedianPruner", "workers": args.workers, "enqueued": queued,
        "command": shlex.join(["tensegrity-sr", *sys.argv[1:]]),
    }  # fmt: skip
    written = write_report(study, out, args.algo, args.env, label, record)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def enqueued_params(algo: str, env_id: str, path: Path, base: dict[str, Any]) -> dict[str, Any]:
    """The trial parameters of ``--enqueue path``: ``{"file", "params", "notes"}``.

    Raises :class:`InputError` naming the file where its ``env_id`` entry cannot be
    drawn by the search over ``base``.
    """
    from policies.tuning.objective import base_entry
    from policies.tuning.search_space import params_of

    if not path.is_file():
        raise InputError(f"--enqueue {path}: no such file")
    entry = base_entry(algo, env_id, path)
    try:
        params, notes = params_of(algo, entry, base)
    except (ValueError, KeyError, TypeError) as e:
        msg = f"missing {e}" if isinstance(e, KeyError) else str(e)
        raise InputError(f"--enqueue {path}: {msg}") from None
    return {"file": str(path), "params": params, "notes": notes}
