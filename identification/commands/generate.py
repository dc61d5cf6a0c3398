"""``tensegrity-sr generate``: randomized MuJoCo rollouts into one HDF5 dataset."""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

from identification.defaults import PRESETS
from tensegrity_env.cli_options import add_end_caps_option
from tensegrity_env.defaults import ASSEMBLY_NAMES, FEATURES
from tensegrity_env.io_utils import add_force_option, check_output_file

EPILOG = """\
presets:
  small   icosahedron 16/4/4 trajectories of 300 steps (seconds)
  paper   1000/200/100 trajectories of 736 steps (736k training steps, as the paper)
  perturbed  4/0/4 trajectories of 20,000 steps under random directed forces f_u
          (control std 1; the paper's generalization data for identifying h)

The file is written once, at the end, through a temporary file and a rename: an
interrupted run leaves no file that looks complete; run the command again.
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "generate",
        help="roll out randomized MuJoCo trajectories into an HDF5 dataset",
        description=(
            "Roll out many seeded, randomized initial conditions (positions, orientations, "
            "velocities that excite the springs) of a spring-rod assembly through MuJoCo's "
            "multi-threaded batched rollout, and write rod states, end caps, controls and "
            "the hidden ground truth into one HDF5 file with train/val/test splits."
        ),
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="small", help="(default: small)")
    src = p.add_mutually_exclusive_group()
    src.add_argument(
        "--assembly", choices=sorted(ASSEMBLY_NAMES), help="built-in assembly (default: icosahedron)"
    )
    src.add_argument(
        "--mjcf",
        type=Path,
        metavar="FILE",
        help="your own MJCF: rods are free bodies with two end-cap sites, springs two-site "
        "spatial tendons (its own timestep and integrator are used)",
    )
    for split in ("train", "val", "test"):
        p.add_argument(f"--n-{split}", type=int, metavar="N", help=f"{split} trajectories")
    p.add_argument("--steps", type=int, metavar="T", help="steps per trajectory")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--ground", action="store_true", help="add a floor at z = 0 and start above it")
    p.add_argument(
        "--ignore",
        action="append",
        default=[],
        metavar="FEATURE",
        choices=sorted(FEATURES),
        help="accept an MJCF feature the model does not have (simulated by MuJoCo, left out of"
        " the model, with a warning); repeatable; see docs/mjcf.md",
    )
    add_end_caps_option(p)
    p.add_argument(
        "--control-std",
        type=float,
        default=None,
        metavar="STD",
        help="std of random control commands f_u per rod and axis, and of cable actuators'"
        " commands, held ~50 ms (default: 0)",
    )
    p.add_argument("--threads", type=int, help="MuJoCo rollout threads (default: all cores)")
    p.add_argument(
        "-o", "--output", type=Path, help="HDF5 file to write (default: <assembly>_<preset>.h5)"
    )
    add_force_option(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def run(args: argparse.Namespace) -> int:
    from identification.data.dataset import write_dataset
    from identification.simulation.generate import GenerateSpec, generate

    spec = GenerateSpec.from_preset(
        args.preset,
        assembly=args.assembly,
        mjcf=None if args.mjcf is None else str(args.mjcf),
        n_train=args.n_train,
        n_val=args.n_val,
        n_test=args.n_test,
        steps=args.steps,
        seed=args.seed,
        ground=args.ground,
        control_std=args.control_std,
        threads=args.threads,
        ignore=tuple(args.ignore),
        end_caps=args.end_caps,
    )
    name = Path(spec.mjcf).stem if spec.mjcf is not None else spec.assembly
    output = check_output_file(args.output or Path(f"{name}_{spec.preset}.h5"), args.force,
                               inputs=[args.mjcf])
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = generate(spec, progress=not args.no_progress)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    t1 = time.perf_counter()
    write_dataset(output, result.dataset, result.ground_truth)
    write_s = time.perf_counter() - t1
    total_s = time.perf_counter() - t0

    ds = result.dataset
    counts = "/".join(str(s.n_trajectories) for s in ds.splits.values())
    names = "/".join(ds.splits)
    extras = []
    if result.ground_truth.effects:
        extras.append("floor contact")
    extras.append(f"control std {spec.control_std:g}" if spec.control_std else "no control")
    print(
        f"Wrote {output}: {ds.attrs['assembly']} ({_count(ds.topology.n_rods, 'rod')}, "
        f"{_count(ds.topology.n_springs, 'spring')}; preset {spec.preset}, seed {spec.seed}, "
        f"{', '.join(extras)}), {names} = {counts} trajectories x {spec.steps} steps at "
        f"dt = {ds.dt * 1e3:g} ms = {ds.n_steps:,} steps, in {total_s:.2f} s wall "
        f"({result.rollout_seconds:.2f} s in MuJoCo rollouts on {result.threads} threads, "
        f"{write_s:.2f} s writing) = {ds.n_steps / total_s:,.0f} steps/s. Springs moved by a "
        f"median {result.spring_std * 1e3:.1f} mm (length std over a trajectory) and stayed "
        f"within {result.spring_ratio[0]:.2f}-{result.spring_ratio[1]:.2f} x their nominal "
        f"length. The ground truth is stored apart (tensegrity-sr inspect {output} "
        "--ground-truth)."
    )
    return 0
