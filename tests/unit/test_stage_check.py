"""Stage checks: the noise level read from end caps, and one-line failures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from identification.trajectory.stage_check import check_stage, fit_diverged, noise_level
from tensegrity_env.io_utils import StageError


def test_noise_level_of_smooth_motion_plus_white_noise() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(361) / 120.0  # 3 s at 120 Hz
    # 5 cm oscillations at 2 Hz and a ballistic arc
    motion = (0.05 * np.sin(2 * np.pi * 2 * t)[None, :, None, None]
              + (1.0 * t - 4.9 * t**2)[None, :, None, None] * np.ones((4, 1, 12, 3)))  # fmt: skip
    for sigma in (0.5e-3, 1e-3, 2e-3):
        noisy = motion + sigma * rng.standard_normal(motion.shape)
        assert noise_level(noisy) == pytest.approx(sigma, rel=0.05)
    assert noise_level(motion) < 5e-5  # clean: far below a millimetre


def test_a_diverged_stage_fails_in_one_line_naming_the_stage() -> None:
    assert not fit_diverged(3e-3, 1e-3)  # a missing effect: a few noise levels
    assert fit_diverged(math.nan, 1e-3) and fit_diverged(1.3e6, 1e-3) and fit_diverged(0.2, 1e-3)
    with pytest.raises(StageError) as e:
        check_stage("the declared model's fit", float("nan"), 1e-3, "shorter windows")
    msg = str(e.value)
    assert msg.startswith("the declared model's fit failed: ") and "\n" not in msg
    assert msg.endswith("try shorter windows")
    check_stage("x", 2e-3, 1e-3, "y")  # plausible: no error


def _row(name: str, group: str, value: float, stderr: float, status: str = "identified"):
    from identification.linear.regression import ParameterRow

    return ParameterRow(name, group, 0, value, stderr, "1", status)


def test_a_parameter_the_data_does_not_determine_fails_the_stage_naming_it() -> None:
    from identification.trajectory.stage_check import check_determined, undetermined

    # the masses of rods decoupled by springs fitted to almost nothing: any value fits
    rows = [
        _row("mass[rod0]", "mass", 2.4, float("nan"), "anchored"),
        _row("mass[rod1]", "mass", 218.7, 3.5e4),
        _row("mass[rod2]", "mass", 0.39, 0.71),
        _row("stiffness[spring3]", "stiffness", 0.04, 22.3),
        _row("damping[spring3]", "damping", 0.02, 19.5),  # damping is not judged
    ]
    assert [n for n, _ in undetermined(rows)] == ["stiffness[spring3]", "mass[rod1]", "mass[rod2]"]
    with pytest.raises(StageError) as e:
        check_determined("the trajectory fit", rows, "a start near the robot")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("the trajectory fit failed: stiffness[spring3]")
    assert "2 more parameters" in msg and "not written" in msg


def test_a_spring_the_take_barely_stretches_alone_is_written() -> None:
    from identification.trajectory.stage_check import (
        POORLY_DETERMINED,
        check_determined,
        undetermined,
    )

    rows = [
        _row("mass[rod1]", "mass", 0.12, 0.002),
        _row("stiffness[spring23]", "stiffness", 400.0, 3600.0),  # 9 x its value
    ]
    check_determined("the trajectory fit", rows, "")  # masses determined: written ...
    assert undetermined(rows, POORLY_DETERMINED) == [("stiffness[spring23]", 9.0)]  # ... warned


def test_well_determined_and_anchored_parameters_pass() -> None:
    from identification.trajectory.stage_check import check_determined, undetermined

    rows = [
        _row("mass[rod0]", "mass", 2.4, float("nan"), "anchored"),
        _row("mass[rod1]", "mass", 2.5, 0.04),
        _row("stiffness[spring0]", "stiffness", 2000.0, 31.0),
        _row("damping[spring0]", "damping", 0.5, 2.0),  # barely seen damping: not judged
        _row("inertia[rod1,y]", "inertia", 1e-3, float("nan"), "not identifiable"),
        _row("mass[rod2]", "mass", 2.5, 0.3, "ratio"),
    ]
    assert undetermined(rows) == []
    check_determined("the trajectory fit", rows, "")
    # a value fitted to zero with a finite error is not determined either
    assert undetermined([_row("stiffness[spring1]", "stiffness", 0.0, 1.0)])


def test_a_poorly_determined_parameter_is_found_at_the_warning_limit() -> None:
    from identification.trajectory.stage_check import POORLY_DETERMINED, undetermined

    rows = [
        _row("mass[rod1]", "mass", 2.0, 1.4),
        _row("stiffness[spring0]", "stiffness", 100.0, 3.0),
    ]
    assert undetermined(rows) == []  # written ...
    assert undetermined(rows, POORLY_DETERMINED) == [("mass[rod1]", 0.7)]  # ... with a warning
    assert undetermined([_row("mass[rod1]", "mass", 2.0, float("inf"))])  # unseen: refused
