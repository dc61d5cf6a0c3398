"""Winch cables: motors that wind a cable's rest length, read from MJCF, stepped by the
engine and by the MuJoCo plant, on the lab-style prism of ``test_mjcf_lab``."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from test_mjcf_lab import lab_mjcf, mj_random_state, mj_rod_state

from identification.linear.regression import SpringRodIdentifier
from identification.report.tables import group_errors
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.engine import Engine, State
from tensegrity_env.engine.winch import REST, SPEED
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import from_mjcf, to_mjcf
from tensegrity_env.model import Model
from tensegrity_sr.cli import main

#: wound cables c0, c4, c8: v_max [m/s], range [m], lag [s] (c4 without lag)
WOUND = (0, 4, 8)
SPEEDS = (0.3, 0.2, 0.25)
LAGS = (0.05, 0.0, 0.02)


def winch_xml(lags: tuple[float, ...] = LAGS, low: float = 0.5, high: float = 1.6) -> str:
    """``<custom>`` with one winch numeric per wound cable (no tau where the lag is 0)."""
    out = []
    for c, v, tau in zip(WOUND, SPEEDS, lags, strict=True):
        data = f"{v} {low} {high}" + (f" {tau}" if tau else "")
        out.append(f'<numeric name="winch:c{c}" data="{data}"/>')
    return "<custom>" + "".join(out) + "</custom>"


def motor_commands(n: int, seed: int, hold: int = 150) -> np.ndarray:
    """Piecewise-constant commands (n, W), some beyond [-1, 1] (clipped by the motors)."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1.4, 1.4, size=(-(-n // hold), len(WOUND)))
    return np.repeat(u, hold, axis=0)[:n]


def test_winches_are_read_from_custom_numerics() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf(extra=winch_xml()))
    assert asm.topology.winches == WOUND
    assert asm.topology.cable_actuators == ()
    assert asm.params.winch_speed.tolist() == list(SPEEDS)
    assert asm.params.winch_lag.tolist() == list(LAGS)
    assert asm.params.winch_min.tolist() == [0.5] * 3
    assert asm.params.winch_max.tolist() == [1.6] * 3


def test_winches_survive_the_mjcf_and_json_round_trips(tmp_path) -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf(extra=winch_xml()))
    again = from_mjcf("<again>", xml=to_mjcf(asm.topology, asm.params, asm.options))
    assert again.topology.same_as(asm.topology) and again.topology.winches == WOUND
    for f in ("winch_speed", "winch_min", "winch_max", "winch_lag", "rest_length"):
        assert torch.equal(getattr(again.params, f), getattr(asm.params, f)), f
    path = Model(asm.topology, asm.params).save(tmp_path / "params.json")
    doc = json.loads(path.read_text())
    assert doc["params"]["winch_speed"] == list(SPEEDS)
    assert doc["topology"]["winches"] == list(WOUND)
    loaded = Model.load(path)
    assert loaded.topology.winches == WOUND
    assert torch.equal(loaded.params.winch_lag, asm.params.winch_lag)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda x: x.replace('name="winch:c0"', 'name="winch:cX"'),
         "numeric 'winch:cX': no tendon named 'cX'"),
        (lambda x: x.replace('data="0.3 0.5 1.6 0.05"', 'data="0.3 0.5"'),
         "numeric 'winch:c0' has 2 values, expected 3 or 4"),
        (lambda x: x.replace('data="0.3 0.5 1.6 0.05"', 'data="-0.3 0.5 1.6"'),
         r"numeric 'winch:c0': v_max \(value 0\) must be > 0"),
        (lambda x: x.replace('data="0.3 0.5 1.6 0.05"', 'data="0.3 0.5 0.4"'),
         r"numeric 'winch:c0': l_max \(value 2\) must be >= l_min"),
        (lambda x: x.replace('data="0.3 0.5 1.6 0.05"', 'data="0.3 0.5 1.6 -1"'),
         r"numeric 'winch:c0': tau \(value 3\) must be >= 0"),
        (lambda x: x.replace("</custom>", '</custom><actuator><motor tendon="c0"/></actuator>'),
         r"lab3bar: spring\(s\) \['c0'\] have both a winch and a cable actuator"),
    ],
)  # fmt: skip
def test_bad_winches_are_refused_by_name(change, message: str) -> None:
    with pytest.raises(InputError, match=f"<lab>: {message}"):
        from_mjcf("<lab>", xml=change(lab_mjcf(extra=winch_xml())))


