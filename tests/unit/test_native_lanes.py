"""The C kernel's two builds, 8 assemblies per SIMD block and 4 (the one a single
environment steps through): the same rod and winch states bit for bit, with winches
and with control forces, each assembly whatever batch it is stepped in."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tensegrity_env.envs.physics import NativeStepper
from tensegrity_env.envs.robot_physics import SRRobotSimulator
from tensegrity_env.envs.sr_env import IcosahedronSREnv
from tensegrity_env.native.kernel import LANES, NARROW_LANES, load_kernel, usable_kernel

pytestmark = pytest.mark.skipif(
    usable_kernel(torch.zeros(1, dtype=torch.float64)) is None, reason="no C compiler"
)

#: control steps compared (50 physics steps of 1 ms each)
STEPS = 40


def _step(lanes: int, stepper: NativeStepper, x: np.ndarray, u: np.ndarray | None,
          winch: np.ndarray | None, commands: np.ndarray | None) -> None:  # fmt: skip
    """One call of the build with ``lanes`` lanes on these arrays, in place."""
    lib = load_kernel(lanes)[0]
    assert lib.tsr_lanes() == lanes
    t = stepper.topology
    springs = np.ascontiguousarray(t.spring_nodes, dtype=np.int32)
    code = lib.tsr_step(
        x.shape[0], t.n_rods, t.n_springs, t.n_anchors, stepper.frame_skip, stepper.dt,
        stepper.iterations, x.ctypes.data, None if u is None else u.ctypes.data,
        stepper._model_ptr, springs.ctypes.data, 1,
        None if winch is None else winch.ctypes.data,
        None if commands is None else commands.ctypes.data,
    )  # fmt: skip
    assert code == 0


def test_narrow_and_wide_builds_wind_the_same_bits() -> None:
    """Three lab 3-bars pushed apart, random motor commands (some beyond [-1, 1]) for 2 s:
    the narrow build's states are the wide build's, and each robot stepped alone is the
    same robot stepped in the batch."""
    sim = SRRobotSimulator()
    stepper = sim.stepper
    assert isinstance(stepper, NativeStepper)
    B, W = 3, sim.topology.n_winches
    rng = np.random.default_rng(7)
    x = np.repeat(sim.rest_pose()[None], B, axis=0)
    x[..., 3:6] += rng.normal(0, 0.1, (B, sim.topology.n_rods, 3))
    winch = np.repeat(sim.rest_winch[None], B, axis=0)
    runs = {lanes: (x.copy(), winch.copy()) for lanes in (LANES, NARROW_LANES)}
    alone = [(x[i : i + 1].copy(), winch[i : i + 1].copy()) for i in range(B)]
    start = x.copy()
    for _ in range(STEPS):
        c = rng.uniform(-1.3, 1.3, (B, W))
        for lanes, (xs, ws) in runs.items():
            _step(lanes, stepper, xs, None, ws, c)
        for i, (xs, ws) in enumerate(alone):
            _step(NARROW_LANES, stepper, xs, None, ws, np.ascontiguousarray(c[i : i + 1]))
    (x8, w8), (x4, w4) = runs[LANES], runs[NARROW_LANES]
    np.testing.assert_array_equal(x4, x8)
    np.testing.assert_array_equal(w4, w8)
    np.testing.assert_array_equal(np.concatenate([a for a, _ in alone]), x8)
    assert np.abs(x8 - start)[..., :3].max() > 1e-2  # the robots crawled
    assert np.ptp(w8[..., 0]) > 1e-2  # and wound their cables apart


def test_narrow_and_wide_builds_roll_the_same_bits() -> None:
    """The icosahedron under random control forces (no winches): the same bits."""
    env = IcosahedronSREnv()
    stepper = getattr(env.sim, "stepper", None)
    assert isinstance(stepper, NativeStepper)
    rng = np.random.default_rng(8)
    B, R = 2, stepper.topology.n_rods
    x = np.repeat(env.rest[None], B, axis=0)
    x[..., 3:6] += rng.normal(0, 0.1, (B, R, 3))
    runs = {lanes: x.copy() for lanes in (LANES, NARROW_LANES)}
    for _ in range(STEPS):
        u = rng.uniform(-2, 2, (B, R, 3))
        for lanes, xs in runs.items():
            _step(lanes, stepper, xs, u, None, None)
    np.testing.assert_array_equal(runs[NARROW_LANES], runs[LANES])
    assert np.abs(runs[LANES] - x)[..., :3].max() > 1e-2
