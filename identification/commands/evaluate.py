"""``tensegrity-sr evaluate``: long-horizon error of identified engines against a dataset."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from tensegrity_env.io_utils import (
    InputError,
    add_force_option,
    atomic_dir,
    atomic_write_text,
    check_output_dir,
)


def register(sub: Any) -> None:
    p = sub.add_parser(
        "evaluate",
        help="long-horizon position/orientation error of params files against a dataset split",
        description=(
            "Roll the engine out open-loop (with the recorded control forces) from the first "
            "state of every trajectory of a split, once per params file, and report the mean rod "
            "position and orientation error at 100, 1000, 2000, 5000, 10000 and 20000 steps as a "
            "markdown table and a plot (the paper's generalization figure)."
        ),
    )
    p.add_argument("dataset", type=Path, help="HDF5 dataset with rod states")
    p.add_argument("--params", type=Path, action="append", required=True,
                   help="params file to evaluate (repeatable)")  # fmt: skip
    p.add_argument(
        "--label", action="append", default=[], help="name per --params (default: file stem)"
    )
    p.add_argument("--split", default="test", help="split to evaluate (default test)")
    p.add_argument("-o", "--output", type=Path, default=Path("evaluation"),
                   help="output folder (default evaluation)")  # fmt: skip
    add_force_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from identification.data.dataset import read_dataset
    from identification.experiments.long_horizon import (
        checkpoint_table,
        long_horizon_errors,
        plot_long_horizon,
    )
    from tensegrity_env.engine import Engine
    from tensegrity_env.model import Model

    check_output_dir(args.output, args.force, inputs=[args.dataset, *args.params])
    dataset = read_dataset(args.dataset, splits=(args.split,))
    split = dataset.split(args.split)
    if not split.has_states:
        raise InputError(
            f"{args.dataset}: split '{args.split}' has no rod states to compare against"
        )
    labels = args.label or [p.stem for p in args.params]
    if len(labels) != len(args.params):
        raise InputError("give one --label per --params")
    curves = {}
    for label, path in zip(labels, args.params, strict=True):
        model = Model.load(path, dt=dataset.dt)
        if not model.topology.same_as(dataset.topology):
            raise InputError(f"{path}: topology differs from {args.dataset}")
        curves[label] = long_horizon_errors(Engine(model.topology, model.dt), model.params, split)
    table = checkpoint_table(curves, dataset.dt)
    with atomic_dir(args.output) as out:  # moved to --output only when complete
        atomic_write_text(
            out / "long_horizon.md",
            f"# Long-horizon error on {args.dataset} ({args.split})\n\n"
            "mean rod position error / mean orientation error\n\n" + table + "\n",
        )
        plot_long_horizon(curves, dataset.dt, out / "long_horizon.png")
    print(table)
    print(f"\nwrote {args.output / 'long_horizon.md'} and {args.output / 'long_horizon.png'}")
    return 0
