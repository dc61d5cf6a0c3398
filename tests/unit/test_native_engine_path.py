"""The engine's no-gradient steps by the C kernel (``Engine(native=True)``): the same
physics as the PyTorch engine to round-off, with every effect the kernel has, with
per-assembly parameters, and the PyTorch step wherever the kernel does not apply."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

from tensegrity_env import effects as fx
from tensegrity_env.effects.springs import CompressionStiffness
from tensegrity_env.engine import Engine, State
from tensegrity_env.envs.physics import NativeStepper, pack_states
from tensegrity_env.envs.twin import face_down_pose, twin_assembly
from tensegrity_env.native.engine_step import FallbackLog
from tensegrity_env.native.kernel import usable_kernel
from tensegrity_env.native.pack import PACKED_PARAMS, NotNative
from tensegrity_env.params import Params

pytestmark = pytest.mark.skipif(
    usable_kernel(torch.zeros(1, dtype=torch.float64)) is None, reason="no C compiler"
)

#: largest state difference accepted after the steps below (float64 round-off, grown
#: through impacts and 20 ms of motion)
ROUND_OFF = 1e-9


def _tumbling(n: int, seed: int) -> State:
    """Face-down icosahedra 2 mm into the floor, moving and spinning at random."""
    a = twin_assembly()
    rng = np.random.default_rng(seed)
    p, q = face_down_pose(a.topology, a.pose_p, a.pose_q, clearance=-2e-3)
    return State.from_numpy(
        p + rng.normal(0, 3e-3, (n, 6, 3)), rng.normal(0, 0.5, (n, 6, 3)),
        np.broadcast_to(q, (n, 6, 4)).copy(), rng.normal(0, 2.0, (n, 6, 3)),
    )  # fmt: skip


def _effects(topology):  # type: ignore[no-untyped-def]
    """Every effect the kernel has, at values that move the rods visibly in 20 ms."""
    rng = np.random.default_rng(7)
    S = topology.n_springs
    return [
        fx.LinearDrag(topology, translational=[2.0, 1.5, 0.4], rotational=[0.05, 0.03, 0.01]),
        fx.QuadraticDrag(topology, translational=[3.0, 2.0, 0.5], rotational=[0.02, 0.02, 0.004]),
        fx.ForceField(topology, force=[0.4, -0.3, 0.6]),
        fx.CubicStiffness(topology, stiffness=rng.normal(0, 2000, S)),
        fx.RestLengthOffset(topology, offset=rng.normal(0, 0.004, S)),
        fx.SlackSprings(topology, springs=[0, 3, 5, 7, 11]),
        fx.SpringFriction(topology, friction=rng.uniform(0.5, 3.0, S)),
        fx.GroundContact(topology, friction=0.8, stiffness=2500.0, impedance=0.93),
    ]


def _both(engine_kw, state, params, control, steps=20):  # type: ignore[no-untyped-def]
    """The states after ``steps`` steps by the PyTorch engine and by the kernel's path."""
    out = []
    for native in (False, True):
        engine = Engine(**engine_kw, native=native)
        s = state
        with torch.no_grad():
            for _ in range(steps):
                s = engine.step(s, params, control)
        out.append(pack_states(s))
    return out


def _spread(params: Params, scales: list[float], runs: list[int]) -> Params:
    """``params`` with a batch dimension: run k of ``runs[k]`` assemblies scales every
    mass, inertia, stiffness, damping and the control gain by ``scales[k]`` and moves
    the rest lengths by ``scales[k] - 1`` mm (the layout of a forward-difference batch)."""
    sc = torch.cat([torch.full((n, 1), s, dtype=torch.float64)
                    for s, n in zip(scales, runs, strict=True)])  # fmt: skip
    B = int(sc.shape[0])
    return Params(
        stiffness=params.stiffness * sc, damping=params.damping * sc,
        rest_length=params.rest_length + (sc - 1) * 1e-3, mass=params.mass * sc,
        inertia=params.inertia * sc[:, :, None],
        control_gain=params.control_gain * sc[:, :, None], gravity=params.gravity,
        cable_gain=params.cable_gain.expand(B, -1),
    )  # fmt: skip