def test_bad_winch_parameters_are_refused_by_name(tmp_path) -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf(extra=winch_xml()))
    doc = Model(asm.topology, asm.params).to_document()
    doc["params"]["winch_speed"][1] = 0.0
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(
        InputError, match=r"bad.json: 'winch_speed' of winch on spring 'c4' is 0\.0"
    ):
        Model.load(path)
    doc["params"]["winch_speed"] = [0.1, 0.2]
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"'winch_speed' has shape \(2,\), expected \(3,\)"):
        Model.load(path)


@pytest.mark.parametrize("lags", [LAGS, (0.0, 0.0, 0.0)])
def test_engine_equals_mujoco_with_winches(lags: tuple[float, ...]) -> None:
    """Engine and MuJoCo plant agree to round-off over 1500 steps of winding, clamped
    ranges and clipped commands included (float64)."""
    asm = from_mjcf("<lab>", xml=lab_mjcf("mid", extra=winch_xml(lags, low=0.825, high=0.96)))
    m, d = mj_random_state(asm, seed=31)
    plant = asm.mj_winches()
    steps = 1500
    u = motor_commands(steps, seed=32)
    engine = Engine(asm.topology, dt=m.opt.timestep)
    state = mj_rod_state(asm, d)
    passive = state
    errors, rests = [], []
    for t in range(steps):
        plant.step(d, u[t])
        state = engine.step(state, asm.params, winches=torch.as_tensor(u[t])[None])
        passive = engine.step(passive, asm.params)
        ref = mj_rod_state(asm, d)
        errors.append(
            max(float((getattr(state, k) - getattr(ref, k)).abs().max()) for k in ("p", "v", "q"))
            + float((state.omega - ref.omega).abs().max())
        )
        assert np.array_equal(state.winch[0, :, REST].numpy(), plant.rest_lengths)
        rests.append(plant.rest_lengths)
    rests = np.array(rests)
    planned = plant.plan(u[None])[0]  # the same winding integrated ahead of the rollout
    assert np.array_equal(planned[1:], rests[:-1])
    start = asm.params.rest_length[list(WOUND)].numpy()
    assert np.all(np.ptp(rests, axis=0) > 0.004)  # every cable is wound
    assert np.any(rests == 0.825) and np.any(rests == 0.96)  # both ends of the range are reached
    assert float((passive.p - ref.p).abs().max()) > 1e-2  # the winches move the rods
    assert not np.allclose(rests[0], start)
    assert errors[0] <= 1e-13
    assert max(errors) <= 1e-9, max(errors)


def test_winding_follows_the_motor_law() -> None:
    """dl0/dt = u v_max after the lag's exact decay; commands clipped to [-1, 1]."""
    asm = from_mjcf("<lab>", xml=lab_mjcf(extra=winch_xml()))
    engine = Engine(asm.topology, dt=0.01, substeps=10)
    _m, d = mj_random_state(asm, seed=3)
    state = mj_rod_state(asm, d)
    u = torch.tensor([[2.0, -0.5, 0.4]], dtype=torch.float64)
    out = engine.step(state, asm.params, winches=u)
    h, v = 1e-3, torch.tensor(SPEEDS, dtype=torch.float64)
    target = torch.tensor([1.0, -0.5, 0.4], dtype=torch.float64) * v
    tau = torch.tensor(LAGS, dtype=torch.float64)
    k = torch.arange(1, 11, dtype=torch.float64)[:, None]
    decay = torch.where(tau > 0, torch.exp(-k * h / tau.clamp_min(1e-300)), torch.zeros(()))
    speeds = target * (1 - decay)  # the speed after each substep, from rest
    start = asm.params.rest_length[list(WOUND)]
    assert torch.allclose(out.winch[0, :, SPEED], speeds[-1], rtol=1e-12)
    assert torch.allclose(out.winch[0, :, REST], start + h * speeds.sum(0), rtol=0, atol=1e-15)


def test_native_engine_winds_as_the_pytorch_engine() -> None:
    """``Engine(native=True)`` steps the winches in the C kernel: the same rollout."""
    asm = from_mjcf("<lab>", xml=lab_mjcf("mid", extra=winch_xml()))
    _m, d = mj_random_state(asm, seed=5)
    state = mj_rod_state(asm, d)
    u = torch.as_tensor(motor_commands(30, seed=6))[None]
    native = Engine(asm.topology, dt=2e-3, substeps=2, native=True)
    with torch.no_grad():
        a = native.rollout(state, asm.params, 30, winches=u)
        b = Engine(asm.topology, dt=2e-3, substeps=2).rollout(state, asm.params, 30, winches=u)
    assert float((a.p - b.p).abs().max()) < 1e-12
    assert float((a.winch - b.winch).abs().max()) < 1e-12
    assert a.winch.shape == (1, 31, 3, 2)
    with torch.no_grad():  # the kernel takes the step (None: it fell back to PyTorch)
        assert native.native_step(state.tensors(), asm.params, None, None,  # type: ignore[misc]
                                  a.winch[:, 0], u[:, 0]) is not None  # fmt: skip


