"""An output is never one of the command's inputs, ``--force`` or not.

Each case names an input file as the output (directly, through another spelling of
its path, a symbolic link or a hard link) and asserts a one-line error and the input
unchanged, byte for byte.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from tensegrity_env.io_utils import (
    InputError,
    atomic_dir,
    atomic_path,
    protect_inputs,
    run_reporting,
)
from tensegrity_sr.cli import main

ASSETS = Path(__file__).resolve().parents[2] / "tensegrity_env" / "assets"
GENERATE = ["generate", "--n-train", "2", "--n-val", "0", "--n-test", "2", "--steps", "20",
            "--no-progress"]  # fmt: skip
REFUSED = "is an input file of this command"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("tiny") / "data.h5"
    assert main([*GENERATE, "-o", str(path)]) == 0
    return path


def _spellings(path: Path) -> dict[str, Path]:
    """Other names of ``path``: another spelling, a symbolic link, a hard link."""
    other = path.parent / "sub"
    other.mkdir(exist_ok=True)
    (path.parent / "soft").unlink(missing_ok=True)
    (path.parent / "hard").unlink(missing_ok=True)
    (path.parent / "soft").symlink_to(path)
    os.link(path, path.parent / "hard")
    return {"same": path, "spelled": other / ".." / path.name,
            "symlink": path.parent / "soft", "hardlink": path.parent / "hard"}  # fmt: skip


@pytest.mark.parametrize("how", ["same", "spelled", "symlink", "hardlink"])
def test_identify_never_replaces_its_dataset(
    how: str, tiny: Path, tmp_path: Path, one_line_error
) -> None:
    data = tmp_path / "DATA.h5"
    shutil.copy(tiny, data)
    before = data.read_bytes()
    out = _spellings(data)[how]
    assert main(["identify", str(data), "-o", str(out), "--force"]) == 2
    one_line_error(f"-o {out}: {REFUSED}", "--force")
    assert data.read_bytes() == before


def _files(tmp_path: Path) -> dict[str, Path]:
    """Input files of the commands below (their content is not read before the check)."""
    files = {"take.csv": "t,x\n0,1\n", "take.c3d": "not read", "robot.xml": "<mujoco/>",
             "map.yaml": "{}", "log.csv": "t,u\n", "policy.zip": "zip", "hp.yml": "{}",
             "fig.png": "png", "model.xml": (ASSETS / "lab_prism.xml").read_text()}  # fmt: skip
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    return {name: tmp_path / name for name in files}


@pytest.mark.parametrize(
    ("argv", "target"),
    [
        (["import-mocap", "take.csv", "--robot", "robot.xml", "-o", "take.csv"], "take.csv"),
        (["import-mocap", "take.c3d", "--robot", "robot.xml", "-o", "take.c3d"], "take.c3d"),
        (["import-mocap", "take.csv", "--robot", "robot.xml", "-o", "robot.xml"], "robot.xml"),
        (["import-mocap", "take.csv", "--robot", "robot.xml", "--map", "map.yaml", "-o",
          "map.yaml"], "map.yaml"),
        (["import-mocap", "take.csv", "--robot", "robot.xml", "--commands", "log.csv", "-o",
          "log.csv"], "log.csv"),
        (["inspect", "fig.png", "--plot", "fig.png"], "fig.png"),
        (["generate", "--mjcf", "model.xml", "--steps", "2", "-o", "model.xml"], "model.xml"),
        (["identify", "take.csv", "--init", "robot.xml", "-o", "robot.xml"], "robot.xml"),
        (["transfer", "policy.zip", "-o", "policy.zip"], "policy.zip"),
        (["train", "ppo", "--hyperparams", "hp.yml", "-o", "hp.yml"], "hp.yml"),
    ],
    ids=lambda a: a[0] if isinstance(a, list) else a,
)
def test_no_command_writes_over_an_input(
    argv: list[str], target: str, tmp_path: Path, monkeypatch, one_line_error
) -> None:
    monkeypatch.chdir(tmp_path)
    files = _files(tmp_path)
    before = {name: p.read_bytes() for name, p in files.items()}
    force = [] if argv[0] == "train" else ["--force"]  # train continues a run, never replaces
    assert main([*argv, *force]) == 2
    one_line_error(REFUSED)
    assert {name: p.read_bytes() for name, p in files.items()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(files)  # nothing else written


def test_a_report_file_named_like_an_input_is_not_moved_over_it(
    tiny: Path, tmp_path: Path, one_line_error
) -> None:
    """With ``--force`` a report folder's files replace those of the same name, never an
    input: the last check before the move refuses, and the folder is left as it was."""
    params = tmp_path / "params.json"
    assert main(["identify", str(tiny), "-o", str(params)]) == 0
    out = tmp_path / "out"
    out.mkdir()
    disguised = out / "long_horizon.md"  # an input that has the name of an output
    shutil.copy(params, disguised)
    before = disguised.read_bytes()
    code = main(["evaluate", str(tiny), "--params", str(disguised), "-o", str(out), "--force"])
    assert code == 2
    one_line_error(f"{disguised}: {REFUSED}")
    assert sorted(p.name for p in out.iterdir()) == ["long_horizon.md"]
    assert disguised.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "params.json"]  # no temporary


def test_atomic_writers_check_the_inputs_at_the_rename(tmp_path: Path) -> None:
    """Code that writes without the command-line checks is held to the same rule."""
    data = tmp_path / "data.csv"
    data.write_text("t,x\n")

    def write_over_input() -> int:
        protect_inputs(data)
        with atomic_path(tmp_path / "sub" / ".." / "data.csv") as tmp:
            tmp.write_text("replaced")
        return 0

    def report_over_input() -> int:
        protect_inputs([data])
        with atomic_dir(tmp_path / "new" / "report") as out:
            (out / "a.md").write_text("a")
        with atomic_dir(tmp_path) as out:
            (out / "data.csv").write_text("replaced")
        return 0

    assert run_reporting(write_over_input) == 2
    assert run_reporting(report_over_input) == 2
    assert data.read_text() == "t,x\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv", "new"]
    assert [p.name for p in (tmp_path / "new" / "report").iterdir()] == ["a.md"]
    with atomic_path(data) as tmp:  # the record of inputs ended with the command
        tmp.write_text("t,x\n0,1\n")
    assert data.read_text() == "t,x\n0,1\n"


def test_an_input_error_is_raised_outside_a_command_too(tmp_path: Path) -> None:
    data = tmp_path / "data.h5"
    data.write_bytes(b"x")
    protect_inputs(data)
    try:
        with pytest.raises(InputError, match=REFUSED), atomic_path(data) as tmp:
            tmp.write_bytes(b"y")
    finally:
        run_reporting(lambda: 0)  # empties the record
    assert data.read_bytes() == b"x"
