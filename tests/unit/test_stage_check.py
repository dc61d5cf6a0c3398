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
