"""Actuator commands logged beside a take, held onto the take's frames.

A lab logs the commands it sends to a cable-driven robot's motors on the controller's
own clock and rate. One command file per take, a CSV: a header ``time`` followed by one
column per cable actuator of the robot, in the robot file's actuator order, then one per
winch motor, in the robot file's winch order (a winch's command in [-1, 1] sets its
cable's rest-length rate, positive lengthening: :mod:`tensegrity_env.engine.winch`); times [s]
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


def read_commands(path: Path, n_actuators: int, what: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Command times (K,) [s] and values (K, n_actuators) of a command CSV (``what``
    names the robot's motors in errors); one-line errors."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            rows = [(reader.line_num, r) for r in reader if any(c.strip() for c in r)]
    except OSError as e:
        raise InputError(f"{path}: cannot read the command file ({e.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    if not rows or rows[0][1][0].strip().lower() != "time":
        raise InputError(f"{path}: command file must start with a header 'time,<actuator>,...'")
    header = rows[0][1]
    if len(header) - 1 != n_actuators:
        raise InputError(f"{path}: {len(header) - 1} command columns, the robot has "
                         f"{what or f'{n_actuators} cable actuators'}")  # fmt: skip
    if len(rows) < 2:
        raise InputError(f"{path}: no commands after the header")
    data = np.empty((len(rows) - 1, n_actuators + 1))
    for i, (line, r) in enumerate(rows[1:]):
        if len(r) != n_actuators + 1:
            raise InputError(f"{path}: row {line} has {len(r)} cells, the header {n_actuators + 1}")
        for j, cell in enumerate(r):
            where = f"{path}: row {line}, column {j + 1} ({header[j].strip()!r})"
            try:
                data[i, j] = float(cell)
            except ValueError:
                raise InputError(f"{where}: {cell!r} is not a number") from None
            if not np.isfinite(data[i, j]):
                raise InputError(f"{where}: {cell!r} is not a finite number")
        if i and data[i, 0] <= data[i - 1, 0]:
            raise InputError(f"{path}: row {line}, column 1: command times do not increase")
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
