"""``tensegrity-sr experiment paper --scale small`` writes every figure and the table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from identification.experiments.paper import ASSEMBLIES, MODELS, REFERENCE
from identification.experiments.paper_report import horizons
from tensegrity_sr.cli import main

FIGURES = [f"{kind}_{a}.png" for a in ASSEMBLIES for kind in ("errors", "training")]
TABLES = ["results.md", "results.json", "efficiency.md", "efficiency.json", "efficiency.png"]
TABLES += ["data_requirement.png"]
TABLES += [f"parameters_{a}.md" for a in ASSEMBLIES]


@pytest.fixture(scope="module")
def out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("experiment")
    assert main(["experiment", "paper", "--scale", "small", "-o", str(path)]) == 0
    return path


def test_every_figure_and_table_is_written(out: Path) -> None:
    for name in FIGURES + TABLES:
        f = out / name
        assert f.is_file() and f.stat().st_size > 0, name
    for name in FIGURES:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name


def test_results_table_has_every_model_assembly_and_the_sweep(out: Path) -> None:
    md = (out / "results.md").read_text()
    assert "tensegrity-sr experiment paper --scale small" in md
    assert "2-core CPU" in md or "-core CPU" in md
    assert "wall time" in md
    for a in ASSEMBLIES:
        assert f"## {a}" in md
    for m in (*MODELS, REFERENCE):
        assert f"| {m} |" in md
    for frac in ("10%", "1%", "0.1%", "0.01%"):
        assert f"| {frac} |" in md
    assert "## The paper's claims, checked" in md


def test_ours_beats_every_baseline_and_recovers_the_parameters(out: Path) -> None:
    text = (out / "results.json").read_text()
    assert "Infinity" not in text and "NaN" not in text  # standard JSON: null where diverged
    data = json.loads(text)
    for a in ASSEMBLIES:
        res = data["assemblies"][a]
        curves = {
            k: np.array([np.inf if v is None else v for v in c]) for k, c in res["curves"].items()
        }
        T = len(curves["Ours"]) - 1
        assert T == res["counts"]["steps"] and T in horizons(T)
        assert curves["Ours"][T] < 1e-9
        assert max(res["group_errors"].values()) < 1e-6
        # 16 training trajectories: too little for every baseline (Koopman+Int catches up
        # with ours only on the paper-scale data, see docs/results/results.md)
        for m in MODELS[1:]:
            assert np.all(curves["Ours"][1:] < curves[m][1:]), (a, m)
        for m in ("Interaction", "Interaction+Int"):
            h = res["training"][m]["history"]
            assert h["n_train"] == res["counts"]["train"] * T and len(h["val_loss"]) >= 1
