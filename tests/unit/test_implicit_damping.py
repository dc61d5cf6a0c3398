"""Implicit linear damping: MuJoCo's free-joint damping under its Euler integrator."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from tensegrity_env.assemblies import element
from tensegrity_env.effects import (
    ImplicitLinearDrag,
    LinearDrag,
    effect_from_dict,
)
from tensegrity_env.engine import Engine, State
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import SimOptions, from_mjcf, to_mjcf
from tensegrity_env.mjcf_checks import IgnoredFeatureWarning
from tensegrity_env.mujoco_state import mj_to_rod_state
from tensegrity_env.rotations import quat_to_matrix

#: free-joint damping [N*s/m and N*m*s]: with a 1.5 kg, 16 mm rod (axial inertia
#: 1.92e-4 kg*m^2) and a 1 ms step, β h / I ≈ 2.08 about the rod's own axis, where an
#: explicit step multiplies the axial spin by 1 - β h / I ≈ -1.08
DAMPING = 0.4


def _damped_case(seed: int = 3):
    asm = element(mass=1.5)
    xml = to_mjcf(asm.topology, asm.params, SimOptions(), asm.pose_p, asm.pose_q)
    xml = xml.replace(
        '<freejoint name="rod0"', f'<joint type="free" damping="{DAMPING}" name="rod0"'
    )
    assert f'damping="{DAMPING}"' in xml
    mj = from_mjcf("<test>", xml=xml)  # read as declared implicit linear drag
    m, d = mj.model, mujoco.MjData(mj.model)
    rng = np.random.default_rng(seed)
    d.qvel[:] = rng.normal(size=m.nv) * 3.0
    return asm, mj, m, d


def _state(mj, d) -> State:
    s = mj_to_rod_state(mj, d.qpos.copy(), d.qvel.copy())
    return State.from_numpy(*(s[k][None] for k in ("p", "v", "q", "omega")))


def _drag(cls: type[LinearDrag], asm) -> LinearDrag:
    return cls(asm.topology, translational=[DAMPING] * 3, rotational=[DAMPING] * 3)


def test_implicit_form_equals_mujoco_joint_damping_over_1000_steps() -> None:
    """The file's free-joint damping, read as the declared effect, steps like MuJoCo."""
    asm, mj, m, d = _damped_case()
    assert DAMPING * m.opt.timestep / asm.params.inertia[0, 2].item() > 2.0
    (declared,) = mj.declared_effects()
    assert isinstance(declared, ImplicitLinearDrag) and mj.joint_damping == DAMPING
    assert declared.to_dict() == _drag(ImplicitLinearDrag, asm).to_dict()
    engine = Engine(asm.topology, dt=m.opt.timestep, effects=[declared])
    state = _state(mj, d)
    err_p, err_w = [], []
    for _ in range(1000):
        mujoco.mj_step(m, d)
        state = engine.step(state, asm.params)
        ref = _state(mj, d)
        err_p.append(float((state.p - ref.p).abs().max()))
        err_w.append(float((state.omega - ref.omega).abs().max()))
    assert max(err_p) <= 1e-10
    assert max(err_w) <= 1e-9
    # the damping acted: the spin about the rod's own axis died out
    assert float(ref.omega.abs().max()) < 1.0


def test_explicit_form_blows_up_where_the_implicit_one_is_stable() -> None:
    asm, mj, m, d = _damped_case()
    engine = Engine(asm.topology, dt=m.opt.timestep, effects=[_drag(LinearDrag, asm)])
    state = _state(mj, d)
    with torch.no_grad():
        for _ in range(1000):
            state = engine.step(state, asm.params)
    assert not bool(torch.isfinite(state.omega).all()) or float(state.omega.abs().max()) > 1e6


