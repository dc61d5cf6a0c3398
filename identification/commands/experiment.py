"""``tensegrity-sr experiment paper``: the paper's experiments, figures and tables."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from identification.defaults import SCALE_NAMES
from tensegrity_env.io_utils import (
    InputError,
    add_force_option,
    atomic_dir,
    check_number,
    check_output_dir,
)


def register(sub: Any) -> None:
    p = sub.add_parser(
        "experiment",
        help="reproduce the paper's experiments: ours vs Interaction, Interaction+Int, "
        "Koopman+Int; parameters; data efficiency",
        description=(
            "Runs the paper's experiments on the one-rod element and the icosahedron: "
            "MuJoCo ground truth, our identification (parameters against the truth), the "
            "three baselines trained on the same training split, rollout position error "
            "against horizon on the same test split for all four models, and the "
            "data-efficiency sweep (10%, 1%, 0.1%, 0.01% of the training transitions). "
            "Writes errors_*.png, training_*.png, parameters_*.md, efficiency.*, "
            "results.json and results.md into the output folder. --scale small runs in "
            "about a minute or two; --scale full uses the paper's data (1000/200/100 x 736 "
            "steps) and takes a few tens of minutes on a 2-core CPU."
        ),
    )
    p.add_argument("which", choices=("paper",), help="the experiment set (the paper's)")
    p.add_argument("--scale", choices=sorted(SCALE_NAMES), default="small",
                   help="small (CI-sized, default) or full (the paper's data)")  # fmt: skip
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    p.add_argument("--seed", type=int, default=0, help="seed of the data and every model")
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads (default 1: the many small batched ops of "
                   "rollouts and MLP training run fastest on one, above all on a shared machine)")  # fmt: skip
    add_force_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import torch

    from identification.experiments.paper import run_paper
    from identification.experiments.paper_report import claim_checks, write_results

    check_output_dir(args.output, args.force)
    check_number("--seed", args.seed, 0)
    if args.threads < 1:
        raise InputError(f"--threads must be >= 1, got {args.threads}")
    command = f"tensegrity-sr experiment {args.which} --scale {args.scale} -o {args.output}"
    command += (f" --seed {args.seed}" if args.seed else "") + (
        f" --threads {args.threads}" if args.threads != 1 else ""
    )
    threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    try:
        result = run_paper(args.scale, seed=args.seed, progress=True)
    finally:
        torch.set_num_threads(threads)
    with atomic_dir(args.output) as out:  # moved to --output only when complete
        paths = [args.output / p.name for p in write_results(result, out, command)]
    print("\n".join(claim_checks(result)))
    print(f"\nwall time {result.seconds:.0f} s; wrote {len(paths)} files into {args.output}:")
    for path in paths:
        print(f"  {path.name}")
    return 0
