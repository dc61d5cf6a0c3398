"""The measured benchmark's table: each diagnosis shows the selection windows it ran with."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import PLANT_VERSION
from measured_report import OLD_SELECTION, marks, matrix_section, selection, write_markdown

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
