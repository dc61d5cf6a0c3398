"""Dry friction along springs: its law, its declarations, its fit, and MuJoCo's frictionloss."""

from __future__ import annotations

import logging

import mujoco
import numpy as np
import pytest
import torch

from identification.data.dataset import Dataset, Split
from identification.discovery.library import LIBRARY, propose
from identification.linear.extended import ExtendedIdentifier
from identification.simulation.planted import PlantSpec, planted_dataset, planted_mjcf
from identification.trajectory.effect_coords import EffectCoords
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.defaults import EFFECT_NAMES
from tensegrity_env.effects import EFFECTS, SpringFriction
from tensegrity_env.effects.spring_friction import REGULARISATION_VELOCITY
from tensegrity_env.engine import Engine, State
from tensegrity_env.engine.forces import spring_frames
from tensegrity_env.engine.kinematics import node_kinematics
from tensegrity_env.native.engine_step import FallbackLog
from tensegrity_env.native.pack import effect_slots, effects_block

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def ico():
    return icosahedron()


def _moving(n: int = 6, seed: int = 0) -> State:
    """Icosahedra near their pose with random velocities, (n,) assemblies."""
    a = icosahedron()
    rng = np.random.default_rng(seed)
    R = a.topology.n_rods
    p = a.pose_p[None] + rng.normal(0, 0.01, (n, R, 3))
    q = np.broadcast_to(a.pose_q, (n, R, 4)).copy()
    return State.from_numpy(p, rng.normal(0, 0.5, (n, R, 3)), q, rng.normal(0, 2.0, (n, R, 3)))


def test_friction_only_removes_energy_at_the_rate_of_its_law(ico):
    """The power of the friction wrench on the rods is ``-Σ F_s tanh(l̇_s / v_ε) l̇_s``
    (<= 0): it acts along each spring, against its elongation rate."""
    S = ico.topology.n_springs
    friction = np.linspace(0.1, 2.0, S)
    effect = SpringFriction(ico.topology, friction=friction)
    state = _moving()
    eng = Engine(ico.topology, 1e-3)
    kin = node_kinematics(state, eng.end_offsets, eng.anchors)
    force, torque = effect.wrench(state, kin, ico.params)
    power = (force * state.v).sum((-1, -2)) + (torque * state.omega).sum((-1, -2))
    nodes = torch.as_tensor(ico.topology.spring_nodes)
    rate = spring_frames(kin, nodes[:, 0], nodes[:, 1]).rate
    law = -(torch.as_tensor(friction) * torch.tanh(rate / REGULARISATION_VELOCITY) * rate).sum(-1)
    torch.testing.assert_close(power, law, rtol=1e-10, atol=1e-12)
    assert bool((power < 0).all())


def test_negative_friction_is_refused_naming_the_spring(ico):
    bad = SpringFriction(ico.topology, validate=False, friction=[0.5] * 3 + [-0.4] * 21)
    assert "'friction' must be >= 0" in bad.violation() and "[3]" in bad.violation()


def test_registered_as_a_candidate_with_its_declared_gate(ico):
    assert EFFECTS["spring_friction"] is SpringFriction
    assert "spring_friction" in EFFECT_NAMES and "spring_friction" in LIBRARY
    ds = planted_dataset(PlantSpec(effect="none", n_train=1, n_val=1, n_test=1, steps=20)).dataset
    (proposal,) = propose(ds.split("train"), ico.topology, (), ["spring_friction"], {})
    assert isinstance(proposal.effect, SpringFriction)
    assert proposal.gate == SpringFriction.gate.text


def test_fit_coordinates_are_the_frictions_bounded_at_zero(ico):
    coords = EffectCoords.of([SpringFriction(ico.topology, friction=0.3)], axial=2)
    S = ico.topology.n_springs
    assert coords.n == S and coords.names()[0] == "spring_friction.friction[" + (
        ico.topology.springs[0].name + "]"
    )
    lo, hi = coords.bounds()
    assert torch.equal(lo, torch.zeros(S, dtype=lo.dtype)) and bool(torch.isinf(hi).all())
    assert bool(coords.hard_bounds().all())
    back = coords.effects_at(torch.full((S,), 0.7, dtype=torch.float64))[0]
    assert torch.allclose(back.values["friction"], torch.full((S,), 0.7, dtype=torch.float64))


