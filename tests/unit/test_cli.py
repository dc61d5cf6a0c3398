"""The command line lists every subcommand without importing any, and the lines match."""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys

import pytest

from identification.commands.durations import seconds
from tensegrity_sr.cli import COMMANDS, SUBCOMMANDS, build_parser


def test_listing_matches_what_each_module_registers() -> None:
    registered = {}
    for module in COMMANDS:
        sub = argparse.ArgumentParser().add_subparsers()
        importlib.import_module(module).register(sub)
        registered.update({a.dest: (module, a.help) for a in sub._choices_actions})
    assert registered == SUBCOMMANDS


def test_help_imports_no_command_module() -> None:
    code = (
        "import sys; from tensegrity_sr.cli import build_parser; build_parser(None); "
        "print(sorted(m for m in ('torch', 'mujoco', 'scipy') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_command_parses_with_only_its_module() -> None:
    args = build_parser("plant").parse_args(["plant", "none", "-o", "x.h5"])
    assert args.effect == "none" and callable(args.func)


def test_durations_are_seconds_and_finite() -> None:
    """``0.1``, ``0.1s`` and ``100ms`` are the same span; an overflowing or non-numeric one
    is an argument error (argparse's one line), not an OverflowError later."""

    assert seconds("0.1") == seconds("0.1s") == seconds("100ms") == 0.1
    for bad in ("1e400", "1e400ms", "nan", "-1", "5h"):
        with pytest.raises(argparse.ArgumentTypeError):
            seconds(bad)
