"""Outputs are checked before any work, never replaced unasked, never left half-written.

Every case runs the command line as a user would and asserts the exit status, a
one-line ``error:`` message naming the path, and that no file was written.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from identification.data.dataset import read_dataset
from tensegrity_env.io_utils import (
    InputError,
    atomic_path,
    check_output_dir,
    check_output_file,
)
from tensegrity_sr.cli import main

ROOT = Path(__file__).resolve().parents[2]
GENERATE = ["generate", "--n-train", "2", "--n-val", "0", "--n-test", "1", "--steps", "20",
            "--no-progress"]  # fmt: skip


@pytest.fixture
def dataset(tmp_path: Path) -> Path:
    path = tmp_path / "data" / "tiny.h5"
    assert main([*GENERATE, "-o", str(path)]) == 0
    return path


def test_generate_into_proc_is_refused_before_any_work(one_line_error, monkeypatch) -> None:
    import identification.simulation.generate as gen

    monkeypatch.setattr(gen, "rollout_split", lambda *a, **k: pytest.fail("work started"))
    assert main([*GENERATE, "-o", "/proc/x/y.h5"]) == 2
    one_line_error("-o /proc/x/y.h5", "cannot create files in /proc")
    assert not Path("/proc/x/y.h5").exists()


def test_output_inside_a_file_is_refused(tmp_path: Path, one_line_error) -> None:
    (tmp_path / "file.txt").write_text("a file\n")
    out = tmp_path / "file.txt" / "y.h5"
    assert main([*GENERATE, "-o", str(out)]) == 2
    one_line_error(str(out), f"{tmp_path / 'file.txt'} is a file, not a folder")
    assert (tmp_path / "file.txt").read_text() == "a file\n"


def test_output_file_that_is_a_folder_is_refused(tmp_path: Path, one_line_error) -> None:
    assert main([*GENERATE, "-o", str(tmp_path)]) == 2
    one_line_error(str(tmp_path), "is a folder")
    assert list(tmp_path.iterdir()) == []


def test_existing_file_is_kept_without_force_and_replaced_with_it(
    tmp_path: Path, one_line_error
) -> None:
    out = tmp_path / "data.h5"
    out.write_bytes(b"precious")
    assert main([*GENERATE, "-o", str(out)]) == 2
    one_line_error(f"-o {out}: exists", "--force")
    assert out.read_bytes() == b"precious"
    assert main([*GENERATE, "-o", str(out), "--force"]) == 0
    assert read_dataset(out).n_steps == 3 * 20
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.h5"]  # no temporary left


def test_identify_output_checked_before_the_fit(dataset: Path, one_line_error) -> None:
    assert main(["identify", str(dataset), "-o", "/proc/x/params.json"]) == 2
    one_line_error("-o /proc/x/params.json")


def test_identify_default_output_is_not_replaced(
    dataset: Path, tmp_path: Path, monkeypatch, one_line_error
) -> None:
    monkeypatch.chdir(tmp_path)
    Path("params.json").write_text("{}\n")
    assert main(["identify", str(dataset)]) == 2
    one_line_error("-o params.json: exists", "--force")
    assert Path("params.json").read_text() == "{}\n"


@pytest.mark.parametrize(
    "argv",
    [
        ["diagnose", "data.h5"],
        ["evaluate", "data.h5", "--params", "p.json"],
        ["efficiency", "data.h5"],
        ["experiment", "paper"],
        ["transfer", "policy.zip"],
    ],
    ids=lambda a: a[0],
)
def test_output_folders_that_hold_files_or_are_files_are_refused(
    argv: list[str], tmp_path: Path, one_line_error
) -> None:
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "report.md").write_text("earlier run\n")
    assert main([*argv, "-o", str(folder)]) == 2
    one_line_error(f"-o {folder}: folder exists and holds files", "--force")
    assert [p.name for p in folder.iterdir()] == ["report.md"]
    assert main([*argv, "-o", str(folder / "report.md")]) == 2
    one_line_error("is a file; name a folder")


def test_plant_and_train_outputs_are_checked(tmp_path: Path, one_line_error) -> None:
    (tmp_path / "f").write_text("")
    assert main(["plant", "none", "-o", str(tmp_path / "f" / "x.h5")]) == 2
    one_line_error("is a file, not a folder")
    assert main(["train", "ppo", "-o", str(tmp_path / "f")]) == 2
    one_line_error("is a file; name a folder")


def test_check_helpers_create_nothing(tmp_path: Path) -> None:
    deep = tmp_path / "a" / "b" / "c.h5"
    assert check_output_file(deep) == deep
    assert check_output_dir(tmp_path / "d" / "e") == tmp_path / "d" / "e"
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "kept.txt").write_text("")
    with pytest.raises(InputError, match=f"^--out {tmp_path}: folder exists and holds files"):
        check_output_dir(tmp_path, option="--out")
    assert check_output_dir(tmp_path, force=True) == tmp_path
    assert [p.name for p in tmp_path.iterdir()] == ["kept.txt"]  # the probe file is gone


def test_an_exception_while_writing_leaves_nothing(tmp_path: Path) -> None:
    final = tmp_path / "x.bin"
    with pytest.raises(RuntimeError), atomic_path(final) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("disk full")
    assert list(tmp_path.iterdir()) == []


# SIGTERM arrives while generate is writing the HDF5 file (the temporary file exists and
# is being filled): the process ends with 143, one line on stderr, and nothing on disk.
SIGTERM_DURING_WRITE = textwrap.dedent(
    """
    import os, signal, sys
    import h5py
    import identification.data.dataset as ds
    from tensegrity_sr.cli import main

    real = h5py.File

    def file_then_sigterm(*args, **kwargs):
        f = real(*args, **kwargs)
        if kwargs.get("mode", args[1] if len(args) > 1 else "r") == "w":
            f.attrs["partial"] = 1
            os.kill(os.getpid(), signal.SIGTERM)
        return f

    ds.h5py.File = file_then_sigterm
    sys.exit(main(sys.argv[1:]))
    """
)


def test_sigterm_during_the_write_phase_leaves_no_file(tmp_path: Path) -> None:
    out = tmp_path / "paper.h5"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, "-c", SIGTERM_DURING_WRITE, *GENERATE, "-o", str(out)],
        capture_output=True, text=True, env=env, cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 143, proc.stderr
    assert proc.stderr.strip() == "terminated"
    assert list(tmp_path.iterdir()) == []
