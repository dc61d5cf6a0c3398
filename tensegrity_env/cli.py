"""The ``tensegrity-sr`` command line: one entry point, one subcommand per job.

Each subcommand lives in its own module that defines ``register(subparsers)``;
add the module to :data:`COMMANDS` to expose it.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from tensegrity_env.io_utils import InputError

#: Modules defining one subcommand each, in the order ``--help`` lists them.
COMMANDS: tuple[str, ...] = (
    "identification.commands.generate",
    "identification.commands.inspect",
    "identification.commands.identify",
    "identification.commands.evaluate",
    "identification.commands.efficiency",
    "identification.commands.experiment",
    "identification.commands.diagnose",
    "policies.commands.train",
    "policies.commands.transfer",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tensegrity-sr",
        description=(
            "System identification of spring-rod (tensegrity) assemblies: MuJoCo ground "
            "truth, a differentiable engine identified by linear regression, and "
            "Gymnasium environments on the identified engine."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMANDS:
        importlib.import_module(module).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
