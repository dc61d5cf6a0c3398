"""Fixtures shared by the test modules."""

from __future__ import annotations

import os

# Headless rendering: MuJoCo picks its GL backend when first imported, and a test module may
# import mujoco before anything of ours sets the default.
os.environ.setdefault("MUJOCO_GL", "egl")

from collections.abc import Iterator

import pytest
import torch


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """Run a test on one torch thread (small float64 problems: threads only add overhead)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
