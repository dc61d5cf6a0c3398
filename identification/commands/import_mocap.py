"""``tensegrity-sr import-mocap``: C3D / TSV / CSV motion capture into the public dataset format."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tensegrity_env.cli_options import add_end_caps_option
from tensegrity_env.io_utils import InputError, add_force_option, check_output_file

if TYPE_CHECKING:  # imported where used: --help imports no torch, MuJoCo or SciPy
    from identification.data.mocap.importer import ImportedTake, Robot
    from identification.data.mocap.recording import MarkerRecording


def register(sub: Any) -> None:
    p = sub.add_parser(
        "import-mocap",
        help="import C3D, TSV or CSV motion capture (labelled or unlabelled) into an HDF5 dataset",
        description=(
            "Read motion-capture takes (C3D, Qualisys TSV, OptiTrack Motive CSV, Vicon Nexus "
            "CSV, or a plain CSV 'time, <marker>_x, <marker>_y, <marker>_z, ...'), map markers to "
            "the robot's end caps (a marker map, or marker names <rod>_<0|1>), check labelled "
            "markers frame by frame, label unlabelled point clouds by tracking the end caps "
            "under the rod-length constraint, and write end caps with their sample times and "
            "gaps (NaN) as a dataset. One take per file becomes one trajectory."
        ),
    )
    p.add_argument("files", type=Path, nargs="+", help="C3D, TSV or CSV files, one take each")
    p.add_argument("--robot", type=Path, required=True,
                   help="robot MJCF (.xml) or NTRT YAML model (.yaml; the rest pose of either starts "
                        "unlabelled tracking), or params.json")  # fmt: skip
    p.add_argument("--map", type=Path, help="marker map YAML (marker -> rod end cap, axial offset)")
    p.add_argument("--units", choices=("m", "mm"),
                   help="length unit of files that do not state theirs (plain CSV)")  # fmt: skip
    p.add_argument("--commands", type=Path, action="append", default=[], metavar="CSV",
                   help="the motor command log of a take (CSV 'time,<actuator>,...': a column per "
                        "cable actuator, then one per winch, in the robot file's order; times from "
                        "the take's first frame, held until the next row), once per take in the "
                        "order of the files; without it, commands are zero")  # fmt: skip
    p.add_argument("--up", choices=("z", "y", "x"),
                   help="the files' vertical axis, rotated to z (default: found in each take, "
                        "from free flight where there is any, else from the floor its lowest "
                        "end caps rest on; a named axis the data contradicts is refused)")  # fmt: skip
    p.add_argument("--split", default="0.7,0.15,0.15", metavar="TRAIN,VAL,TEST",
                   help="fractions of the takes (of each take's pieces of its stretches with "
                        "fewer than 3 takes); default 0.7,0.15,0.15")  # fmt: skip
    p.add_argument("--segments", metavar="START-END,...",
                   help="the stretches a fit uses, in seconds of each take (e.g. 0-7,11.5-20); "
                        "default: found in each take (at rest and free; not where something "
                        "outside the model, such as a person, acts on the robot)")  # fmt: skip
    p.add_argument("--piece", type=float, default=2.0, metavar="SECONDS",
                   help="the stretches are cut into trajectories of this length [s], each "
                        "whole in one split (default 2; 0: each stretch whole)")  # fmt: skip
    p.add_argument("--val", type=Path, action="append", default=[],
                   help="a file for the val split (repeatable; the split then goes by file)")  # fmt: skip
    p.add_argument("--test", type=Path, action="append", default=[],
                   help="a file for the test split (repeatable; the split then goes by file)")  # fmt: skip
    p.add_argument("--ignore", action="append", default=[], metavar="FEATURE",
                   help="accept this unmodelled MJCF feature of the robot file with a warning")  # fmt: skip
    add_end_caps_option(p)
    p.add_argument("-o", "--output", type=Path, required=True, help="dataset file to write (.h5)")
    add_force_option(p)
    p.set_defaults(func=run)


def command_logs(
    files: list[Path], recordings: list[MarkerRecording], n_cables: int, n_winches: int = 0
) -> list[tuple[np.ndarray, np.ndarray] | None]:
    """Each take's ``--commands`` log, times (K,) [s] and values (K, C + W) (the cable
    actuators', then the winch motors'), read and checked against its take before any
    work; None for every take without files."""
    from identification.data.mocap.commands import hold_commands, read_commands

    n = n_cables + n_winches
    what = " and ".join(x for x in (f"{n_cables} cable actuators" if n_cables else "",
                                    f"{n_winches} winches" if n_winches else "") if x)  # fmt: skip
    if not files:
        if n:
            print(f"warning: the robot has {what} and no --commands were given: their "
                  "commands are recorded as zero (an unactuated robot)")  # fmt: skip
        return [None] * len(recordings)
    if not n:
        raise InputError(f"{files[0]}: --commands given, but the robot has no cable actuators or winches")
    if len(files) != len(recordings):
        raise InputError(f"--commands: {len(files)} command files for {len(recordings)} takes "
                         "(one per take, in the order of the files)")  # fmt: skip
    logs: list[tuple[np.ndarray, np.ndarray] | None] = []
    for f, rec in zip(files, recordings, strict=True):
        times, values = read_commands(f, n, what)
        hold_commands(times, values, rec.time[:1], str(f))  # refuses a log that starts late
        logs.append((times, values))
    return logs


def with_commands(take: ImportedTake, log: tuple[np.ndarray, np.ndarray] | None) -> ImportedTake:
    """``take`` with its log's commands held onto its frames
    (:func:`~identification.data.mocap.commands.hold_commands`)."""
    from identification.data.mocap.commands import hold_commands

    return take if log is None else replace(take, commands=hold_commands(*log, take.time, str(take.source)))


def with_stretches(take: ImportedTake, segments: str | None, robot: Robot) -> ImportedTake:
    """``take`` (z-up) placed on the robot's end caps and floor
    (:func:`~identification.data.mocap.placement.place_take`, from the stretches found
    in it; an unlabelled take's tracking report printed before), with the stretches a fit uses: the user's ``segments`` (``--segments``),
    else those found when something outside the model acts in it (else none: the whole
    take is used), printed with their times."""
    from identification.data.mocap.importer import cap_distances, tracking_report
    from identification.data.mocap.placement import place_take
    from identification.data.mocap.stretches import find_stretches, named_stretches, parse_segments

    found = find_stretches(take.caps, take.time)
    print(f"{take.source}: stretches " + ", ".join(map(str, found)))
    if take.reacquired is not None:  # the tracking as labelled, before the placement
        print(tracking_report(take, robot.topology))
    radius = np.array([r.radius for r in robot.topology.rods])
    caps, placement = place_take(take.caps, take.time, found, cap_distances(robot), radius)
    for line in placement.lines():
        print(f"{take.source}: {line}")
    take = replace(take, caps=caps, placement=placement)
    if segments is None:
        if not any(s.kind == "external" for s in found):
            return take
        print(f"{take.source}: the fit leaves out what acts from outside the model (--segments "
              "names the stretches to use instead)")  # fmt: skip
        return replace(take, stretches=tuple(found))
    named = named_stretches(parse_segments(segments), take.time, str(take.source))
    print(f"{take.source}: --segments: the fit uses " + ", ".join(f"{s.start:.2f}-{s.end:.2f} s" for s in named))
    return replace(take, stretches=tuple(named))


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from identification.data.dataset import write_dataset
    from identification.data.mocap.formats import read_recording
    from identification.data.mocap.importer import (
        build_dataset,
        check_take,
        label_take,
        parse_fractions,
        read_robot,
        upright,
    )
    from identification.data.mocap.marker_map import read_marker_map
    from identification.data.quality import PLACEHOLDER_KINDS, REPEAT_TOL

    check_output_file(args.output, args.force, inputs=[*args.files, args.robot, args.map,
                                                     *args.commands, *args.val, *args.test])
    fractions = parse_fractions(args.split)
    if args.segments is not None:
        from identification.data.mocap.stretches import parse_segments

        parse_segments(args.segments)  # refused before any work
    if not args.piece >= 0:
        raise InputError(f"--piece: {args.piece:g} s must be positive, or 0 (each stretch whole)")
    named = {f.name for f in args.files}
    assign = {f.name: "val" for f in args.val} | {f.name: "test" for f in args.test}
    for f in [*args.val, *args.test]:
        if f.name not in named:
            raise InputError(f"{f}: named by --val/--test but not among the files to import")
    robot = read_robot(args.robot, tuple(args.ignore), args.end_caps)
    mmap = read_marker_map(args.map, robot.topology) if args.map else None
    recordings = [read_recording(f, args.units) for f in args.files]  # all checked before work
    maps = [check_take(rec, robot, mmap) for rec in recordings]
    logs = command_logs(args.commands, recordings, robot.topology.n_cables, robot.topology.n_winches)
    takes = [with_commands(label_take(r, robot, m), log)
             for r, m, log in tqdm(list(zip(recordings, maps, logs, strict=True)), desc="labelling",
                                   unit="take")]  # fmt: skip
    turned = [upright(t, args.up) for t in takes]  # every take checked before one is written
    for _, line in turned:
        print(line)
    takes = [with_stretches(t, args.segments, robot) for t, _ in turned]
    for rec, take in zip(recordings, takes, strict=True):
        if len(take.time) < rec.n_frames:
            print(f"{rec.source}: tracking starts at frame {rec.n_frames - len(take.time)} "
                  f"({take.time[0]:.3g} s), the first that shows every end cap; the frames "
                  "before it are left out")  # fmt: skip
    dataset = build_dataset(takes, robot, fractions, assign or None, args.piece)
    write_dataset(args.output, dataset)
    frames = sum(len(t.time) for t in takes)
    seen = np.mean([np.isfinite(t.caps).all(-1).mean() for t in takes])
    repeated = sum(r.repeated_frames for r in recordings)
    if repeated:
        print(f"{repeated} frames repeated the frame before within {REPEAT_TOL * 1e6:g} µm (not "
              "measurements): read as gaps")  # fmt: skip
    held = sum(r.placeholders for r in recordings)
    if held:
        print(f"{held} marker samples were placeholders for unseen markers ({PLACEHOLDER_KINDS}): "
              "read as unseen")  # fmt: skip
    print(
        f"{args.output}: {len(takes)} takes, {frames} frames at {1 / dataset.dt:g} Hz, "
        f"{2 * robot.topology.n_rods} end caps, {100 * (1 - seen):.2f} % unseen; "
        f"relabelled frames {dataset.attrs['relabelled_frames']}, "
        f"ghost points rejected {dataset.attrs['ghost_points']}; "
        + (f"labelled samples off their rod's length read as unseen "
           f"{dataset.attrs['rejected_samples']}; " if dataset.attrs["rejected_samples"] else "")
        + f"splits {', '.join(f'{k} {v.n_trajectories}' for k, v in dataset.splits.items())}"
        + (f"; commands of {robot.topology.n_cables + robot.topology.n_winches} motors from "
           f"{len(args.commands)} logs" if args.commands else "")
    )
    return 0