def test_every_native_effect_with_control_matches_the_engine() -> None:
    """Rest lengths 15 % long, so that some of the slack springs go slack."""
    a = twin_assembly()
    state = _tumbling(11, 0)
    u = torch.as_tensor(np.random.default_rng(1).normal(0, 2, (11, 6, 3)))
    fields = ("stiffness", "damping", "mass", "inertia", "control_gain", "gravity", "cable_gain")
    params = Params(**{f: getattr(a.params, f) for f in fields},
                    rest_length=a.params.rest_length * 1.15)  # fmt: skip
    effects = _effects(a.topology)
    kw = {"topology": a.topology, "dt": 1 / 120, "effects": effects, "substeps": 9}
    ref, mine = _both(kw, state, params, u)
    assert np.abs(mine - ref).max() < ROUND_OFF
    for k in range(len(effects) - 1):  # each effect moves the states: none is left out
        without = {**kw, "effects": effects[:k] + effects[k + 1 :]}
        assert np.abs(_both(without, state, params, u)[1] - ref).max() > 1e-3


def test_implicit_linear_drag_matches_the_engine() -> None:
    """Linear drag integrated implicitly (as ``diagnose`` proposes it), strong enough
    that an explicit step would differ, beside the contact."""
    a = twin_assembly()
    state = _tumbling(9, 4)
    drag = fx.ImplicitLinearDrag(a.topology, translational=[8.0, 6.0, 2.0],
                              rotational=[0.2, 0.1, 0.05])  # fmt: skip
    contact = fx.GroundContact(a.topology, friction=0.8, stiffness=2500.0, impedance=0.93)
    kw = {"topology": a.topology, "dt": 1 / 120, "effects": [drag, contact], "substeps": 9}
    ref, mine = _both(kw, state, a.params, None)
    assert np.abs(mine - ref).max() < ROUND_OFF
    explicit = fx.LinearDrag(a.topology, translational=[8.0, 6.0, 2.0], rotational=[0.2, 0.1, 0.05])
    other = _both({**kw, "effects": [explicit, contact]}, state, a.params, None)[1]
    assert np.abs(other - ref).max() > 1e-6  # the implicit step is not the explicit one


def test_parameters_per_assembly_run_by_run() -> None:
    """Three runs of equal parameters (as a forward-difference batch lays them out), the
    middle run's 5 % heavier, stiffer and more damped model giving other states."""
    a = twin_assembly()
    runs = [5, 9, 3]
    state = _tumbling(sum(runs), 2)
    params = _spread(a.params, [1.0, 1.05, 0.97], runs)
    kw = {"topology": a.topology, "dt": 1 / 120, "effects": _effects(a.topology), "substeps": 9}
    ref, mine = _both(kw, state, params, None)
    assert np.abs(mine - ref).max() < ROUND_OFF
    same = _both(kw, state, a.params, None)[0]
    assert np.abs(same[5:14] - ref[5:14]).max() > 1e-4  # the runs stepped their own models


def test_gradients_and_effects_without_native_form_take_the_pytorch_step() -> None:
    a = twin_assembly()
    state = _tumbling(2, 3)
    engine = Engine(a.topology, 1 / 120, [fx.GroundContact(a.topology)], substeps=9, native=True)
    stiff = a.params.stiffness.clone().requires_grad_(True)
    params = Params(**{**{f: getattr(a.params, f) for f in ("damping", "rest_length", "mass",
                    "inertia", "control_gain", "gravity", "cable_gain")}, "stiffness": stiff})  # fmt: skip
    assert engine.native_step(state.tensors(), params, None, None) is None
    out = engine.step(state, params)
    assert out.p.requires_grad  # the gradient flows through the PyTorch step
    other = engine.with_effects([CompressionStiffness(a.topology)])
    with torch.no_grad():
        assert other.native_step(state.tensors(), a.params, None, None) is None
        assert engine.native_step(state.tensors(), a.params, None, None) is not None


