"""The ``tensegrity-sr`` command line: one entry point, one subcommand per job.

Each subcommand lives in its own module that defines ``register(subparsers)``;
add the module to :data:`COMMANDS` to expose it.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import NoReturn

from tensegrity_env.io_utils import InputError, run_reporting

#: subcommand -> (the module defining it with ``register(subparsers)``, its one-line help),
#: in the order ``--help`` lists them. Only the module of the command being run is
#: imported (torch, MuJoCo and SciPy take seconds), so ``--help`` lists these lines;
#: ``tests/unit/test_cli.py`` checks they match what each module registers.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "generate": ("identification.commands.generate",
                 "roll out randomized MuJoCo trajectories into an HDF5 dataset"),
    "import-mocap": ("identification.commands.import_mocap",
                     "import C3D, TSV or CSV motion capture (labelled or unlabelled) into an HDF5 dataset"),
    "inspect": ("identification.commands.inspect",
                "summarize a dataset: topology, time step, splits, arrays, ground truth"),
    "identify": ("identification.commands.identify",
                 "identify spring and rod parameters from a dataset by linear regression"),
    "evaluate": ("identification.commands.evaluate",
                 "long-horizon position/orientation error of params files against a dataset split"),
    "efficiency": ("identification.commands.efficiency",
                   "identify from random 100%%..0.01%% of the training transitions (data efficiency)"),
    "experiment": ("identification.commands.experiment",
                   "reproduce the paper's experiments: ours vs Interaction, Interaction+Int, "
                   "Koopman+Int; parameters; data efficiency"),
    "diagnose": ("identification.commands.diagnose",
                 "residual loop: find the missing effect, name it, add it, report errors before/after"),
    "plant": ("identification.commands.diagnose",
              "MuJoCo data with an undeclared effect (contact, drag, slack cables, joint damping) "
              "to diagnose"),
    "train": ("policies.commands.train",
              "train a PPO or SAC policy on IcosahedronSR-v0 (or any registered env)"),
    "tune": ("policies.commands.tune",
             "search PPO/SAC hyperparameters with Optuna (TPE, median pruning), local or distributed"),
    "transfer": ("policies.commands.transfer",
                 "evaluate a policy in the identified env and the MuJoCo twin (sim-to-sim transfer)"),
}  # fmt: skip
#: the modules, each once, in order
COMMANDS: tuple[str, ...] = tuple(dict.fromkeys(m for m, _ in SUBCOMMANDS.values()))


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are :class:`InputError`: one line naming the
    option and the problem, exit 2 (argparse would print the whole usage)."""

    def error(self, message: str) -> NoReturn:
        raise InputError(f"{self.prog}: {message}")


def build_parser(command: str | None = "*") -> argparse.ArgumentParser:
    """The parser. ``"*"``: every module imported; a subcommand: only its module
    (the others are listed); None: none imported (all listed, for ``--help``)."""
    parser = Parser(
        prog="tensegrity-sr",
        description=(
            "System identification of spring-rod (tensegrity) assemblies: MuJoCo ground "
            "truth, a differentiable engine identified by linear regression, and "
            "Gymnasium environments on the identified engine."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    wanted = COMMANDS if command == "*" else () if command is None else (SUBCOMMANDS[command][0],)
    loaded: set[str] = set()
    for name, (module, help_text) in SUBCOMMANDS.items():
        if module in wanted:
            if module not in loaded:
                importlib.import_module(module).register(sub)
                loaded.add(module)
        else:
            sub.add_parser(name, help=help_text)
    return parser


def _command(argv: Sequence[str]) -> str | None:
    """The subcommand named in ``argv`` (the first word that is one), if any."""
    return next((a for a in argv if a in SUBCOMMANDS), None)


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand; returns its exit status (2: bad input, 130: Ctrl-C, 143: SIGTERM)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    command = _command(argv)

    def work() -> int:
        args = build_parser(command).parse_args(argv)  # --help exits here, nothing imported
        return int(args.func(args) or 0)

    return run_reporting(work)  # SIGTERM unwinds like Ctrl-C: temporary files are removed


if __name__ == "__main__":
    sys.exit(main())
