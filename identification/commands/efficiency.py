"""``tensegrity-sr efficiency``: the paper's data-efficiency experiment on a dataset."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from identification.commands.durations import samples_of, seconds
from identification.defaults import DEFAULT_FRACTIONS
from tensegrity_env.io_utils import InputError, add_force_option, atomic_dir, check_output_dir


def register(sub: Any) -> None:
    p = sub.add_parser(
        "efficiency",
        help="identify from random 100%%..0.01%% of the training transitions (data efficiency)",
        description=(
            "The paper's data-efficiency experiment: fit on random fractions of the training "
            "transitions (several seeds each) and report, per fraction, the number of "
            "transitions, the largest relative parameter error per group and overall (where "
            "the dataset carries ground truth) and the test-split rollout position errors. "
            "Writes efficiency.md, efficiency.json and efficiency.png into the output folder "
            "and prints the table. Without --anchor the parameters are ratios to the first "
            "rod's mass and are compared with the true ratios (the ground truth is never "
            "used to fix the scale)."
        ),
    )
    p.add_argument("dataset", type=Path, help="HDF5 dataset with rod states")
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    p.add_argument(
        "--anchor", action="append", default=[], metavar="NAME=VALUE",
        help="a known parameter value fixing the scale, e.g. mass[rod0]=1.95 (repeatable)",
    )  # fmt: skip
    p.add_argument("--seeds", type=int, default=3, help="random subsets per fraction (default 3)")
    p.add_argument(
        "--fractions", type=float, nargs="+", default=list(DEFAULT_FRACTIONS), metavar="F",
        help="fractions of the training transitions in (0, 1] "
        f"(default {' '.join(f'{f:g}' for f in DEFAULT_FRACTIONS)})",
    )  # fmt: skip
    p.add_argument("--split", default="train", help="split to fit on (default train)")
    p.add_argument("--test-split", default="test", help="split for rollout errors (default test)")
    p.add_argument(
        "--horizon", type=seconds, default=None, metavar="SECONDS",
        help="rollout horizon on the test split, e.g. 2s (default: whole trajectories)",
    )  # fmt: skip
    p.add_argument("--solver", choices=("lstsq", "network"), default="lstsq",
                   help="exact least squares (default) or the paper's linear layer trained on MSE")  # fmt: skip
    add_force_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from identification.data.dataset import read_dataset, read_ground_truth
    from identification.experiments.efficiency import run_efficiency, write_outputs
    from identification.linear.anchors import parse_anchor

    check_output_dir(args.output, args.force, inputs=[args.dataset])
    if args.horizon is not None and not args.horizon > 0:
        raise InputError(f"--horizon must be > 0 s, got {args.horizon}")
    bad = [f for f in args.fractions if not 0 < f <= 1]
    if bad:
        raise InputError(f"--fractions must be in (0, 1], got {bad}")
    if args.seeds < 1:
        raise InputError(f"--seeds must be >= 1, got {args.seeds}")
    anchors = dict(parse_anchor(a) for a in args.anchor)
    dataset = read_dataset(args.dataset, splits=(args.split, args.test_split))
    truth = read_ground_truth(args.dataset)
    if not anchors:
        print(
            "No --anchor given: M, I, K, c, h share one unknown scale, so they are identified "
            "as RATIOS to the first rod's mass"
            + (" and compared with the true ratios." if truth is not None else ".")
            + " Pass e.g. --anchor mass[rod0]=<kg> for absolute values.",
            file=sys.stderr,
        )
    result = run_efficiency(
        dataset,
        truth.params if truth is not None else None,
        anchors=anchors,
        fractions=args.fractions,
        seeds=args.seeds,
        split=args.split,
        test_split=args.test_split,
        horizon=None if args.horizon is None else samples_of(args.horizon, dataset.dt),
        progress=True,
        solver=args.solver,
    )
    with atomic_dir(args.output) as out:  # moved to --output only when complete
        paths = {k: args.output / p.name for k, p in write_outputs(result, out).items()}
    print()
    print(result.markdown())
    if truth is None:
        print("\n(no ground truth in this dataset: parameter errors are not measured)")
    print("\nwrote " + ", ".join(str(p) for p in paths.values()))
    return 0
