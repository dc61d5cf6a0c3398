"""The real-take benchmark's report: generated from its JSON, each target judged."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from bench_real import _kabsch_rms, main, markdown


def _record(identified: list[float] | None) -> dict:
    held = {"horizon_s": [0.1, 0.25, 0.5, 1.0], "pieces": 2, "piece_s": 2.0,
            "nominal_rms_m": [0.03, 0.03, 0.03, float("nan")]}  # fmt: skip
    if identified is not None:
        held["identified_rms_m"] = identified
    return {"file": "take.csv", "robot": "robot.yaml", "heldout": held,
            "runs": {"identify": {"returncode": 2, "seconds": 10.0, "last": "error: the fit failed"}},
            "rest_shape_rms_m": {"nominal": 0.014, "identified": 0.002},
            "stretches": [{"start_s": 0.0, "end_s": 6.37, "kind": "rest"}]}  # fmt: skip


def test_the_report_judges_each_target_from_the_numbers() -> None:
    text = markdown({"good": _record([0.002, 0.004, 0.01, 0.02]), "bad": _record([0.02, 0.02, 0.02, 0.03]),
                     "none": _record(None), "meta": {"command": "cmd", "seconds": 1.0}})  # fmt: skip
    good, bad, none = (text.split(f"## {k}")[1].split("##")[0] for k in ("good", "bad", "none"))
    assert "| identified | 0.20 | 0.40 | 1.00 | 2.00 |" in good and "| nominal | 3.00 | 3.00 | 3.00 | - |" in good
    assert "1/3 of nominal at 0.25 s: met (0.40 cm against 3.00 cm)" in good
    assert "<= 1 cm at 0.25 s: met" in good and "rest shape <= 3 mm: met (2.00 mm)" in good
    assert "1/3 of nominal at 0.25 s: missed (2.00 cm against 3.00 cm)" in bad and "<= 1 cm at 0.25 s: missed" in bad
    assert "not evaluated (no identified model)" in none and "`identify`: exit 2" in none
    assert "error: the fit failed" in none and "rest 0.00-6.37 s" in none


def test_rest_shapes_are_compared_up_to_a_rigid_motion() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(12, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    assert _kabsch_rms(a, a @ q.T + [1.0, 2.0, 3.0]) < 1e-12
    b = a.copy()
    b[0] += [0.012, 0.0, 0.0]  # one cap 12 mm off
    assert 0.001 < _kabsch_rms(a, b) < 0.012 / np.sqrt(12) + 1e-9


def test_without_the_recordings_it_says_so_and_succeeds(tmp_path: Path, capsys) -> None:
    assert main(["--data", str(tmp_path / "absent"), "--json", str(tmp_path / "real.json")]) == 0
    assert "skipped: no real recordings" in capsys.readouterr().out
    assert not (tmp_path / "real.json").exists()


def test_missing_values_are_null_in_standard_json_with_their_reason(tmp_path: Path) -> None:
    from bench_real import write_results

    rec = _record([0.002, 0.004, None, None])
    rec["missing"] = {"heldout.identified_rms_m[2]": "diverged: non-finite end caps in 1 of 8 rollouts by then",
                      "heldout.identified_rms_m[3]": "diverged: non-finite end caps in 1 of 8 rollouts by then"}  # fmt: skip
    rec["rest_shape_rms_m"]["diagnosed"] = float("inf")
    cross = {"a->b": {"horizon_s": [0.1, 0.25, 0.5, 1.0], "nominal_rms_m": [0.01] * 4,
                      "identified_rms_m": [float("nan")] * 4}}  # fmt: skip
    path, md = tmp_path / "real.json", tmp_path / "real.md"
    write_results(path, md, {"take": rec, "cross_take": cross, "meta": {"command": "cmd", "seconds": 1.0}})

    def refuse(name: str) -> None:
        raise AssertionError(f"non-standard JSON constant {name}")

    doc = json.loads(path.read_text(), parse_constant=refuse)
    take = doc["take"]
    assert take["heldout"]["nominal_rms_m"][3] is None and take["rest_shape_rms_m"]["diagnosed"] is None
    assert take["missing"]["heldout.identified_rms_m[2]"].startswith("diverged")
    assert take["missing"]["heldout.nominal_rms_m[3]"] == "not a finite number (nan)"
    assert take["missing"]["rest_shape_rms_m.diagnosed"] == "not a finite number (inf)"
    assert doc["cross_take"]["a->b"]["identified_rms_m"] == [None] * 4
    text = md.read_text()
    assert "- no value: identified at 0.5 s, 1 s: diverged: non-finite end caps in 1 of 8 rollouts" in text
    assert "- no value: nominal at 1 s: not a finite number (nan)" in text
    assert "- no value: diagnosed rest shape: not a finite number (inf)" in text and "diagnosed -" in text
    assert "- no value (a->b): identified at 0.1 s, 0.25 s, 0.5 s, 1 s: not a finite number (nan)" in text
    assert "target identified <= 1 cm at 0.25 s: met" in text


def test_a_diverging_rollout_is_no_value_with_its_reason(tmp_path: Path) -> None:
    from dataclasses import replace

    from bench_real import HORIZONS, open_loop
    from measured_plant import Cell, write_cell

    from identification.data.dataset import read_dataset
    from tensegrity_env.model import Model

    cell = write_cell(Cell("flight", 120.0, 1e-4, 0.0, "none"), tmp_path)
    ds = read_dataset(cell.measured)
    nodes, p = ds.split("test").nodes, cell.truth.params
    good, why = open_loop(Model(ds.topology, p, dt=ds.dt), nodes, ds.dt, HORIZONS)
    assert all(x is not None and x < 0.1 for x in good) and why == [None] * 4
    bad, why = open_loop(Model(ds.topology, replace(p, stiffness=p.stiffness * 1e6), dt=ds.dt), nodes, ds.dt, HORIZONS)
    assert bad == [None] * 4 and all(w is not None and w.startswith("diverged: non-finite end caps") for w in why)
