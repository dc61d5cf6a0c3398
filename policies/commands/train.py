"""``tensegrity-sr train``: PPO or SAC with Stable-Baselines3 on a (batched) environment."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from tensegrity_env.io_utils import InputError

#: the algorithms of :data:`policies.artifacts.ALGOS` (not imported here: SB3 is slow to import)
ALGO_NAMES = ("ppo", "sac")


def register(sub: Any) -> None:
    p = sub.add_parser(
        "train",
        help="train a PPO or SAC policy on IcosahedronSR-v0 (or any registered env)",
        description=(
            "Train with Stable-Baselines3 on the natively batched environment, "
            "hyperparameters from a YAML file keyed by environment id (rl-zoo3 convention; "
            "default: the shipped policies/hyperparams/<algo>.yml). Writes OUT/model.zip, "
            "OUT/model_vecnormalize.pkl (observation statistics, reused frozen at evaluation), "
            "OUT/model.json (run record), checkpoints in OUT/checkpoints and TensorBoard logs "
            "in OUT/tb (tensorboard --logdir OUT/tb). An interrupted run continues with "
            "--resume."
        ),
    )
    p.add_argument("algo", choices=ALGO_NAMES, help="algorithm")
    p.add_argument("--env", default="IcosahedronSR-v0", help="environment id (default %(default)s)")
    p.add_argument("--model", type=Path, default=None,
                   help="TensegritySR-v0: the identified params file to train on")  # fmt: skip
    p.add_argument("--robot", type=Path, default=None,
                   help="TensegritySR-v0/TensegrityMJ-v0: the robot's MJCF (default: the "
                        "shipped lab 3-bar)")  # fmt: skip
    p.add_argument("--task", default=None,
                   help="TensegritySR-v0/TensegrityMJ-v0: goal or shape (default: the "
                        "hyperparameters' env_kwargs, else goal)")  # fmt: skip
    p.add_argument("-o", "--output", type=Path, default=None,
                   help="run folder (default runs/<algo>_<env>_s<seed>)")  # fmt: skip
    p.add_argument("--timesteps", type=int, default=None,
                   help="budget in env steps (default: n_timesteps of the hyperparameters)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed of model and envs (default 0)")
    p.add_argument("--seeds", default=None,
                   help="several seeds (0-4 or 0,2,7), one run folder each: OUT/s<seed> "
                        "(default OUT runs/<algo>_<env>)")  # fmt: skip
    p.add_argument("--workers", type=int, default=1,
                   help="with --seeds: seeds trained at once, one process each (default 1)")  # fmt: skip
    p.add_argument("--n-envs", type=int, default=None,
                   help="environments stepped together (default: the hyperparameters')")  # fmt: skip
    p.add_argument("--hyperparams", type=Path, default=None,
                   help="YAML file keyed by env id (default: the shipped one)")  # fmt: skip
    p.add_argument("--checkpoint-every", type=int, default=50_000,
                   help="checkpoint period in env steps (default %(default)s)")  # fmt: skip
    p.add_argument("--resume", action="store_true",
                   help="continue the newest checkpoint in the run folder")  # fmt: skip
    p.add_argument("--init", type=Path, default=None,
                   help="fine-tune a trained policy (model.zip): start from its weights and "
                        "statistics, the budget counted from 0, env arguments as given")  # fmt: skip
    p.add_argument("--threads", type=int, default=1,
                   help="physics threads of the batched env, 0 for every core (default 1)")  # fmt: skip
    p.add_argument("--torch-threads", type=int, default=1,
                   help="PyTorch threads (default 1: the networks are small)")  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-tensorboard", action="store_true", help="no TensorBoard logs")
    p.add_argument("-v", "--verbose", type=int, default=0, choices=(0, 1, 2), help="SB3 verbosity")
    p.set_defaults(func=run)


def env_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The environment arguments of ``--model``, ``--robot`` and ``--task`` (files checked)."""
    kw: dict[str, Any] = {}
    for option, value in (("--model", args.model), ("--robot", args.robot)):
        if value is not None:
            if not value.is_file():
                raise InputError(f"{option} {value}: no such file")
            kw[option[2:]] = str(value.resolve())
    if args.task is not None:
        kw["task"] = args.task
    if kw and not args.env.startswith("Tensegrity"):
        raise InputError(f"--model/--robot/--task are options of TensegritySR-v0 and "
                         f"TensegrityMJ-v0, not {args.env}")  # fmt: skip
    if "model" in kw and args.env != "TensegritySR-v0":
        raise InputError(f"--model: {args.env} has no identified model (TensegritySR-v0 has)")
    return kw


def run(args: argparse.Namespace) -> int:
    if args.init is not None:
        if args.seeds is not None:
            raise InputError("--init fine-tunes one policy: give --seed, not --seeds")
        if not args.init.is_file():
            raise InputError(f"--init {args.init}: no such file")
    if args.seeds is not None:
        return run_seeds(args)
    if args.workers != 1:
        raise InputError("--workers needs --seeds (one process per seed)")
    from policies.train import train
    from tensegrity_env.io_utils import check_number, check_output_dir

    out = args.output or Path("runs") / f"{args.algo}_{args.env}_s{args.seed}"
    # a folder holding a run is continued with --resume, never replaced (train() says so)
    check_output_dir(out, force=True, inputs=[args.hyperparams])
    for option, value, low in (("--timesteps", args.timesteps, 1), ("--seed", args.seed, 0),
                               ("--n-envs", args.n_envs, 1), ("--threads", args.threads, 0),
                               ("--checkpoint-every", args.checkpoint_every, 1),
                               ("--torch-threads", args.torch_threads, 1)):  # fmt: skip
        check_number(option, value, low)
    result = train(
        args.algo,
        args.env,
        out,
        timesteps=args.timesteps,
        seed=args.seed,
        n_envs=args.n_envs,
        hyperparams=args.hyperparams,
        checkpoint_every=args.checkpoint_every,
        resume=args.resume,
        threads=args.threads or None,
        torch_threads=args.torch_threads,
        progress=not args.no_progress,
        tensorboard=not args.no_tensorboard,
        verbose=args.verbose,
        command=shlex.join(["tensegrity-sr", *sys.argv[1:]]),
        env_kwargs=env_kwargs(args),
        init=args.init,
    )
    print(
        f"trained {result.timesteps:,} env steps in {result.wall_s:.0f} s: {result.model_path} "
        f"(+ {result.model_path.stem}_vecnormalize.pkl, {result.model_path.stem}.json)"
    )
    return 0


def run_seeds(args: argparse.Namespace) -> int:
    """Train every seed of ``--seeds`` with ``--workers`` processes."""
    from policies.seeds import parse_seeds, train_seeds

    seeds = parse_seeds(args.seeds)
    out = args.output or Path("runs") / f"{args.algo}_{args.env}"
    print(f"training seeds {seeds} with {args.workers} worker(s) into {out}/s<seed>")
    done = train_seeds(
        args.algo, args.env, out, seeds, args.workers, timesteps=args.timesteps,
        n_envs=args.n_envs, hyperparams=args.hyperparams,
        checkpoint_every=args.checkpoint_every, resume=args.resume,
        threads=args.threads or None, tensorboard=not args.no_tensorboard,
        verbose=args.verbose, command=shlex.join(["tensegrity-sr", *sys.argv[1:]]),
        env_kwargs=env_kwargs(args),
    )  # fmt: skip
    for seed, path, steps, wall in done:
        print(f"seed {seed}: {steps:,} env steps in {wall:.0f} s: {path}")
    return 0