def test_both_forms_agree_for_weak_damping() -> None:
    asm, mj, _, d = _damped_case()
    weak = {"translational": [0.01, 0.01, 0.002], "rotational": [1e-4, 1e-4, 1e-7]}
    state0 = _state(mj, d)
    out = []
    for cls in (LinearDrag, ImplicitLinearDrag):
        engine = Engine(asm.topology, dt=1e-3, effects=[cls(asm.topology, **weak)])
        state = state0
        for _ in range(200):
            state = engine.step(state, asm.params)
        out.append(state.p)
    # per step they differ by a relative h b / M (6e-6 here)
    assert float((out[0] - out[1]).abs().max()) < 1e-5
    assert float((out[0] - state0.p).abs().max()) > 0.1


def test_form_round_trips_through_the_params_entry() -> None:
    asm = element()
    doc = _drag(ImplicitLinearDrag, asm).to_dict()
    assert doc["form"] == "implicit"
    back = effect_from_dict(doc, asm.topology)
    assert isinstance(back, ImplicitLinearDrag)
    assert "form" not in _drag(LinearDrag, asm).to_dict()
    assert type(effect_from_dict(_drag(LinearDrag, asm).to_dict(), asm.topology)) is LinearDrag


def test_unknown_form_is_a_one_line_error() -> None:
    doc = {**_drag(LinearDrag, element()).to_dict(), "form": "semi"}
    with pytest.raises(InputError, match="form must be one of explicit, implicit"):
        effect_from_dict(doc, element().topology)


def test_regression_columns_at_the_velocities_after_the_step() -> None:
    """``M a = f - b v'`` and ``I α_l = τ_l - β ω_l'``: linear in (b, β) at the next state."""
    asm, mj, _, d = _damped_case()
    drag = _drag(ImplicitLinearDrag, asm)
    s0 = _state(mj, d)
    s1 = Engine(asm.topology, dt=1e-3, effects=[drag]).step(s0, asm.params)
    plain = Engine(asm.topology, dt=1e-3)
    a0, alpha0, _ = plain.accelerations(s0, asm.params)
    kin = plain.kinematics(s0)
    f, tq = drag.transition_basis(s0, s1, kin, asm.params)
    theta = drag.theta().double()
    mass, inertia = asm.params.mass.double(), asm.params.inertia.double()
    lhs = mass[:, None] * (s1.v - s0.v) / 1e-3
    assert torch.allclose(lhs, mass[:, None] * a0 + f @ theta, atol=1e-9)
    rot1 = quat_to_matrix(s1.q)
    w0 = torch.einsum("brji,brj->bri", kin.rot, s0.omega)
    w1 = torch.einsum("brji,brj->bri", rot1, s1.omega)
    torque_l = torch.einsum("brji,brj->bri", kin.rot, tq @ theta)
    assert torch.allclose(inertia * (w1 - w0) / 1e-3, inertia * alpha0 + torque_l, atol=1e-9)


def test_joint_damping_the_model_cannot_hold_is_refused_by_name() -> None:
    """Different values on two rods (the drag is one per axis for all rods), or a body
    frame off the centre of mass (the damping force would act off it)."""
    from tensegrity_env.assemblies import icosahedron

    asm = icosahedron()
    xml = to_mjcf(asm.topology, asm.params, SimOptions(), asm.pose_p, asm.pose_q)
    uneven = xml.replace('<freejoint name="rod0"', '<joint type="free" damping="0.4" name="rod0"')
    with pytest.raises(
        InputError, match=r"rod0.*not one value on every rod.*--ignore joint-dynamics"
    ):
        from_mjcf("<test>", xml=uneven)
    with pytest.warns(IgnoredFeatureWarning):
        ignored = from_mjcf("<test>", xml=uneven, ignore=("joint-dynamics",))
    assert ignored.joint_damping == 0.0 and not ignored.declared_effects()
    even = xml.replace("<freejoint ", '<joint type="free" damping="0.4" ')
    assert from_mjcf("<test>", xml=even).joint_damping == 0.4
