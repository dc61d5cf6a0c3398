"""The MuJoCo plants' NumPy winding (:class:`~tensegrity_env.mjcf.winches.Winding`)
against the engine's winch step (:func:`~tensegrity_env.engine.winch.winch_step`, the
reference): the same numbers, with and without motor lag, clamped ranges and clipped
commands included."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tensegrity_env.engine.winch import REST, SPEED, winch_step
from tensegrity_env.mjcf.winches import Winding
from tensegrity_env.params import Params

#: physics step [s]
H = 1e-3
#: batch of winch sets stepped together
B = 4


def winch_params(lags: tuple[float, ...]) -> Params:
    """Five winches on five springs of one rod (only the winch fields wind); ranges narrow
    enough that commands held for 0.1 s reach both ends."""
    return Params.create(
        stiffness=[100.0] * 5, damping=[1.0] * 5, rest_length=[0.5] * 5, mass=[1.0],
        inertia=[[1.0, 1.0, 1.0]],
        winch_speed=[0.1, 0.05, 0.2, 0.08, 0.12],
        winch_min=[0.495, 0.40, 0.49, 0.45, 0.499],
        winch_max=[0.52, 0.90, 0.51, 1.00, 0.501],
        winch_lag=lags,
    )  # fmt: skip


@pytest.mark.parametrize("lags", [(0.03, 0.0, 0.01, 0.2, 0.005), (0.0,) * 5])
def test_numpy_winding_is_the_engine_winch_step(lags: tuple[float, ...]) -> None:
    """2000 steps, commands in [-1.5, 1.5] held 100 steps each (clipped): every state
    and every step's starting rest length as the engine's, to the bit."""
    params = winch_params(lags)
    winding = Winding(params, H)
    rng = np.random.default_rng(7)
    commands = rng.uniform(-1.5, 1.5, (20, B, 5))
    ref = torch.stack([torch.full((B, 5), 0.5, dtype=torch.float64),
                       torch.zeros(B, 5, dtype=torch.float64)], dim=-1)  # fmt: skip
    rest, speed = ref[..., REST].numpy().copy(), ref[..., SPEED].numpy().copy()
    lows = highs = 0
    for u in commands:
        before, rest, speed = winding.wind(rest, speed, u, steps=100)
        for k in range(100):
            np.testing.assert_array_equal(before[k], ref[..., REST].numpy())
            ref = winch_step(ref, params, torch.as_tensor(u), H)
        np.testing.assert_array_equal(rest, ref[..., REST].numpy())
        np.testing.assert_array_equal(speed, ref[..., SPEED].numpy())
        lows += int(np.sum(rest == params.winch_min.numpy()))
        highs += int(np.sum(rest == params.winch_max.numpy()))
    assert lows > 0 and highs > 0  # both ends of the ranges were reached
    assert np.ptp(rest) > 0.01  # the cables were wound apart


def test_numpy_winding_without_command_holds_the_motors() -> None:
    """No command: the motors' speed decays through their lag, as the engine's None."""
    params = winch_params((0.03, 0.0, 0.01, 0.2, 0.005))
    start = torch.stack([torch.full((1, 5), 0.5, dtype=torch.float64),
                         torch.full((1, 5), 0.05, dtype=torch.float64)], dim=-1)  # fmt: skip
    _, rest, speed = Winding(params, H).wind(start[..., REST].numpy(), start[..., SPEED].numpy(),
                                             None, steps=3)  # fmt: skip
    ref = start
    for _ in range(3):
        ref = winch_step(ref, params, None, H)
    np.testing.assert_array_equal(rest, ref[..., REST].numpy())
    np.testing.assert_array_equal(speed, ref[..., SPEED].numpy())
    assert speed[0, 1] == 0.0 and 0.0 < speed[0, 3] < 0.05  # no lag: stopped; lag: slowing
