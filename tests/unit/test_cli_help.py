"""Every command's ``--help``: every option explained, readable text, no heavy imports."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys

import pytest

from tensegrity_sr.cli import SUBCOMMANDS, build_parser

#: the longest run of characters without a space in a help text: a longer one (a list
#: joined by bare commas) is broken mid-word when argparse wraps it to the terminal
LONGEST_WORD = 40


def _subparser(command: str) -> argparse.ArgumentParser:
    parser = build_parser(command)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[command]


@pytest.mark.parametrize("command", list(SUBCOMMANDS))
def test_every_option_has_readable_help(command: str) -> None:
    p = _subparser(command)
    shown = {a.dest for a in p._actions if a.help and a.help != argparse.SUPPRESS}
    missing = [a.dest for a in p._actions if not a.help and a.dest not in shown]  # hidden aliases
    assert missing == [], f"{command}: options without help {missing}"
    text = p.format_help()  # what --help prints: help strings %-expanded, descriptions not
    assert "%%" not in text
    assert not re.search(r"\{'\w+': ", text), f"{command}: a Python dict in the help"
    for a in p._actions:
        words = p._get_formatter()._expand_help(a).split()
        long = [w for w in words if len(w) > LONGEST_WORD]
        assert long == [], f"{command} {a.dest}: words argparse would break {long}"


def test_command_help_imports_no_torch_mujoco_scipy() -> None:
    """Building each command's parser (what ``--help`` does) leaves the heavy libraries
    unimported: they take seconds, ``--help`` a fraction of one."""
    code = (
        "import sys\n"
        "from tensegrity_sr.cli import SUBCOMMANDS, build_parser\n"
        "for c in SUBCOMMANDS:\n"
        "    build_parser(c)\n"
        "print(sorted(m for m in ('torch', 'mujoco', 'scipy', 'matplotlib', 'h5py') "
        "if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_light_name_lists_match_their_registries() -> None:
    from identification.defaults import SCALE_NAMES
    from identification.experiments.paper import SCALES
    from tensegrity_env.assemblies import ASSEMBLIES
    from tensegrity_env.defaults import ASSEMBLY_NAMES, EFFECT_NAMES
    from tensegrity_env.effects import EFFECTS

    assert tuple(EFFECTS) == EFFECT_NAMES
    assert tuple(ASSEMBLIES) == ASSEMBLY_NAMES
    assert tuple(SCALES) == SCALE_NAMES
