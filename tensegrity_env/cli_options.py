"""Command-line options shared by several commands, importable without torch or MuJoCo."""

from __future__ import annotations

import argparse


def add_end_caps_option(parser: argparse.ArgumentParser) -> None:
    """``--end-caps SITE,SITE,...``: the end-cap sites of every rod, two per rod (where
    the convention of :mod:`tensegrity_env.mjcf` does not find them)."""
    parser.add_argument(
        "--end-caps",
        type=site_names,
        default=(),
        metavar="SITE,SITE,...",
        help="the MJCF sites motion capture tracks, two per rod (default: the two sites at"
        " each rod's ends along its axis); every other site a spring uses is an attachment"
        " point",
    )


def site_names(text: str) -> tuple[str, ...]:
    """Comma-separated site names, each non-empty and named once."""
    names = tuple(n.strip() for n in text.split(","))
    if not all(names):
        raise argparse.ArgumentTypeError(f"'{text}': an empty site name")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise argparse.ArgumentTypeError(f"'{text}': sites named twice {dup}")
    return names
