"""Actuator commands logged beside a take, held onto the take's frames.

A lab logs the commands it sends to a cable-driven robot's motors on the controller's
own clock and rate. One command file per take, a CSV: a header ``time`` followed by one
column per cable actuator of the robot, in the robot file's actuator order; times [s]
from the take's first frame (the two clocks aligned); one row per command sent. A
command holds until the next row (zero-order hold, as a motor controller applies it):
the command in force over the sample interval that starts at a frame is the last row
at or before that frame's time.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from tensegrity_env.io_utils import InputError, atomic_write_text

#: a command logged this close after a frame's time [s] counts as in force at that frame
#: (the round-off of times written with a few decimals)
TIME_TOL = 1e-6


def read_commands(path: Path, n_actuators: int) -> tuple[np.ndarray, np.ndarray]:
    """Command times (K,) [s] and values (K, C) of a command CSV; one-line errors."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = [r for r in csv.reader(f) if any(c.strip() for c in r)]
    except OSError as e:
        raise InputError(f"{path}: cannot read the command file ({e.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    if not rows or rows[0][0].strip().lower() != "time":
        raise InputError(f"{path}: command file must start with a header 'time,<actuator>,...'")
    if len(rows[0]) - 1 != n_actuators:
        raise InputError(f"{path}: {len(rows[0]) - 1} command columns, the robot has "
                         f"{n_actuators} cable actuators")  # fmt: skip
    if len(rows) < 2:
        raise InputError(f"{path}: no commands after the header")
    data = np.empty((len(rows) - 1, n_actuators + 1))
    for i, r in enumerate(rows[1:]):
        if len(r) != n_actuators + 1:
            raise InputError(f"{path}: row {i + 2} has {len(r)} cells, the header {n_actuators + 1}")
        try:
            data[i] = [float(c) for c in r]
        except ValueError:
            raise InputError(f"{path}: row {i + 2} holds a cell that is not a number") from None
    if not np.isfinite(data).all():
        raise InputError(f"{path}: commands or times that are not finite")
    if (np.diff(data[:, 0]) <= 0).any():
        raise InputError(f"{path}: command times do not increase")
    return data[:, 0], data[:, 1:]


def hold_commands(times: np.ndarray, values: np.ndarray, frames: np.ndarray, where: str) -> np.ndarray:
    """The command in force from each frame on, (F, C): the last command at or before the
    frame's time ``frames`` (F,) [s]. A log that starts after the first frame is refused."""
    if times[0] > frames[0] + TIME_TOL:
        raise InputError(f"{where}: the first command is logged at {times[0]:.6g} s, after the "
                         f"take's first frame ({frames[0]:.6g} s): align the clocks")  # fmt: skip
    return values[np.searchsorted(times, frames + TIME_TOL, side="right") - 1]


def write_commands(path: str | Path, times: np.ndarray, values: np.ndarray, names: list[str]) -> Path:
    """Write commands ``values`` (K, C) at ``times`` (K,) [s] as a command CSV."""
    lines = [",".join(["time", *names])]
    lines += [",".join([repr(float(t)), *(repr(float(v)) for v in row)]) for t, row in zip(times, values, strict=True)]
    return atomic_write_text(path, "\n".join(lines) + "\n")