def test_a_fallback_logs_its_reason_once(caplog: pytest.LogCaptureFixture) -> None:
    """An effect the kernel lacks: three steps in PyTorch, one warning naming it; a
    gradient wanted: said once, at INFO."""
    a = twin_assembly()
    state = _tumbling(2, 3)
    engine = Engine(a.topology, 1 / 120, [CompressionStiffness(a.topology)], native=True)
    engine.native_step.fallbacks = FallbackLog()  # type: ignore[union-attr]
    with caplog.at_level(logging.INFO, logger="tensegrity_env.native"):
        with torch.no_grad():
            for _ in range(3):
                engine.step(state, a.params)
        said = [r for r in caplog.records if r.name == "tensegrity_env.native"]
        assert len(said) == 1 and said[0].levelno == logging.WARNING
        assert "compression_stiffness" in said[0].getMessage()
        grad = engine.with_effects([fx.GroundContact(a.topology)])
        grad.native_step.fallbacks = FallbackLog()  # type: ignore[union-attr]
        stiff = a.params.stiffness.clone().requires_grad_(True)
        for _ in range(2):
            grad.step(state, a.params.replace(stiffness=stiff))
        said = [r for r in caplog.records if r.name == "tensegrity_env.native"][1:]
        assert len(said) == 1 and said[0].levelno == logging.INFO
        assert "gradient" in said[0].getMessage()


def test_environments_step_every_native_effect_by_the_same_packing() -> None:
    """The environments' stepper takes the effects the engine's path takes (one
    packing): 50 physics steps equal the engine's to round-off; an effect the kernel
    lacks is refused by name."""
    a = twin_assembly()
    state = _tumbling(11, 5)
    effects = _effects(a.topology)
    u = np.random.default_rng(2).normal(0, 2, (11, 6, 3))
    engine = Engine(a.topology, 1e-3, effects)
    ref = state
    with torch.no_grad():
        for _ in range(50):
            ref = engine.step(ref, a.params, torch.as_tensor(u))
    x = pack_states(state)
    NativeStepper(a.topology, a.params, effects, 1e-3, 50)(x, u)
    assert np.abs(x - pack_states(ref)).max() < ROUND_OFF
    with pytest.raises(NotNative, match="compression_stiffness"):
        NativeStepper(a.topology, a.params, [CompressionStiffness(a.topology)], 1e-3, 50)


def test_the_packed_model_follows_the_parameters() -> None:
    """The cache packs once for the same parameter tensors and again when one changes in
    place or is another tensor: every step equals the PyTorch engine's."""
    a = twin_assembly()
    state = _tumbling(3, 6)
    kw = {"topology": a.topology, "dt": 1 / 120, "effects": [fx.GroundContact(a.topology)],
          "substeps": 9}  # fmt: skip
    torch_engine, engine = Engine(**kw), Engine(**kw, native=True)
    params = a.params.replace(stiffness=a.params.stiffness.clone())
    packed = []
    with torch.no_grad():
        for change in (None, None, "in place", "new tensor"):
            if change == "in place":
                params.stiffness.mul_(1.2)
            elif change == "new tensor":
                params = params.replace(stiffness=params.stiffness * 0.7)
            ref = pack_states(torch_engine.step(state, params))
            mine = pack_states(engine.step(state, params))
            assert np.abs(mine - ref).max() < ROUND_OFF
            packed.append(engine.native_step.cache.get(  # type: ignore[union-attr]
                [getattr(params, k) for k in PACKED_PARAMS], 3))
    assert packed[0] is packed[1]  # the same tensors: packed once
    assert packed[1] is not packed[2] and packed[2] is not packed[3]