def test_the_c_kernel_steps_friction_as_the_engine(ico, caplog):
    """Its C form: the per-spring slot holds F, the velocity slot v_ε; 200 steps of
    icosahedra whose cables slide both faster and slower than v_ε, by the kernel and by
    PyTorch, agree to round-off, and no step falls back."""
    S = ico.topology.n_springs
    friction = SpringFriction(ico.topology, friction=np.linspace(0.2, 3.0, S))
    _, block, _ = effects_block([friction], ico.topology)
    slots = effect_slots(S)
    at, width = slots["spring_friction"]
    np.testing.assert_array_equal(block[at : at + width], np.linspace(0.2, 3.0, S))
    assert block[slots["friction_velocity"][0]] == REGULARISATION_VELOCITY
    moving = _moving(5, seed=3)
    slow = torch.tensor([1.0, 1.0, 1.0, 0.01, 0.01], dtype=torch.float64)[:, None, None]
    start = State(moving.p, moving.v * slow, moving.q, moving.omega * slow)  # two nearly still
    out = []
    for native in (False, True):
        engine = Engine(ico.topology, 1e-2, [friction], substeps=10, native=native)
        if native:
            engine.native_step.fallbacks = FallbackLog()  # type: ignore[union-attr]
        s = start
        with caplog.at_level(logging.INFO, logger="tensegrity_env.native"), torch.no_grad():
            for _ in range(20):
                s = engine.step(s, ico.params)
        out.append(torch.cat(s.tensors(), dim=-1))
    assert not [r for r in caplog.records if r.name == "tensegrity_env.native"]
    assert float((out[0] - out[1]).abs().max()) <= 1e-10
    ref = Engine(ico.topology, 1e-3)
    kin = node_kinematics(start, ref.end_offsets, ref.anchors)
    nodes = torch.as_tensor(ico.topology.spring_nodes)
    rate = spring_frames(kin, nodes[:, 0], nodes[:, 1]).rate.abs()
    assert bool((rate < REGULARISATION_VELOCITY).any()) and bool((rate > 0.1).any())
    free = Engine(ico.topology, 1e-2, [], substeps=10, native=True)
    with torch.no_grad():
        s = start
        for _ in range(20):
            s = free.step(s, ico.params)
    assert float((torch.cat(s.tensors(), dim=-1) - out[1]).abs().max()) > 1e-3  # it acts


def test_regression_recovers_friction_planted_in_the_engine(ico):
    """Rod states rolled out by the engine with a planted friction: the one-step
    regression finds every spring's friction and the declared parameters to 1e-6."""
    S = ico.topology.n_springs
    true = np.linspace(0.2, 1.0, S)
    engine = Engine(ico.topology, 1e-3, effects=[SpringFriction(ico.topology, friction=true)])
    with torch.no_grad():
        traj = engine.rollout(_moving(4, seed=1), ico.params, 200)
    flat = State(*(t.reshape(-1, *t.shape[2:]) for t in traj.tensors()))
    kin = node_kinematics(flat, engine.end_offsets, engine.anchors)
    R = ico.topology.n_rods
    ends = kin.x[:, : 2 * R].reshape(4, 201, 2 * R, 3).numpy()
    split = Split(nodes=ends, control=np.zeros((4, 200, R, 3)), p=traj.p.numpy(),
                  v=traj.v.numpy(), q=traj.q.numpy(), omega=traj.omega.numpy())  # fmt: skip
    data = Dataset(ico.topology, 1e-3, {"train": split, "val": split, "test": split})
    anchors = {"mass[rod0]": float(ico.params.mass[0])}
    est = ExtendedIdentifier(effects=[SpringFriction(ico.topology)], anchors=anchors,
                             init_params=ico.params, fit_rest_length=False).fit(data)  # fmt: skip
    found = est.effects_[0].values["friction"].numpy()
    np.testing.assert_allclose(found, true, rtol=1e-6)
    np.testing.assert_allclose(
        est.params_.stiffness.numpy(), ico.params.stiffness.numpy(), rtol=1e-6
    )


def test_mujoco_frictionloss_is_the_same_law_where_cables_slide():
    """MuJoCo's tendon ``frictionloss`` is a soft constraint, solved with the
    accelerations: where a cable slides faster than 10 v_ε it is the full Coulomb force
    ``-F sign(l̇)``, as the engine's law, on >= 99 % of such samples (the rest reverse
    within the step); near sticking it holds whatever the other forces need, up to F,
    which no law of the velocity alone reproduces."""
    F = 0.2
    xml, record = planted_mjcf(PlantSpec(effect="spring_friction", strength=F))
    assert record["params"] == {"friction": F}
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    assert np.all(m.tendon_frictionloss == F)
    d.qvel[:] = np.random.default_rng(0).normal(0, 1.0, m.nv)
    rate, force = [], []
    for _ in range(1500):
        mujoco.mj_step(m, d)
        f = np.zeros(m.ntendon)
        rows = d.efc_type[: d.nefc] == mujoco.mjtConstraint.mjCNSTR_FRICTION_TENDON
        f[d.efc_id[: d.nefc][rows]] = d.efc_force[: d.nefc][rows]
        rate.append(d.ten_velocity.copy())
        force.append(f)
    v, f = np.array(rate), np.array(force)
    sliding = np.abs(v) > 10 * REGULARISATION_VELOCITY
    law = -F * np.tanh(v / REGULARISATION_VELOCITY)
    agree = np.abs(law - f)[sliding] < 1e-6 * F
    assert sliding.mean() > 0.3 and agree.mean() >= 0.99
