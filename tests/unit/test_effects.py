"""The effect library: physics against MuJoCo, gates, serialisation into the engine."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from identification.experiments.drop_check import DROP_TOLERANCE, drop_check
from identification.linear.features import transitions_of
from identification.simulation.planted import PlantSpec, planted_dataset
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
from identification.trajectory.windows import sample_windows
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import (
    EFFECTS,
    ControlLag,
    CubicStiffness,
    ForceField,
    GroundContact,
    LinearDrag,
    QuadraticDrag,
    RestLengthOffset,
    SlackSprings,
    SpringFriction,
    effect_from_dict,
    effects_from_document,
)
from tensegrity_env.effects.base import spring_lengths, spring_tension_wrench, spring_unit_wrench
from tensegrity_env.effects.springs import CompressionStiffness
from tensegrity_env.engine import Engine, State
from tensegrity_env.engine.kinematics import node_kinematics
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def ico():
    return icosahedron()


def _examples(topology):
    S = topology.n_springs
    return [
        GroundContact(topology, friction=0.7, stiffness=2000.0),
        LinearDrag(topology, translational=[0.5, 0.5, 0.1], rotational=[0.01, 0.01, 0.0]),
        QuadraticDrag(topology, translational=[1.4, 1.4, 0.04], rotational=[0.05, 0.05, 0.0]),
        SlackSprings(topology, springs=[0, 3, 5]),
        ForceField(topology, force=[0.1, -0.2, 0.3]),
        CubicStiffness(topology, stiffness=np.linspace(0, 50, S)),
        RestLengthOffset(topology, offset=np.linspace(-0.01, 0.01, S)),
        ControlLag(topology, time_constant=0.02),
        SpringFriction(topology, friction=np.linspace(0.1, 1.0, S)),
    ]


def _random_state(topology, n=5, seed=0, lift=0.3):
    a = icosahedron()
    rng = np.random.default_rng(seed)
    R = topology.n_rods
    p = a.pose_p[None] + rng.normal(0, 0.02, (n, R, 3))
    p[..., 2] += lift
    q = np.broadcast_to(a.pose_q, (n, R, 4)).copy()
    return State.from_numpy(p, rng.normal(0, 0.5, (n, R, 3)), q, rng.normal(0, 1.0, (n, R, 3)))


def test_registry_has_every_effect(ico):
    assert {e.name for e in _examples(ico.topology)} == set(EFFECTS)


def test_to_dict_round_trip(ico):
    for effect in _examples(ico.topology):
        d = effect.to_dict()
        assert set(d) == {"name", "params", "units", "uncertainty"}
        back = effect_from_dict(d, ico.topology)
        for k, v in effect.values.items():
            assert torch.equal(back.values[k], v), (effect.name, k)


def test_params_file_round_trips_into_the_engine(ico, tmp_path):
    effects = [e for e in _examples(ico.topology) if not isinstance(e, ControlLag)]
    path = Model(ico.topology, ico.params, effects).save(tmp_path / "p.json")
    model = Model.load(path)
    topology, params, loaded = model.topology, model.params, list(model.effects)
    assert [e.name for e in loaded] == [e.name for e in effects]
    state = _random_state(ico.topology, lift=-0.55)  # some end caps below the floor
    a = Engine(ico.topology, 1e-3, effects=effects).step(state, ico.params)
    b = Engine(topology, 1e-3, effects=loaded).step(state, params)
    for x, y in zip(a.tensors(), b.tensors(), strict=True):
        torch.testing.assert_close(x, y, rtol=1e-12, atol=1e-12)
    assert not torch.allclose(a.v, Engine(ico.topology, 1e-3).step(state, ico.params).v)


def test_params_file_is_standard_json_with_unseen_errors_read_back_as_infinite(ico, tmp_path):
    """An effect coordinate the data does not see has an infinite standard error: the
    file holds null there (standard JSON, which refuses NaN and Infinity), and loading
    it gives inf back."""
    drag = LinearDrag(
        ico.topology, translational=[0.5, 0.5, 0.1], rotational=[0.01, 0.01, 0.0],
        uncertainty={"translational": [0.01, 0.02, float("inf")], "rotational": float("nan")},
    )  # fmt: skip
    extra = {"diagnose": {"test_errors_before": {"rollout": float("inf")}}}
    path = Model(ico.topology, ico.params, [drag]).save(tmp_path / "p.json", extra)

    def refuse(constant: str) -> None:
        raise ValueError(f"non-standard JSON constant {constant}")

    doc = json.loads(path.read_text(), parse_constant=refuse)
    assert doc["effects"][0]["uncertainty"]["translational"] == [0.01, 0.02, None]
    assert doc["diagnose"]["test_errors_before"]["rollout"] is None
    loaded = Model.load(path).effects[0]
    assert loaded.uncertainty["translational"] == [0.01, 0.02, float("inf")]
    assert loaded.uncertainty["rotational"] == float("inf")


def test_unknown_effect_is_a_clear_error(ico):
    with pytest.raises(InputError, match="unknown effect"):
        effects_from_document({"effects": [{"name": "magic"}]}, ico.topology)
    with pytest.raises(InputError, match="unknown parameter"):
        GroundContact(ico.topology, stifness=1.0)


def test_linear_effects_wrench_is_basis_times_theta(ico):
    state = _random_state(ico.topology)
    eng = Engine(ico.topology, 1e-3)
    kin = node_kinematics(state, eng.end_offsets, eng.anchors)
    for effect in _examples(ico.topology):
        if not hasattr(effect, "basis"):
            continue
        f, t = effect.basis(state, kin, ico.params)
        wf, wt = effect.wrench(state, kin, ico.params)
        torch.testing.assert_close(wf, f @ effect.theta())
        torch.testing.assert_close(wt, t @ effect.theta())
        twice = effect.with_theta(2 * effect.theta())
        torch.testing.assert_close(twice.wrench(state, kin, ico.params)[1], 2 * wt)


def test_spring_tensions_act_through_the_nodes_as_the_unit_wrench(ico):
    """Per-spring tensions summed through the nodes = the dense unit wrench contracted."""
    topology, params = ico.topology, ico.params
    state = _random_state(topology, seed=5)
    eng = Engine(topology, 1e-3)
    kin = node_kinematics(state, eng.end_offsets, eng.anchors)
    tension = torch.as_tensor(np.random.default_rng(1).normal(0, 10, (5, topology.n_springs)))
    force, torque, _ = spring_unit_wrench(kin, topology)
    f, t = spring_tension_wrench(kin, topology, tension)
    torch.testing.assert_close(f, torch.einsum("brks,bs->brk", force, tension))
    torch.testing.assert_close(t, torch.einsum("brks,bs->brk", torque, tension))
    # each spring pulls its two rods together: no net force on the structure
    torch.testing.assert_close(f.sum(1), torch.zeros(5, 3, dtype=f.dtype))
    # compression stiffness (the slack probe) through the same path as its design
    probe = CompressionStiffness(topology, stiffness=np.linspace(-300, 50, topology.n_springs))
    bf, bt = probe.basis(state, kin, params)
    wf, wt = probe.wrench(state, kin, params)
    torch.testing.assert_close(wf, bf @ probe.theta())
    torch.testing.assert_close(wt, bt @ probe.theta())
    # a slack cable shorter than rest loses exactly -K (l - l0) of its tension
    cables = SlackSprings(topology, springs=list(range(topology.n_springs)))
    length = spring_lengths(kin, topology)[0]
    stretch = length - params.rest_length
    lost = -params.stiffness * stretch * (stretch < 0)
    assert bool((lost != 0).any()) and bool((lost == 0).any())
    sf, st = cables.wrench(state, kin, params)
    torch.testing.assert_close(sf, torch.einsum("brks,bs->brk", force, lost))
    torch.testing.assert_close(st, torch.einsum("brks,bs->brk", torque, lost))


def test_drag_opposes_motion(ico):
    state = _random_state(ico.topology, seed=3)
    eng = Engine(ico.topology, 1e-3)
    kin = node_kinematics(state, eng.end_offsets, eng.anchors)
    for cls in (LinearDrag, QuadraticDrag):
        f, t = cls(ico.topology, translational=[1, 2, 0.1], rotational=[0.1, 0.2, 0.01]).wrench(
            state, kin, ico.params
        )
        assert (f * state.v).sum() < 0 and (t * state.omega).sum() < 0


def test_box_drag_depends_on_the_roll_end_caps_cannot_see(ico):
    """MuJoCo's inertia-box fluid model (the quadratic-drag plant, mirrored by
    QuadraticDrag) acts per axis of each rod's box: rolling a rod about its own axis
    leaves its end caps where they are but changes |v_x| v_x + |v_y| v_y. Linear drag
    with equal cross-axis coefficients does not see the roll. Why noisy end caps pin
    quadratic drag far less well than linear drag (README, noisy end caps)."""
    from identification.data.end_caps import RodAxes
    from tensegrity_env.rotations import quat_mul, quat_to_matrix

    topo, params = ico.topology, ico.params
    state = _random_state(topo, n=8, seed=4)
    axis = RodAxes.of(topo).axis
    R = topo.n_rods
    rot = quat_to_matrix(state.q)
    along = torch.stack([rot[:, r, :, axis[r]] for r in range(R)], dim=1)  # (B, R, 3) world
    omega = state.omega - (state.omega * along).sum(-1, keepdim=True) * along  # no spin
    angle = torch.as_tensor(np.random.default_rng(1).uniform(0, 2 * np.pi, (8, R)))
    half = torch.zeros(8, R, 4, dtype=torch.float64)
    half[..., 0] = torch.cos(angle / 2)
    for r in range(R):
        half[:, r, 1 + axis[r]] = torch.sin(angle / 2)[:, r]
    plain = State(state.p, state.v, state.q, omega)
    rolled = State(state.p, state.v, quat_mul(state.q, half), omega)
    eng = Engine(topo, 0.01)
    seen = [node_kinematics(s, eng.end_offsets, eng.anchors) for s in (plain, rolled)]
    assert torch.allclose(seen[0].x, seen[1].x, atol=1e-12)  # end caps: positions and
    assert torch.allclose(seen[0].xd, seen[1].xd, atol=1e-12)  # velocities the same
    drags = {
        "quadratic": QuadraticDrag(topo, translational=[1.44, 1.44, 0.04],
                                   rotational=[0.05, 0.05, 0.0]),
        "linear": LinearDrag(topo, translational=[1.0, 1.0, 0.1], rotational=[0.1, 0.1, 0.0]),
    }  # fmt: skip
    gap = {}
    for name, drag in drags.items():
        e = Engine(topo, 0.01, effects=[drag])
        a, b = e.rollout(plain, params, 100), e.rollout(rolled, params, 100)
        gap[name] = float((a.p[:, -1] - b.p[:, -1]).norm(dim=-1).mean())  # after 1 s [m]
    assert gap["quadratic"] > 1e-2, gap  # 164 mm measured
    assert gap["linear"] < 1e-9, gap


def test_contact_gate_no_force_above_the_floor(ico):
    state = _random_state(ico.topology, lift=1.0)  # every cap well above z = 0
    eng = Engine(ico.topology, 1e-3)
    kin = node_kinematics(state, eng.end_offsets, eng.anchors)
    f, t = GroundContact(ico.topology).wrench(state, kin, ico.params)
    assert torch.count_nonzero(f) == 0 and torch.count_nonzero(t) == 0


def test_declared_gates_a_regression_reads(ico):
    """A floor's clearance is each end cap's height above it less its radius; slack cables
    lose their elastic tension only while shorter than rest; other effects declare neither."""
    state = _random_state(ico.topology, lift=0.05)
    eng = Engine(ico.topology, 1e-3)
    kin = node_kinematics(state, eng.end_offsets, eng.anchors)
    floor = GroundContact(ico.topology, height=0.02)
    R = ico.topology.n_rods
    caps = kin.x[:, : 2 * R].reshape(-1, R, 2, 3)[..., 2]
    radius = torch.tensor([r.radius for r in ico.topology.rods], dtype=caps.dtype)
    assert torch.allclose(floor.clearance(state, kin), caps - radius[None, :, None] - 0.02)
    assert floor.floor_height() == pytest.approx(0.02)
    length, _ = spring_lengths(kin, ico.topology)
    rest = length[0].clone()
    rest[[0, 3]] += 0.01  # springs 0 and 3 shorter than rest, spring 1 longer
    rest[1] -= 0.01
    slack = SlackSprings(ico.topology, springs=[0, 1]).elastic(length[:1], rest)
    assert slack[0, :4].tolist() == [False, True, True, True] and bool(slack[0, 4:].all())
    for e in _examples(ico.topology)[1:]:
        assert e.floor_height() is None and e.clearance(state, kin) is None
        assert e.name == "slack_springs" or e.elastic(length, rest) is None


@pytest.mark.parametrize(("friction", "seed"), [(1.0, 0), (0.3, 4), (2.0, 7)])
def test_ground_contact_reproduces_mujoco_one_step(friction, seed):
    data = planted_dataset(PlantSpec("ground_contact", friction, n_train=2, n_val=0, n_test=0,
                                     steps=400, seed=seed))  # fmt: skip
    ds, truth = data.dataset, data.ground_truth
    s0, s1, u = transitions_of(ds.split("train"))
    contact = GroundContact(ds.topology, friction=friction)
    with torch.no_grad():
        bare = Engine(ds.topology, ds.dt).step(s0, truth.params, u)
        full = Engine(ds.topology, ds.dt, effects=[contact]).step(s0, truth.params, u)
    before = (bare.p - s1.p).norm(dim=-1).mean()
    after = (full.p - s1.p).norm(dim=-1)
    assert before > 1e-6
    assert after.mean() < 1e-13 and after.max() < 1e-9


def test_slack_springs_reproduce_mujoco_dead_band():
    data = planted_dataset(PlantSpec("slack_springs", 8, n_train=2, n_val=0, n_test=0,
                                     steps=300, seed=5))  # fmt: skip
    ds, truth = data.dataset, data.ground_truth
    cables = truth.effects[0]["params"]["springs"]
    s0, s1, u = transitions_of(ds.split("train"))
    with torch.no_grad():
        full = Engine(ds.topology, ds.dt, effects=[SlackSprings(ds.topology, springs=cables)])
        err = (full.step(s0, truth.params, u).p - s1.p).norm(dim=-1).max()
    assert err < 1e-15


def test_control_lag_filters_commands(ico):
    u = torch.zeros(1, 100, ico.topology.n_rods, 3, dtype=torch.float64)
    u[:, 10:] = 1.0
    f = ControlLag(ico.topology, time_constant=0.01).filter_commands(u, 1e-3)
    assert f[0, 9].abs().max() == 0 and 0.5 < f[0, 20, 0, 0] < 0.7 and f[0, -1, 0, 0] > 0.99


def test_identified_contact_free_fall_and_bounce_within_2cm():
    """Contact identified from tumbling data, then a 2-s drop from rest: MuJoCo within 2 cm."""
    train = planted_dataset(PlantSpec("ground_contact", "moderate", n_train=4, n_val=0, n_test=0,
                                      steps=500, seed=11))  # fmt: skip
    start = GroundContact(train.dataset.topology, stiffness=1000.0, damping=50.0, friction=0.5,
                          impedance=0.9)  # fmt: skip
    free = [(0, k) for k in ("stiffness", "damping", "friction", "impedance")]
    windows = sample_windows(train.dataset.split("train"), 1, 600, seed=0)
    engine = Engine(train.dataset.topology, train.dataset.dt)
    problem = WindowedProblem.effects_only(engine, train.ground_truth.params, [start], free,
                                           windows)  # fmt: skip
    contact = problem.effects_at(fit(problem, FitOptions.dense(max_iter=20)))[0]
    assert abs(float(contact.values["friction"]) - 1.0) < 1e-3
    drop = drop_check(train.ground_truth.params, [contact], n=3, seed=21)
    assert drop.lowest < 0.0  # it did reach the floor and bounce
    assert drop.worst < DROP_TOLERANCE


def test_effect_coordinate_the_data_does_not_see_has_an_infinite_standard_error():
    """Contact parameters on tumbling data are seen (finite, positive standard errors,
    friction to its true 1.0); a control lag on data without control acts on nothing (a
    zero column of the Jacobian beside contact coordinates whose curvatures differ by
    orders of magnitude), so its standard error is infinite, not 0 and not round-off."""
    train = planted_dataset(PlantSpec("ground_contact", "moderate", n_train=4, n_val=0, n_test=0,
                                      steps=500, seed=11))  # fmt: skip
    topo = train.dataset.topology
    start = GroundContact(topo, stiffness=1000.0, damping=50.0, friction=0.5, impedance=0.9)
    lag = ControlLag(topo, time_constant=0.02)
    free = [(0, k) for k in ("stiffness", "damping", "friction", "impedance")]
    windows = sample_windows(train.dataset.split("train"), 1, 600, seed=0)
    problem = WindowedProblem.effects_only(Engine(topo, train.dataset.dt),
                                           train.ground_truth.params, [start, lag],
                                           [*free, (1, "time_constant")], windows)  # fmt: skip
    assert problem.vec.coords is not None
    assert problem.vec.coords.names()[-1] == "control_lag.time_constant"
    contact, fitted_lag = problem.effects_at(fit(problem, FitOptions.dense(max_iter=20)))
    keys = [k for _, k in free]
    se = np.array([contact.uncertainty[k] for k in keys])
    assert abs(float(contact.values["friction"]) - 1.0) < 1e-3
    assert np.all(np.isfinite(se)) and np.all(se > 0)
    assert contact.uncertainty["friction"] < 1e-2
    assert fitted_lag.uncertainty["time_constant"] == np.inf
    assert float(fitted_lag.values["time_constant"]) == pytest.approx(0.02)
