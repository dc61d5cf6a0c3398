"""On the floor a rod's spin about its own axis is part of the state a window must fit.

Friction acts at an end cap's contact point, one rod radius below the axis, so it
spins a rod about its axis (tiny axial inertia: tens of rad/s for a rod rolling on the
floor), and that spin sets how the contact point slips. End caps cannot show it. The
plant is ``benchmarks/measured_plant.py``'s icosahedron on MuJoCo's soft floor; end caps
are computed from its clean rod states, and the model is the true one.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from identification.trajectory.floor_fit import with_floor
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.window_errors import window_sse
from identification.trajectory.window_states import fit_states
from identification.trajectory.windows import STATE_KEYS, cut_windows, local_basis
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import GroundContact
from tensegrity_env.engine import Engine, State, substeps_for
from tensegrity_env.rotations import quat_to_matrix

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from measured_plant import clean_rolling

pytestmark = [pytest.mark.usefixtures("one_torch_thread"), pytest.mark.slow]

STEPS = 30  # 0.25 s at 120 Hz, the floor fit's window


def _axial(state: State) -> torch.Tensor:
    """Each rod's angular velocity about its end-cap axis (rod frame z), (B, R) [rad/s]."""
    return (state.omega * quat_to_matrix(state.q)[..., :, 2]).sum(-1)


@pytest.fixture(scope="module")
def rolling():
    """Two clean 30-step windows of the icosahedron rolling on the floor, the true model."""
    truth, clean = clean_rolling(seed=0)
    topo = icosahedron().topology
    grid = {k: getattr(clean, k) for k in STATE_KEYS}
    windows = cut_windows(clean.nodes, clean.control, grid, STEPS)
    spins = _axial(windows.state).abs().max(-1).values
    windows = windows.take(np.sort(np.argsort(-spins.numpy())[:2]))  # the fastest spins
    contact = GroundContact(topo, friction=1.0, height=0.0)  # MuJoCo's default floor
    vec = with_floor(ParamVector.at(topo, truth.params), [], contact, None)
    theta = vec.theta0()
    engine = Engine(topo, 1 / 120, substeps=substeps_for(1 / 120))
    return vec.engine(engine, theta), vec.held_at(theta), windows


def _rms(engine, vec, windows) -> float:
    basis = local_basis(vec.axes)
    return float(np.sqrt(window_sse(engine, vec, windows, basis, vec.theta0(), 8)
                         / windows.residuals))  # fmt: skip


def test_true_model_and_state_reproduce_the_rolling_plant(rolling):
    engine, vec, windows = rolling
    assert _axial(windows.state).abs().max() > 20.0  # rad/s: the rods really spin
    assert _rms(engine, vec, windows) < 1e-9


def test_window_states_on_the_floor_need_the_axial_spin(rolling):
    engine, vec, windows = rolling
    s = windows.state
    axis = quat_to_matrix(s.q)[..., :, 2]
    spinless = replace(windows, state=replace(s, omega=s.omega - _axial(s)[..., None] * axis))
    # the spin the end caps cannot show moves them by millimetres within 0.25 s
    assert _rms(engine, vec, spinless) > 1e-3
    without = fit_states(engine, vec, spinless, 10, spin=False)
    with_spin = fit_states(engine, vec, spinless, 10, spin=True)
    e_without, e_with = (float(np.sqrt(f.history[-1])) for f in (without, with_spin))
    assert e_without > 5e-4, e_without  # no spinless state explains the rolling
    assert e_with < 0.5 * e_without, (e_with, e_without)  # 0.26 against 0.72 mm measured
