"""Winches in the C kernel: the PyTorch engine and the kernel wind the shipped lab 3-bar's
cables the same way to round-off, through the engine's no-gradient step and through the
environments' stepper (one packing, :func:`~tensegrity_env.native.pack.pack_model`)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tensegrity_env.engine import Engine, State
from tensegrity_env.engine.winch import REST, SPEED
from tensegrity_env.envs.physics import NativeStepper, pack_states, unpack_states
from tensegrity_env.envs.robot_physics import SRRobotSimulator
from tensegrity_env.native.kernel import usable_kernel
from tensegrity_env.native.pack import PACKED_PARAMS
from tensegrity_env.params import Params

pytestmark = pytest.mark.skipif(
    usable_kernel(torch.zeros(1, dtype=torch.float64)) is None, reason="no C compiler"
)

#: largest rod-state difference accepted after 1000 steps (1 s) of winding on the floor
#: [m, m/s, -, rad/s]: float64 round-off (the kernel and the engine order their sums
#: differently)
ROUND_OFF = 1e-10
#: physics steps compared (1 ms each)
STEPS = 1000


@pytest.fixture(scope="module")
def prism() -> SRRobotSimulator:
    """The shipped lab 3-bar (six winches, ground contact) at its resting pose."""
    return SRRobotSimulator()


def _ranged(prism: SRRobotSimulator, lagged: bool) -> Params:
    """The prism's parameters with each winch's range 1.2-1.7 cm either side of its rest
    length (so 0.3 s of winding at 0.1 m/s reaches an end) and its 30 ms lag, or none."""
    params, winches = prism.params, list(prism.topology.winches)
    rest = params.rest_length[winches]
    k = torch.arange(len(winches), dtype=torch.float64)
    lag = params.winch_lag if lagged else torch.zeros_like(params.winch_lag)
    return params.replace(winch_min=rest - 0.012 - 0.001 * k, winch_max=rest + 0.012 + 0.001 * k,
                          winch_lag=lag)  # fmt: skip


def _commands(W: int, seed: int) -> np.ndarray:
    """Motor commands (STEPS, W): 0.3 s at full speed, half the motors winding in and
    half out (beyond [-1, 1]: clipped), 0.4 s the other way (so each winch reaches both
    ends of its range), then random commands held 30-120 ms each."""
    rng = np.random.default_rng(seed)
    way = np.where(np.arange(W) % 2 == 0, 1.0, -1.0) * rng.uniform(1.0, 1.3, W)
    out = [np.repeat(way[None], 300, axis=0), np.repeat(-way[None], 400, axis=0)]
    t = 700
    while t < STEPS:
        hold = int(rng.integers(30, 120))
        out.append(np.repeat(rng.uniform(-1.4, 1.4, (1, W)), hold, axis=0))
        t += hold
    return np.concatenate(out)[:STEPS]


@pytest.mark.parametrize("lagged", [True, False], ids=["lag", "no-lag"])
def test_engine_and_kernel_wind_the_same_to_round_off(
    prism: SRRobotSimulator, lagged: bool
) -> None:
    params = _ranged(prism, lagged)
    W = prism.topology.n_winches
    u = torch.as_tensor(_commands(W, seed=3 if lagged else 4))
    start = unpack_states(prism.rest_pose()[None])
    out, rests = [], []
    for native in (False, True):
        engine = Engine(prism.topology, prism.dt, prism.effects, native=native)
        s = start
        with torch.no_grad():
            for t in range(STEPS):
                s = engine.step(s, params, winches=u[t][None])
                if native:
                    rests.append(s.winch[0, :, REST].numpy())
        out.append(s)
    ref, mine = out
    assert mine.winch is not None and ref.winch is not None
    assert np.abs(pack_states(mine) - pack_states(ref)).max() <= ROUND_OFF
    assert np.abs((mine.winch - ref.winch).numpy()).max() <= ROUND_OFF
    rests = np.array(rests)
    lo, hi = params.winch_min.numpy(), params.winch_max.numpy()
    # every winch reaches both ends of its range; the random commands after move them on
    assert np.all((rests == lo).any(axis=0) & (rests == hi).any(axis=0))
    assert np.ptp(rests[700:], axis=0).max() > 5e-3
    if not lagged:  # without lag the speed is the clipped command at once
        last = np.clip(u[-1].numpy(), -1, 1) * params.winch_speed.numpy()
        np.testing.assert_array_equal(mine.winch[0, :, SPEED].numpy(), last)
    # the winding moves the rods: the same steps with the motors at rest end elsewhere
    idle = Engine(prism.topology, prism.dt, prism.effects, native=True)
    s = start
    with torch.no_grad():
        for _ in range(STEPS):
            s = idle.step(s, params)
    assert np.abs(pack_states(s) - pack_states(mine))[..., :3].max() > 2e-3


def test_environment_stepper_winds_as_the_engine(prism: SRRobotSimulator) -> None:
    """:meth:`NativeStepper.wind`, 50 physics steps a call, four assemblies with their
    own commands and winch states: the engine's states to round-off."""
    params = _ranged(prism, lagged=True)
    W, B = prism.topology.n_winches, 4
    rng = np.random.default_rng(9)
    x = np.repeat(prism.rest_pose()[None], B, axis=0)
    x[:, :, 3:6] += rng.normal(0, 0.05, (B, 3, 3))
    winch = np.stack([rng.uniform(params.winch_min.numpy(), params.winch_max.numpy(), (B, W)),
                      rng.normal(0, 0.05, (B, W))], -1)  # fmt: skip
    stepper = NativeStepper(prism.topology, params, prism.effects, prism.dt, 50)
    engine = Engine(prism.topology, prism.dt, prism.effects)
    ref = State(*unpack_states(x.copy()).tensors(), winch=torch.tensor(winch))  # copies
    for _ in range(4):
        u = rng.uniform(-1.2, 1.2, (B, W))
        stepper.wind(x, winch, u)
        with torch.no_grad():
            for _ in range(50):
                ref = engine.step(ref, params, winches=torch.as_tensor(u))
    assert np.abs(x - pack_states(ref)).max() <= ROUND_OFF
    assert np.abs(winch - ref.winch.numpy()).max() <= ROUND_OFF  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="winch commands have shape"):
        stepper.wind(x, winch, np.zeros((B, W + 1)))