def test_winch_speed_and_lag_have_gradients() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf("mid", extra=winch_xml()))
    _m, d = mj_random_state(asm, seed=7)
    speed = asm.params.winch_speed.clone().requires_grad_(True)
    lag = asm.params.winch_lag.clone().requires_grad_(True)
    rest = asm.params.rest_length.clone().requires_grad_(True)
    params = asm.params.replace(winch_speed=speed, winch_lag=lag, rest_length=rest)
    u = torch.as_tensor(motor_commands(40, seed=8, hold=10))[None]
    roll = Engine(asm.topology, dt=1e-3).rollout(mj_rod_state(asm, d), params, 40, winches=u)
    roll.p[:, -1].sum().backward()
    assert torch.all(speed.grad != 0) and torch.all(torch.isfinite(speed.grad))
    assert lag.grad[0] != 0 and lag.grad[1] == 0 and torch.all(torch.isfinite(lag.grad))
    assert torch.all(rest.grad[list(WOUND)] != 0)  # the wound springs' starting rest lengths


# ---------------------------------------------------------------------- identification
@cache
def _winch_data(tmp: str, lag: float) -> tuple:
    """MuJoCo trajectories of the prism driven by its winches (ranges never reached)."""
    path = Path(tmp) / f"lab_winches_{lag}.xml"
    path.write_text(lab_mjcf("mid", extra=winch_xml((lag,) * 3, low=0.2, high=2.0)))
    spec = GenerateSpec(mjcf=str(path), n_train=3, n_val=0, n_test=1, steps=600, seed=4,
                        control_std=1.0, control_hold=0.05)  # fmt: skip
    return generate_dataset(spec)


def test_generate_drives_the_winches(tmp_path_factory: pytest.TempPathFactory) -> None:
    ds, truth = _winch_data(str(tmp_path_factory.mktemp("winches")), 0.0)
    train = ds.split("train")
    assert train.winch_control.shape == (3, 600, 3)
    assert np.abs(train.winch_control).max() <= 1.0 and train.winch_control.std() > 0.4
    assert train.control.std() == 0.0  # no world-frame force actuators in this model
    assert truth.params.winch_speed.tolist() == list(SPEEDS)
    # the recorded motion is the engine's, winch state integrated from rest
    engine = Engine(ds.topology, dt=ds.dt)
    first = State.from_numpy(*(getattr(train, k)[:1, 0] for k in ("p", "v", "q", "omega")))
    roll = engine.rollout(
        first, truth.params, 600, winches=torch.as_tensor(train.winch_control[:1])
    )
    assert float((roll.p - torch.as_tensor(train.p[:1])).abs().max()) <= 1e-9


@pytest.mark.parametrize("lag", [0.0, 0.04])
def test_regression_recovers_winch_speeds_given_the_lag(
    tmp_path_factory: pytest.TempPathFactory, lag: float
) -> None:
    """From exact rod states and the command log, ``K``, ``c`` and ``v_max`` to round-off."""
    ds, truth = _winch_data(str(tmp_path_factory.mktemp("winches")), lag)
    anchor = {"mass[r0]": float(truth.params.mass[0])}
    est = SpringRodIdentifier(anchors=anchor, winch_lag=lag).fit(ds)
    errors = group_errors(est.table_, truth.params)
    assert {"stiffness", "damping", "winch_speed"} <= set(errors)
    assert max(errors.values()) <= 1e-8, errors
    assert [r.name for r in est.table_ if r.group == "winch_speed"] == [
        f"winch_speed[c{c}]" for c in WOUND
    ]
    assert est.params_.winch_lag.tolist() == [lag] * 3
    # the range is the span of rest lengths the training data wound through
    assert torch.all(est.params_.winch_min < truth.params.rest_length[list(WOUND)])
    assert torch.all(est.params_.winch_max > truth.params.rest_length[list(WOUND)])
    assert est.score(ds, "train")["one_step_position_error"] <= 1e-12
    if lag:  # a wrong lag biases the speeds
        wrong = SpringRodIdentifier(anchors=anchor, winch_lag=0.0).fit(ds)
        assert group_errors(wrong.table_, truth.params)["winch_speed"] > 1e-3


# ---------------------------------------------------------------------- the shipped robot
LAB_PRISM = Path(__file__).resolve().parents[2] / "tensegrity_env" / "assets" / "lab_prism.xml"


