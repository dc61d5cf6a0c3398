"""Held-out errors with the window states fitted from two starts: a window whose given
state sits in another basin is fitted again from smoothing, and the error is the
model's, not the basin's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from identification.data.end_caps import RodAxes
from identification.simulation.planted import PlantSpec, planted_dataset
from identification.trajectory.end_cap_data import EndCapData, TrajectorySettings, TrajFit, heldout
from identification.trajectory.param_vector import ParamVector
from tensegrity_env.engine import State
from tensegrity_env.rotations import quat_mul

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_a_window_given_a_far_state_is_fitted_again_from_smoothing() -> None:
    d = planted_dataset(PlantSpec("none", noise=0.001, seed=5, n_train=1, n_val=2, n_test=1,
                                  steps=300))  # fmt: skip
    data = EndCapData(d.dataset, TrajectorySettings(window=100, seed=1))
    vec = ParamVector.at(d.dataset.topology, d.ground_truth.params)
    vec = replace(vec, free=torch.zeros_like(vec.free))
    truth = TrajFit(vec, vec.theta0(), data.windows["train"], 0.0, 1, np.zeros(0))
    sse, m, fitted = heldout(data, truth, "val", 10)
    st = fitted.state
    axes = RodAxes.of(d.dataset.topology)
    half_turn = torch.zeros(4, dtype=torch.float64)
    half_turn[1 + (int(axes.axis[0]) + 1) % 3] = 1.0  # 180 degrees across the rod axis
    q = st.q.clone()
    q[0] = quat_mul(st.q[0], half_turn.expand_as(st.q[0]))
    # window 0 with every rod turned end for end: its end caps swapped, another basin
    far = replace(fitted, state=State(st.p, st.v, q, st.omega))
    stuck = heldout(data, truth, "val", 10, far)[0]
    both = heldout(data, truth, "val", 10, far, fresh=True)[0]
    noise = np.sqrt(sse / m)
    assert noise < 1.2e-3  # the true model at 1 mm noise
    assert np.sqrt(stuck / m) > 5e-3, np.sqrt(stuck / m)  # measured 32 mm
    assert both == pytest.approx(sse, rel=1e-6)
