"""Fixtures shared by the test modules."""

from __future__ import annotations

import os

# Headless rendering: MuJoCo picks its GL backend when first imported, and a test module may
# import mujoco before anything of ours sets the default.
os.environ.setdefault("MUJOCO_GL", "egl")

from collections.abc import Callable, Iterator

import pytest
import torch
from hypothesis import HealthCheck, settings

# Property-based tests: a few dozen examples locally (random, fast); `HYPOTHESIS_PROFILE=ci`
# derandomizes them so that CI runs the same examples every time.
settings.register_profile(
    "dev", max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile(
    "ci", max_examples=25, deadline=None, derandomize=True, database=None,
    suppress_health_check=[HealthCheck.too_slow],
)  # fmt: skip
settings.register_profile(
    "long", max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)  # a deeper search when changing a reader: HYPOTHESIS_PROFILE=long
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """Run a test on one torch thread (small float64 problems: threads only add overhead)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture
def one_line_error(capsys: pytest.CaptureFixture[str]) -> Callable[..., str]:
    """``one_line_error(*words)``: the captured stderr is exactly one ``error:`` line
    holding every word, with no traceback; returns that line."""

    def check(*words: str) -> str:
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), err
        assert "Traceback" not in err
        for w in words:
            assert w in lines[0], (w, lines[0])
        return lines[0]

    return check