def test_shipped_lab_prism_winds_its_triangles_on_the_floor() -> None:
    """Six winches on the end-cap triangles, three passive diagonals; engine (floor
    contact as the file declares it) and MuJoCo plant agree over 1000 steps."""
    asm = from_mjcf(LAB_PRISM)
    topo = asm.topology
    wound = {frozenset(topo.spring_nodes[s] // 2) for s in topo.winches}
    assert topo.n_winches == 6 and topo.cable_actuators == ()
    for s in topo.winches:  # a triangle cable joins the same end of two rods
        a, b = topo.spring_nodes[s]
        assert a % 2 == b % 2
    assert len(wound) == 3
    assert asm.params.winch_lag.tolist() == [0.03] * 6
    m = asm.model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    plant = asm.mj_winches()
    engine = Engine(topo, dt=m.opt.timestep, effects=asm.declared_effects())
    state = mj_rod_state(asm, d)
    u = np.random.default_rng(12).uniform(-1, 1, size=(10, 6)).repeat(100, axis=0)
    worst, contacts = 0.0, 0
    for t in range(len(u)):
        plant.step(d, u[t])
        contacts += d.ncon
        state = engine.step(state, asm.params, winches=torch.as_tensor(u[t])[None])
        ref = mj_rod_state(asm, d)
        worst = max(
            worst, float((state.p - ref.p).abs().max()), float((state.q - ref.q).abs().max())
        )
    assert contacts >= len(u)  # it stands on the floor throughout
    assert np.ptp(plant.rest_lengths) > 0.05  # the commands wound the cables apart
    assert worst <= 1e-9, worst


def test_identify_command_with_winches(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    robot = tmp_path / "robot.xml"
    robot.write_text(lab_mjcf("mid", extra=winch_xml((0.04,) * 3, low=0.2, high=2.0)))
    data, out = tmp_path / "d.h5", tmp_path / "params.json"
    assert main(["generate", "--mjcf", str(robot), "--n-train", "2", "--n-val", "0", "--n-test",
                 "1", "--steps", "400", "--seed", "5", "--control-std", "1", "--no-progress",
                 "-o", str(data)]) == 0  # fmt: skip
    base = ["identify", str(data), "--anchor", "mass[r0]=2.17", "-o", str(out)]
    assert main([*base, "--winch-lag", "0.04"]) == 0
    text = capsys.readouterr().out
    assert "winch_speed[c4]" in text and "winch_max[c8]" in text
    doc = json.loads(out.read_text())
    assert np.allclose(doc["params"]["winch_speed"], SPEEDS, rtol=1e-6)
    assert doc["params"]["winch_lag"] == [0.04] * 3
    assert Model.load(out).topology.winches == WOUND
    for bad, message in (
        ("-1", "--winch-lag must be a finite number >= 0"),
        ("soon", "'soon' is neither"),
    ):
        out.unlink(missing_ok=True)
        assert main([*base, "--winch-lag", bad]) != 0
        assert message in capsys.readouterr().err


def test_regression_warns_where_the_data_reaches_a_range(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    ds, truth = _winch_data(str(tmp_path_factory.mktemp("winches")), 0.0)
    anchor = {"mass[r0]": float(truth.params.mass[0])}
    est = SpringRodIdentifier(anchors=anchor, init_params=truth.params).fit(ds)
    assert torch.equal(est.params_.winch_max, truth.params.winch_max)  # the range is kept
    start = truth.params.rest_length[list(WOUND)]
    narrow = truth.params.replace(winch_min=start - 1e-4, winch_max=start + 1e-4)
    with pytest.warns(UserWarning, match=r"winches on \[.*'c0'.*\] reach the end of their range"):
        SpringRodIdentifier(anchors=anchor, init_params=narrow).fit(ds)


def test_unwound_winches_are_reported_not_identifiable(tmp_path: Path) -> None:
    """Without winding in the data, ``v_max`` is not identifiable: named, never a number
    (or the starting params' value where given)."""
    path = tmp_path / "robot.xml"
    path.write_text(lab_mjcf("mid", extra=winch_xml()))
    spec = GenerateSpec(mjcf=str(path), n_train=2, n_val=0, n_test=0, steps=300, seed=6,
                        control_std=0.0)  # fmt: skip
    ds, truth = generate_dataset(spec)
    assert not ds.split("train").has_winch_commands
    anchor = {"mass[r0]": float(truth.params.mass[0])}
    est = SpringRodIdentifier(anchors=anchor).fit(ds)
    assert {f"winch_speed[c{c}]" for c in WOUND} <= set(est.unidentifiable())
    assert torch.isnan(est.params_.winch_speed).all()
    given = SpringRodIdentifier(anchors=anchor, init_params=truth.params).fit(ds)
    assert torch.equal(given.params_.winch_speed, truth.params.winch_speed)
