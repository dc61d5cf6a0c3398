"""What identify and diagnose say of the floor fit's two starts (identification.commands.two_starts)."""

from __future__ import annotations

from identification.commands.two_starts import two_starts_report
from identification.trajectory.floor_declared import STARTS_APART, StartCheck


def test_starts_apart_are_a_warning_naming_the_parameter(capsys) -> None:
    check = StartCheck("mass[rod3]", 2 * STARTS_APART, (1.2e-3, 1.0e-3), 1, "val windows of 30 steps")
    doc = two_starts_report(check)
    out = capsys.readouterr().out
    assert out.startswith("warning: ") and "mass[rod3] 6 %" in out and "kept the second" in out
    assert doc["tried"] and doc["apart"] and doc["kept"] == "second"
    assert doc["largest_difference"] == {"name": "mass[rod3]", "relative": 2 * STARTS_APART}


def test_starts_that_agree_are_one_line_and_one_start_says_so(capsys) -> None:
    check = StartCheck("stiffness[s0]", STARTS_APART / 2, (1.0e-3, 1.0e-3), 0, "val windows")
    assert not two_starts_report(check)["apart"]
    assert not capsys.readouterr().out.startswith("warning")
    assert two_starts_report(None) == {"tried": False}
    assert "one start" in capsys.readouterr().out
