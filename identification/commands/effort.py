"""``--effort quick|default|thorough``: the trajectory fits' window counts and iteration
limits as one choice, in ``identify`` and ``diagnose``.

``default`` is the measured defaults (:mod:`identification.defaults` and the commands'
own); ``quick`` halves every count and ``thorough`` doubles it. ``quick`` also fits
floor-only data from one start instead of two
(:attr:`~identification.trajectory.end_cap_data.TrajectorySettings.second_start`). A fit's cost grows in
proportion to its windows and iterations, and the spread of the weakest parameters
(spring damping first) shrinks as the inverse square root of the windows. The window
lengths are not part of it: they come from the data (the sample rate; on the floor, how
far the windows' states can be fitted, :func:`~identification.trajectory.floor_declared.windows_from_data`),
and ``--window`` sets them by hand.

The old per-knob options (``--windows``, ``--fit-windows``, ``--floor-windows``,
``--final-floor-windows``, ``--final-floor-window``, ``--final-iterations``,
``--fit-window``, ``--first-window``) are still read, hidden from ``--help``: given, one
replaces its preset value.
"""

from __future__ import annotations

import argparse
from typing import Any

from identification.defaults import FINAL_FLOOR_WINDOWS, FINAL_ITERATIONS, FLOOR_WINDOWS

#: the choices and each one's factor on the default counts
EFFORTS = {"quick": 0.5, "default": 1.0, "thorough": 2.0}
#: the default counts the factor scales (identify: ``floor_windows``, ``max_iter``;
#: diagnose: all but ``max_iter``)
COUNTS: dict[str, int] = {
    "windows": 8,  # random selection windows per split (diagnose's WINDOWS)
    "fit_windows": 32,  # training windows of the declared and accepted models' final fits
    "floor_windows": FLOOR_WINDOWS,
    "final_floor_windows": FINAL_FLOOR_WINDOWS,
    "final_iterations": FINAL_ITERATIONS,
    "max_iter": 20,  # Levenberg-Marquardt iterations per stage of identify in free flight
}


def effort_counts(effort: str) -> dict[str, int]:
    """The counts of ``effort`` (a key of :data:`EFFORTS`), each at least 1."""
    f = EFFORTS[effort]
    return {k: max(1, round(f * v)) for k, v in COUNTS.items()}


def two_starts(effort: str) -> bool:
    """Whether ``effort`` fits floor-only data from two starts (all but ``quick``)."""
    return effort != "quick"


def add_effort_option(p: argparse.ArgumentParser, hidden: dict[str, Any]) -> None:
    """``--effort`` and the hidden per-knob options ``hidden`` (option -> type), each
    defaulting to None (the effort's value)."""
    p.add_argument("--effort", choices=tuple(EFFORTS), default="default",
                   help="how hard the trajectory fits work: quick halves their windows and "
                   "iterations and fits floor-only data from one start, thorough doubles them "
                   "(default: default); the report prints what was used")  # fmt: skip
    for option, kind in hidden.items():
        p.add_argument(option, type=kind, default=None, help=argparse.SUPPRESS)


def apply_effort(args: argparse.Namespace) -> dict[str, int]:
    """Fill every per-knob option of ``args`` left at None from ``args.effort``; returns
    the counts the effort gave (before the options given by hand)."""
    counts = effort_counts(args.effort)
    for key, value in counts.items():
        if getattr(args, key, "absent") is None:
            setattr(args, key, value)
    return counts


def effort_line(args: argparse.Namespace, keys: tuple[str, ...]) -> str:
    """One line of what ``args`` (after :func:`apply_effort`) uses, e.g. for the report."""
    return f"effort {args.effort}: " + ", ".join(
        f"{k.replace('_', ' ')} {getattr(args, k)}" for k in keys if hasattr(args, k)
    )
