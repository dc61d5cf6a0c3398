"""``identify`` on end caps only: the trajectory identification, physical and checked."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import Cell, write_cell

from tensegrity_sr.cli import main as cli


@pytest.mark.slow
def test_identify_runs_the_trajectory_identification_on_end_caps(tmp_path, capsys) -> None:
    cell = Cell("flight", 120.0, 1e-3, 0.0, "none")
    data = write_cell(cell, tmp_path)
    truth = data.truth.params.numpy()
    out = tmp_path / "params.json"
    anchor = f"mass[rod0]={float(truth['mass'][0])!r}"
    assert cli(["identify", str(data.measured), "--anchor", anchor, "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "trajectory identification" in text and "9 steps" not in text
    doc = json.loads(out.read_text())
    p = {k: np.asarray(v) for k, v in doc["params"].items()}
    for group, tol in (("mass", 0.03), ("stiffness", 0.03), ("damping", 0.10)):
        assert np.abs(p[group] / truth[group] - 1).max() < tol, group
    # stated standard errors: none exactly 0, and the truth mostly within 2 of them
    se = doc["uncertainty"]
    assert se and min(se.values()) > 0
    k = np.array([se[f"stiffness[spring{s}]"] for s in range(24)])
    assert np.mean(np.abs(p["stiffness"] - truth["stiffness"]) <= 2 * k) >= 0.8
    assert doc["provenance"]["physics_dt_s"] == 1e-3
    assert abs(doc["provenance"]["noise_level_m"] / 1e-3 - 1) < 0.1


def test_identify_refuses_regression_options_on_end_caps(tmp_path, capsys) -> None:
    from identification.data.dataset import Dataset, Split, write_dataset
    from tensegrity_env.assemblies import icosahedron

    topo = icosahedron().topology
    nodes = np.random.default_rng(0).normal(size=(1, 11, 12, 3))
    ds = Dataset(topo, 1 / 120, {"train": Split(nodes=nodes, control=np.zeros((1, 10, 6, 3)))})
    path = write_dataset(tmp_path / "caps.h5", ds)
    assert cli(["identify", str(path), "--shared", "-o", str(tmp_path / "p.json")]) == 2
    assert "--shared need rod states" in capsys.readouterr().err
    assert not (tmp_path / "p.json").exists()


def test_end_caps_on_a_floor_are_fitted_with_contact_at_any_rate(tmp_path, capsys, monkeypatch) -> None:
    """At 1000 Hz the floor cell's drops are airborne for 50 samples and more; the declared
    model alone, fitted through the impacts, diverged. Any data that reach a floor go to
    the floor fit (stopped here at its start)."""
    from identification.commands import identify_end_caps
    from identification.data.dataset import read_dataset
    from identification.trajectory.airborne import has_airborne_stretch
    from tensegrity_env.io_utils import StageError

    def floor_fit(*args, **kwargs):
        raise StageError("the floor fit", "reached", "nothing")

    data = write_cell(Cell("floor", 1000.0, 1e-3, 0.0, "none"), tmp_path)
    monkeypatch.setattr(identify_end_caps, "identify_on_floor", floor_fit)
    ds = read_dataset(data.measured)
    assert has_airborne_stretch(ds.split("train").nodes, ds.topology)
    assert cli(["identify", str(data.measured), "-o", str(tmp_path / "p.json")]) != 0
    captured = capsys.readouterr()
    assert "end caps reach a floor" in captured.out
    assert "the floor fit failed: reached" in captured.err
    assert not (tmp_path / "p.json").exists()
