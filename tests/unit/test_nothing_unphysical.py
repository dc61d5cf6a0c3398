"""Nothing unphysical or empty is written: a fit outside the physical domain fails with
its stage's one-line reason, and a failed or stopped report leaves no folder."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
import torch

from tensegrity_env.assemblies import ASSEMBLIES
from tensegrity_env.io_utils import InputError
from tensegrity_sr.cli import main

GENERATE = ["generate", "--n-val", "0", "--no-progress"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("tiny") / "tiny.h5"
    assert main([*GENERATE, "--n-train", "2", "--n-test", "1", "--steps", "20", "-o",
                 str(path)]) == 0  # fmt: skip
    return path


def test_identify_on_two_samples_fails_and_writes_nothing(tmp_path: Path, one_line_error) -> None:
    data = tmp_path / "two.h5"
    assert main([*GENERATE, "--n-train", "1", "--n-test", "0", "--steps", "1", "-o",
                 str(data)]) == 0  # fmt: skip
    out = tmp_path / "params.json"
    assert main(["identify", str(data), "-o", str(out)]) == 1
    one_line_error("the regression failed", "NaN or inf", "spring0", "not written", "try ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["two.h5"]


def test_the_domain_check_names_the_spring_and_the_rod() -> None:
    assembly = ASSEMBLIES["icosahedron"]()
    topo, good = assembly.topology, assembly.params
    k = good.stiffness.clone()
    k[3] = -1.0
    name = topo.springs[3].name
    with pytest.raises(InputError, match=rf"stiffness must be positive: {name} = -1\.0$"):
        good.replace(stiffness=k).validate(topo, "p.json")
    m = good.mass.clone()
    m[2] = torch.nan
    with pytest.raises(InputError, match=rf"'mass' contains NaN or inf \({topo.rods[2].name} = nan\)"):
        good.replace(mass=m).validate(topo, "p.json")


@pytest.mark.parametrize("nested", [False, True])
def test_diagnose_with_an_unknown_anchor_leaves_no_folder(
    tiny: Path, tmp_path: Path, nested: bool, one_line_error
) -> None:
    out = tmp_path / "a" / "b" / "report" if nested else tmp_path / "report"
    argv = ["diagnose", str(tiny), "--anchor", "mass[nope]=1", "--max-effects", "0"]
    assert main([*argv, "-o", str(out)]) == 2
    one_line_error("unknown anchor 'mass[nope]'")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_sigterm_while_the_report_is_written_leaves_no_folder(
    tiny: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    import identification.discovery.report as report

    real = report.write_params
    seen: list[list[str]] = []

    def params_then_sigterm(result, path: Path, extra):
        real(result, path, extra)
        seen.append(sorted(p.name for p in path.parent.iterdir()))
        os.kill(os.getpid(), signal.SIGTERM)
        return path

    monkeypatch.setattr(report, "write_params", params_then_sigterm)
    out = tmp_path / "report"
    assert main(["diagnose", str(tiny), "--max-effects", "0", "-o", str(out)]) == 143
    assert capsys.readouterr().err.strip().endswith("terminated")
    assert "report.md" in seen[0] and "params.json" in seen[0]  # it was stopped at the end
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    # a folder that existed (--force) keeps what it held, and only that
    out.mkdir()
    (out / "report.md").write_text("earlier\n")
    assert main(["diagnose", str(tiny), "--max-effects", "0", "-o", str(out), "--force"]) == 143
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]
    assert [p.name for p in out.iterdir()] == ["report.md"]
    assert (out / "report.md").read_text() == "earlier\n"


def test_a_complete_report_replaces_files_of_the_same_name(tiny: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    out.mkdir()
    (out / "report.md").write_text("earlier\n")
    (out / "notes.txt").write_text("mine\n")
    assert main(["diagnose", str(tiny), "--max-effects", "0", "-o", str(out), "--force"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["notes.txt", "params.json", "report.md", "residuals_0.png", "rollout.png"]
    assert (out / "report.md").read_text().startswith("# Residual loop")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]  # no temporary folder
