"""The drawn-plant benchmark: its invariants judge what `identify` wrote, a rerun skips
the plants already measured on the same draw, and a plant MuJoCo cannot run is a
record that names the stage."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import bench_family
from family_invariants import (
    at_the_truth,
    contact_errors,
    largest_move,
    relative_se,
    silently_wrong,
    structure_error,
    verdict,
    warned,
    worst_errors,
)


def _doc(mass: list[float], se: float, effects: list[dict[str, Any]] | None = None,
         unseen: dict[str, str] | None = None) -> dict[str, Any]:  # fmt: skip
    return {
        "topology": {"rods": [{"name": "a"}, {"name": "b"}], "springs": [{"name": "s"}]},
        "params": {"mass": mass, "inertia": [[1.0, 1.0, 0.02]] * 2, "stiffness": [100.0],
                   "damping": [1.0], "rest_length": [0.5]},
        "uncertainty": {"mass[a]": se, "mass[b]": se, "stiffness[s]": 1.0},
        "effects": effects or [],
        "identifiability": {"not_identifiable": unseen or {}},
    }


TRUTH = {"mass": np.array([1.0, 2.0]), "inertia": np.array([[1.0, 1.0, 0.01]] * 2),
         "stiffness": np.array([100.0]), "damping": np.array([1.1]),
         "rest_length": np.array([0.5])}  # fmt: skip


def test_the_largest_move_is_counted_in_standard_errors() -> None:
    name, z, rms = largest_move(_doc([1.0, 2.3], 0.1), TRUTH)
    assert name == "mass[b]" and z == pytest.approx(3.0) and rms == pytest.approx(np.sqrt(3))
    assert largest_move(_doc([1.0, 2.0], 0.1), TRUTH)[1:] == (0.0, 0.0)
    doc = _doc([1.0, 2.0], 0.1)
    doc["uncertainty"] = {}
    assert largest_move(doc, TRUTH) == ("", 0.0, 0.0)


def test_worst_errors_leave_the_assumed_axial_moment_out() -> None:
    w = worst_errors(_doc([1.0, 2.2], 0.1)["params"], TRUTH)
    assert w["mass"] == pytest.approx(0.1) and w["inertia"] == 0.0
    assert w["damping"] == pytest.approx(1 / 11)


def test_contact_errors_skip_what_the_data_cannot_pin() -> None:
    want = [{"name": "ground_contact", "params": {"stiffness": 1e3, "damping": 10.0,
                                                  "friction": 1.0}}]  # fmt: skip
    got = [{"name": "ground_contact", "params": {"stiffness": 1.2e3, "damping": 10.0,
                                                 "friction": 3.0}}]  # fmt: skip
    doc = _doc([1.0, 2.0], 0.1, got, {"ground_contact.friction": "no sliding"})
    errs, unseen = contact_errors(doc, want)
    assert errs == pytest.approx({"stiffness": 0.2, "damping": 0.0}) and "friction" in unseen
    errs, _ = contact_errors(_doc([1.0, 2.0], 0.1), want)  # no contact identified at all
    assert errs["stiffness"] == float("inf")
    assert contact_errors(_doc([1.0, 2.0], 0.1), []) == ({}, {})


def _record(start: str, **kw: Any) -> dict[str, Any]:
    run = {"status": "ok", "message": ""}
    return {"start": start, "identify": run, "rms_over_noise": 1.0, "moved": ["", 0.0, 0.0],
            "worst": dict.fromkeys(bench_family.GROUPS, 0.0), "contact": {}, **kw}  # fmt: skip


def test_the_verdict_names_the_stage_and_why() -> None:
    assert verdict(_record("truth")) == ""
    assert "RMS 1.5 x noise" in verdict(_record("truth", rms_over_noise=1.5))
    # the largest of many honest moves is ~3 standard errors: their RMS is judged
    assert verdict(_record("truth", moved=["mass[b]", 3.0, 1.0])) == ""
    miss = verdict(_record("truth", moved=["mass[b]", 3.0, 1.8]))
    assert "an RMS of 1.8 standard errors > 1.5 (largest: mass[b], 3)" in miss
    assert "nan" in verdict(_record("truth", rms_over_noise=float("nan")))
    worst = {**dict.fromkeys(bench_family.GROUPS, 0.0), "mass": 0.02, "damping": 0.09,
             "rest_length": 0.5}  # fmt: skip
    assert verdict(_record("default", worst=worst)) == ""  # rest length is not judged
    assert "stiffness 4 %" in verdict(_record("default", worst={**worst, "stiffness": 0.04}))
    assert "contact damping 12 %" in verdict(_record("default", contact={"damping": 0.12}))
    failed = _record("default", identify={"status": "failed", "message": "diverged"})
    assert verdict(failed) == "identify (failed): diverged"


def test_a_default_start_fit_is_also_judged_by_the_truths_own_check() -> None:
    """Tolerances tighter than the data's standard errors fail any start: the default
    start's fit is also judged as the truth's is, and the stated errors are reported."""
    far = _record("default", worst={**dict.fromkeys(bench_family.GROUPS, 0.0), "damping": 0.4},
                  moved=["damping[s]", 1.9, 1.1])  # fmt: skip
    assert "damping 40 %" in verdict(far) and at_the_truth(far) == ""
    assert "an RMS of 1.6 standard errors" in at_the_truth(_record("default", moved=["m", 3.0, 1.6]))
    assert at_the_truth(_record("default", identify={"status": "failed"})) == "identify (failed)"
    se = relative_se(_doc([1.0, 2.0], 0.1))
    assert se == pytest.approx({"mass": 0.075, "stiffness": 0.01})  # medians of 0.1 and 0.05


def test_a_fit_written_off_its_invariants_must_carry_the_warning() -> None:
    from identification.trajectory.stage_check import POORLY_DETERMINED

    off = {**dict.fromkeys(bench_family.GROUPS, 0.0), "mass": 0.5}
    quiet = _record("default", worst=off, worst_se_ratio=POORLY_DETERMINED / 2)
    assert silently_wrong(quiet) and not warned(quiet)
    loud = _record("default", worst=off, worst_se_ratio=POORLY_DETERMINED)
    assert warned(loud) and not silently_wrong(loud)
    assert not silently_wrong(_record("default", worst_se_ratio=0.0))  # met: nothing to warn of
    damped = {**dict.fromkeys(bench_family.GROUPS, 0.0), "damping": 0.5}
    assert not silently_wrong(_record("default", worst=damped))  # damping: not the warning's
    refused = _record("default", identify={"status": "failed", "message": "x"})
    assert not silently_wrong(refused) and not warned(refused)
    # the floor fit's two starts ending apart is a warning too
    apart = _record("default", worst=off, worst_se_ratio=0.0,
                    two_starts={"tried": True, "apart": True})  # fmt: skip
    assert warned(apart) and not silently_wrong(apart)
    agreed = _record("default", worst=off, two_starts={"tried": True, "apart": False})
    assert silently_wrong(agreed)


def test_a_nan_error_counts_as_off() -> None:
    nan = {**dict.fromkeys(bench_family.GROUPS, 0.0), "mass": float("nan")}
    assert np.isnan(structure_error(_record("default", worst=nan)))
    assert silently_wrong(_record("default", worst=nan, worst_se_ratio=0.0))
    assert structure_error(_record("default", worst={"inertia": 0.02, "stiffness": 0.05})) == 0.05


def test_a_plant_mujoco_cannot_run_is_a_record_naming_the_plant(monkeypatch) -> None:
    def diverge(d, folder, share):
        raise RuntimeError(f"{d.label}: MuJoCo diverged in trajectory 0")

    monkeypatch.setattr(bench_family, "write_family_cell", diverge)
    recs = bench_family.run_plant(3, "floor", ["truth", "default"], 0.5, 10.0, None)
    assert [r["start"] for r in recs] == ["truth", "default"]
    assert all(r["verdict"].startswith("plant: family3/floor") for r in recs)
    assert recs[0]["draw_id"] == bench_family.draw_id(bench_family.draw(3, "floor"), 0.5)


def test_a_rerun_skips_the_plants_measured_on_the_same_draw() -> None:
    same = bench_family.draw_id(bench_family.draw(0, "flight"), 0.5)
    records = [{"seed": 0, "setting": "flight", "start": "truth", "draw_id": same},
               {"seed": 1, "setting": "flight", "start": "truth", "draw_id": "other"}]  # fmt: skip
    jobs = list(bench_family.todo(records, [0, 1], ["flight"], ["truth", "default"], 0.5, False))
    assert jobs == [(0, "flight", ["default"]), (1, "flight", ["truth", "default"])]
    assert list(bench_family.todo(records, [0], ["flight"], ["truth"], 0.5, False)) == []
    assert list(bench_family.todo(records, [0], ["flight"], ["truth"], 1.0, False)) != []
    assert list(bench_family.todo(records, [0], ["flight"], ["truth"], 0.5, True)) != []
