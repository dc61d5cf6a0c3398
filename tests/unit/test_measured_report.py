"""The measured benchmark's table: each diagnosis shows the selection windows it ran with;
the floor cells' contact is scored against the plant's."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import FRICTION, PLANT_VERSION, Cell, CellData, true_model
from measured_report import (
    OLD_SELECTION,
    contact_errors,
    contact_section,
    coverage_by_model,
    marks,
    matrix_section,
    selection,
    true_contact,
    write_markdown,
)

from identification.commands.diagnose import WINDOW_S, WINDOWS


def _record(effect: str, diagnose_args: str | None, status: str = "ok") -> dict:
    cell = {"setting": "flight", "rate": 120.0, "noise": 1e-3, "dropout": 0.0,
            "effect": effect, "seed": 0, "label": f"flight/120Hz/1mm/drop0%/{effect}/seed0"}  # fmt: skip
    run = {"status": status, "code": 0, "seconds": 1.0, "message": "", "command": ""}
    rec = {"cell": cell, "expected": [], "plant_version": PLANT_VERSION, "identify": run,
           "diagnose": run, "before": {}, "after": {}, "named": [] if status == "ok" else None}  # fmt: skip
    if diagnose_args is not None:  # None: a record from before cells stated their selection
        rec["diagnose_args"] = diagnose_args
        rec["selection"] = selection(diagnose_args)
    return rec


def test_selection_reads_the_window_options_as_diagnose_does():
    assert selection("") == {"window_s": WINDOW_S, "windows": WINDOWS}
    assert selection("--window 300ms --windows 4 --max-effects 2") == {
        "window_s": pytest.approx(0.3), "windows": 4}  # fmt: skip
    assert selection("--windows=32") == {"window_s": WINDOW_S, "windows": 32}


def test_rows_selected_on_other_windows_are_marked(tmp_path):
    cells = {"a": _record("none", ""), "b": _record("force_field", "--windows 32"),
             "c": _record("linear_drag", "--identify-only", status="skipped")}  # fmt: skip
    assert marks(cells["a"]) == "" and marks(cells["b"]) == " ‡"
    assert marks(cells["c"]) == ""  # no diagnosis, nothing selected
    old = _record("quadratic_drag", None)
    default = {"window_s": WINDOW_S, "windows": WINDOWS}
    assert marks(old) == ("" if OLD_SELECTION == default else " ‡")
    text = write_markdown({"cells": cells}, tmp_path / "m.md").read_text()
    row = next(ln for ln in text.splitlines() if ln.startswith("| flight ‡ | force_field"))
    assert f"| 32 x {WINDOW_S:g} s |" in row
    assert f"({WINDOWS} x {WINDOW_S:g} s per split" in text


def test_matrix_counts_combinations_not_seeds_and_counts_crashes():
    a, b = _record("none", ""), _record("none", "")
    b["cell"] = {**b["cell"], "seed": 1, "label": "flight/120Hz/1mm/drop0%/none/seed1"}
    c = _record("linear_drag", "")
    c["cell"] = {**c["cell"], "rate": 60.0, "label": "flight/60Hz/1mm/drop0%/linear_drag/seed0"}
    c["diagnose"] = {**c["diagnose"], "status": "crash"}
    d = _record("slack_cables", "--identify-only", status="skipped")
    lines = matrix_section({"a": a, "b": b, "c": c, "d": d})
    text = "\n".join(lines)
    assert "= 336 combinations; **3 run** (any seed), with a crash in 1 runs." in text
    assert "| flight | none | 1 of 24 | 1 | 0 |" in lines
    assert "| flight | linear_drag | 1 of 24 | 1 | 1 |" in lines
    assert "| flight | slack_cables | 1 of 24 | 0 | 0 |" in lines
    assert "| floor | none | 0 of 24 | 0 | 0 |" in lines


def test_diagnosed_cells_off_the_committed_rate_get_their_own_table(tmp_path):
    here, there = _record("force_field", ""), _record("force_field", "")
    there["cell"] = {**there["cell"], "rate": 240.0, "label": "flight/240Hz/1mm/drop0%/force_field/seed0"}
    text = write_markdown({"cells": {"a": here, "b": there}}, tmp_path / "m.md").read_text()
    main, other = text.split("## Other rates, noise levels and dropouts")
    assert "| flight | force_field | 0 |" in main and "240Hz" not in main.split("## Floor")[0]
    other = other.split("## ")[0]
    assert "| flight/240Hz/1mm/drop0%/force_field/seed0 | - | nothing |" in other
    assert "| flight | force_field" not in other


def test_contact_is_scored_against_the_plants_mujoco_contact(tmp_path):
    cell = Cell("floor", 120.0, 1e-3, 0.0, "linear_drag", 0)
    data = CellData(tmp_path / "m.h5", tmp_path / "c.h5", true_model(cell), cell)
    truth = true_contact(data)
    # MuJoCo's default soft contact (solref 0.02 1, solimp 0.9 0.95 0.001) at a 0.93 ms step
    # (refsafe leaves tc = 0.02 s): K = 1/(dmax tc)^2, B = 2/(dmax tc), per unit mass
    assert truth["stiffness"] == pytest.approx(1 / (0.95 * 0.02) ** 2)
    assert truth["damping"] == pytest.approx(2 / (0.95 * 0.02))
    assert truth["impedance"] == pytest.approx(0.95)
    assert truth["friction"] == pytest.approx(FRICTION) and truth["height"] == 0.0
    fitted = {**truth, "stiffness": 1.1 * truth["stiffness"], "friction": 0.8 * FRICTION,
              "height": -0.002}  # fmt: skip
    doc = {"effects": [{"name": "linear_drag", "params": {}},
                       {"name": "ground_contact", "params": fitted}]}  # fmt: skip
    errors = contact_errors(doc, truth)
    assert errors is not None
    assert errors["stiffness"] == pytest.approx(0.1) and errors["friction"] == pytest.approx(0.2)
    assert errors["damping"] == errors["impedance"] == 0.0
    assert errors["height_mm"] == pytest.approx(2.0)
    assert contact_errors({"effects": []}, truth) is None
    rec = _record("linear_drag", "")
    rec["after"] = {"contact": errors}
    row = next(ln for ln in contact_section({"floor/x": rec}) if ln.startswith("| floor/x "))
    assert row.endswith("| diagnose | 10 | 0 | 0 | 20 | 2 |")


def test_floor_cells_show_their_floor_fit_windows(tmp_path):
    from measured_report import OLD_FLOOR_WINDOWS, floor_windows, floor_windows_text

    from identification.trajectory.end_cap_data import FINAL_FLOOR_WINDOWS, FLOOR_WINDOWS

    assert floor_windows("", "") == {"identify": FLOOR_WINDOWS, "diagnose": FLOOR_WINDOWS,
                                     "diagnose_final": FINAL_FLOOR_WINDOWS}  # fmt: skip
    given = floor_windows("--floor-windows 24", "--max-effects 1 --floor-windows 12 "
                          "--final-floor-windows 0")  # fmt: skip
    assert given == {"identify": 24, "diagnose": 12, "diagnose_final": 0}
    flight = _record("none", "")
    floor, old = _record("none", "--floor-windows 12"), _record("none", "")
    refit = _record("none", "")
    for r in (floor, old, refit):
        r["cell"] = {**r["cell"], "setting": "floor", "label": "floor/120Hz/1mm/drop0%/none/seed0"}
    floor["floor_windows"] = {"identify": FLOOR_WINDOWS, "diagnose": 12, "diagnose_final": 12}
    refit["floor_windows"] = {"identify": 8, "diagnose": 8, "diagnose_final": 24}
    assert floor_windows_text(refit) == "8 / 8 → 24"
    assert floor_windows_text(flight) == "-"
    assert floor_windows_text(floor) == f"{FLOOR_WINDOWS} / 12"
    assert floor_windows_text(old) == f"{OLD_FLOOR_WINDOWS} / {OLD_FLOOR_WINDOWS}"
    text = write_markdown({"cells": {"a": floor}}, tmp_path / "m.md").read_text()
    assert f"| {WINDOWS} x {WINDOW_S:g} s | {FLOOR_WINDOWS} / 12 |" in text


def test_coverage_is_split_by_whether_the_fitted_model_holds_the_plant():
    """identify on a plant the declared model holds, identify on one it lacks an effect
    of, and diagnose where it named the effect: three rows, each its own fraction."""
    held, lacking = _record("none", ""), _record("linear_drag", "")
    lacking["expected"] = ["linear_drag"]
    held["before"]["coverage"] = [True, True, True, False]
    lacking["before"]["coverage"] = [True, False, False, False]
    lacking["named"], lacking["named_right"] = ["linear_drag"], True
    lacking["after"]["coverage"] = [True, True]
    lines = coverage_by_model({"a": held, "b": lacking})
    assert "| flight | `identify` | the declared model holds the plant | 4 | 75.0 % |" in lines
    assert ("| flight | `identify` | the declared model lacks the planted effect | 4 | 25.0 % |"
            in lines)  # fmt: skip
    assert "| flight | `diagnose` | the effects named right | 2 | 100.0 % |" in lines
    assert not any("an effect missed" in ln for ln in lines)


def test_a_run_s_cpu_time_is_shown_beside_its_wall_time_where_recorded(tmp_path):
    recorded = _record("none", "")
    recorded["diagnose"] = {**recorded["diagnose"], "seconds": 387.4, "cpu_seconds": 153.3}
    text = write_markdown({"cells": {"a": recorded}}, tmp_path / "m.md").read_text()
    row = next(ln for ln in text.splitlines() if ln.startswith("| flight | none"))
    assert "| ok 1 s | ok 387 s (153 s CPU) |" in row  # identify: recorded before, no CPU


def test_run_cli_records_the_command_s_cpu_time(tmp_path):
    import bench_measured

    run = bench_measured.run_cli(["--help"], tmp_path, "help.log", timeout=120)
    assert run["status"] == "ok" and 0 < run["cpu_seconds"] < 120
