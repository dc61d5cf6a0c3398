"""``tensegrity-sr inspect``: what a dataset holds (and whether it is well formed)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tensegrity_env.io_utils import InputError, add_force_option, check_output_file

if TYPE_CHECKING:  # imported where used: --help imports no torch, MuJoCo or SciPy
    from identification.data.dataset import Dataset, GroundTruth


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "inspect",
        help="summarize a dataset: topology, time step, splits, arrays, ground truth",
        description=(
            "Read and check a dataset file and summarize it: the topology (rods, springs, "
            "anchors), the time step, the splits with their sizes, which arrays are stored, "
            "and whether a ground truth is present (shown only with --ground-truth). Given a "
            "motion-capture file instead: its frames, rate, markers, gaps, noise and "
            "placeholder samples, before importing it."
        ),
    )
    p.add_argument("dataset", type=Path,
                   help="HDF5 dataset, or a motion-capture file (.c3d, .tsv, .csv) to look at "
                        "before importing it")  # fmt: skip
    p.add_argument("--units", choices=("m", "mm"),
                   help="length unit of a motion-capture file that does not state its own")  # fmt: skip
    p.add_argument("--ground-truth", action="store_true", help="also print the stored ground truth")
    p.add_argument("--plot", type=Path, metavar="PNG",
                   help="draw gaps, dropout and marker noise per end cap into this PNG")  # fmt: skip
    add_force_option(p)
    p.set_defaults(func=run)


def summary(ds: Dataset, truth: GroundTruth | None) -> str:
    """The text that ``inspect`` prints, without the ground truth's values."""
    from identification.data.dataset import SPLITS

    topo = ds.topology
    a = ds.attrs
    lines = [f"{ds.path}: {a.get('source', 'unknown source')}, created {a.get('created', '?')}"]
    lines.append(
        f"assembly: {a.get('assembly', topo.name)}: {topo.n_rods} rods, {topo.n_springs} "
        f"springs, {topo.n_anchors} world anchors ({2 * topo.n_rods} end caps)"
    )
    lines.append(f"time step: dt = {ds.dt * 1e3:g} ms ({1 / ds.dt:g} Hz)")
    if "preset" in a or "seed" in a:
        lines.append(f"generated: preset {a.get('preset', '?')}, seed {a.get('seed', '?')}")
    lines.append("splits:")
    width = max(len(n) for n in ds.splits)
    order = [n for n in SPLITS if n in ds.splits] + sorted(set(ds.splits) - set(SPLITS))
    for name in order:
        s = ds.splits[name]
        lines.append(
            f"  {name:<{width}}  N = {s.n_trajectories:>5}  T = {s.n_transitions:>5} steps "
            f"({s.n_transitions * ds.dt:.3g} s)  {s.n_trajectories * s.n_transitions:>10,} steps"
        )
    lines.append(f"  {'total':<{width}}  {ds.n_steps:>44,} steps")
    if all(s.has_states for s in ds.splits.values()):
        stored = "rod states (p, v, q, omega), end caps (nodes) and control"
    else:
        stored = (
            "end caps only (nodes) and control: rod states are derived from the end caps "
            "(identification.data.end_caps.rod_states_from_nodes)"
        )
    lines.append(f"arrays: {stored}")
    control = [np.abs(s.control).max() for s in ds.splits.values() if s.control.size]
    lines.append(f"control: {'none (all zero)' if not control or max(control) == 0 else 'applied'}")
    for what, attr, n in (("cable actuator", "has_cable_commands", ds.topology.n_cables),
                          ("winch motor", "has_winch_commands", ds.topology.n_winches)):  # fmt: skip
        if n:
            driven = any(getattr(s, attr) for s in ds.splits.values())
            lines.append(f"{what} commands: {n} {what}s, " + ("commanded" if driven else "none (all zero)"))
    if truth is None:
        lines.append("ground truth: none (measured data)")
    else:
        lines.append("ground truth: present (not shown; pass --ground-truth to print it)")
    return "\n".join(lines)


def ground_truth_text(truth: GroundTruth) -> str:
    """The ground truth, for ``--ground-truth``."""
    from tensegrity_env.params import UNITS

    lines = ["ground truth parameters:"]
    with np.printoptions(precision=6, suppress=True, linewidth=100):
        for f, values in truth.params.numpy().items():
            lines.append(f"  {f} [{UNITS[f]}]:")
            lines.extend(f"    {row}" for row in str(values).splitlines())
    lines.append(f"simulation: {json.dumps(truth.sim)}")
    lines.append(f"planted effects: {json.dumps(truth.effects) if truth.effects else 'none'}")
    lines.append(f"MJCF: {len(truth.mjcf):,} characters (HDF5 attribute /ground_truth mjcf)")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from identification.data.dataset import read_dataset, read_ground_truth
    from identification.data.end_caps import cap_names
    from identification.data.mocap.formats import MOCAP_SUFFIXES, read_recording
    from identification.data.mocap.summary import recording_text
    from identification.data.quality import plot_quality, quality_text, sample_quality
    from identification.report.plots import check_figure_path

    if args.plot is not None:
        check_figure_path(args.plot, "--plot")
        check_output_file(args.plot, args.force, "--plot", inputs=[args.dataset])
    if args.dataset.suffix.lower() in MOCAP_SUFFIXES:
        if args.plot is not None or args.ground_truth:
            raise InputError(f"{args.dataset}: --plot and --ground-truth are for datasets; "
                             "import the take first (import-mocap)")  # fmt: skip
        print(recording_text(read_recording(args.dataset, args.units)))
        return 0
    ds = read_dataset(args.dataset)
    truth = read_ground_truth(args.dataset)
    text = summary(ds, truth)
    names = cap_names(ds.topology)
    quality = sample_quality(ds)
    text += "\n" + quality_text(quality, names)
    if args.plot is not None:
        plot_quality(ds, quality, names, str(args.plot))
        text += f"\npicture: {args.plot}"
    if args.ground_truth:
        text = text.replace("present (not shown; pass --ground-truth to print it)", "present")
        if truth is not None:
            text += "\n" + ground_truth_text(truth)
    print(text)
    return 0