def test_winches_wanting_a_gradient_take_the_pytorch_step(prism: SRRobotSimulator) -> None:
    speed = prism.params.winch_speed.clone().requires_grad_(True)
    params = prism.params.replace(winch_speed=speed)
    engine = Engine(prism.topology, prism.dt, prism.effects, native=True)
    s = engine.step(unpack_states(prism.rest_pose()[None]), params,
                    winches=torch.ones(1, prism.topology.n_winches, dtype=torch.float64))  # fmt: skip
    s.winch[..., REST].sum().backward()  # type: ignore[index]
    assert speed.grad is not None and torch.all(speed.grad != 0)


def test_per_assembly_winch_parameters_run_by_run(prism: SRRobotSimulator) -> None:
    """Winch speeds, lags and stiffnesses with a batch dimension (a forward-difference
    Jacobian's layout): three runs of assemblies, each stepped with its own packed model,
    equal to PyTorch's."""
    p, B = prism.params, 6
    scale = torch.tensor([1.0, 1.0, 1.2, 1.2, 1.2, 0.9], dtype=torch.float64)[:, None]
    params = p.replace(winch_speed=p.winch_speed * scale, winch_lag=p.winch_lag * scale,
                       stiffness=p.stiffness * scale)  # fmt: skip
    start = unpack_states(np.repeat(prism.rest_pose()[None], B, axis=0))
    u = torch.as_tensor(np.random.default_rng(0).uniform(-1, 1, (B, prism.topology.n_winches)))
    out = []
    for native in (False, True):
        engine = Engine(prism.topology, 10 * prism.dt, prism.effects, substeps=10, native=native)
        s = start
        with torch.no_grad():
            for _ in range(30):
                s = engine.step(s, params, winches=u)
        out.append(s)
    assert engine.native_step is not None
    assert list(engine.native_step.cache.get([getattr(params, k) for k in PACKED_PARAMS], B)
                .start) == [0, 2, 5, 6]  # fmt: skip
    assert np.abs(pack_states(out[0]) - pack_states(out[1])).max() <= ROUND_OFF
    assert np.abs((out[0].winch - out[1].winch).numpy()).max() <= ROUND_OFF  # type: ignore[operator]
    assert np.abs((out[1].winch[0] - out[1].winch[2]).numpy()).max() > 1e-4  # type: ignore[index]
