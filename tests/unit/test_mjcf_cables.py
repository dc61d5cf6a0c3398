"""Cable actuators: tendon actuators whose command scales a cable's tension, optionally
through MuJoCo's first-order filter, on the lab-style prism of ``test_mjcf_lab``."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from test_mjcf_lab import lab_mjcf, mj_random_state, mj_rod_state

from identification.discovery.library import FitSettings
from identification.discovery.loop import EffectDiscovery
from identification.discovery.one_step import OneStepScorer
from identification.linear.extended import ExtendedIdentifier, evaluate_model
from identification.linear.regression import SpringRodIdentifier
from identification.report.tables import group_errors
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.effects import ControlLag
from tensegrity_env.engine import Engine
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import from_mjcf, to_mjcf

#: cables c0, c4 and c8 are driven; gains in N per command unit (a pull for u > 0)
DRIVEN = (0, 4, 8)
GAINS = (-40.0, -55.0, -70.0)


def actuators(lag: float = 0.0, form: str = "general") -> str:
    """``<actuator>`` with one tendon actuator per driven cable."""
    out = []
    for k, (c, g) in enumerate(zip(DRIVEN, GAINS, strict=True)):
        if form == "motor":
            out.append(f'<motor name="a{k}" tendon="c{c}" gear="{g}"/>')
            continue
        dyn = f' dyntype="filter" dynprm="{lag}"' if lag else ""
        out.append(f'<general name="a{k}" tendon="c{c}" gainprm="{g}"{dyn}/>')
    return "<actuator>" + "".join(out) + "</actuator>"


def commands(n: int, seed: int, hold: int = 20) -> np.ndarray:
    """Piecewise-constant random commands (n, C)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(-(-n // hold), len(DRIVEN)))
    return np.repeat(u, hold, axis=0)[:n]


def test_tendon_actuators_are_read_as_cable_commands() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf(extra=actuators()))
    assert asm.topology.cable_actuators == DRIVEN
    assert asm.params.cable_gain.tolist() == list(GAINS)
    assert asm.cable_lag == 0.0
    motor = from_mjcf("<lab>", xml=lab_mjcf(extra=actuators(form="motor")))
    assert motor.params.cable_gain.tolist() == list(GAINS)  # motor: the gear is the gain
    lagged = from_mjcf("<lab>", xml=lab_mjcf(extra=actuators(lag=0.03)))
    assert lagged.cable_lag == 0.03 and lagged.options.cable_lag == 0.03


@pytest.mark.parametrize("lag", [0.0, 0.03])
def test_engine_equals_mujoco_with_cable_actuators(lag: float) -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf("mid", extra=actuators(lag)))
    m, d = mj_random_state(asm, seed=21)
    steps = 1000
    u = commands(steps, seed=22)
    acting = torch.as_tensor(u)[None]
    if lag:
        acting = ControlLag(asm.topology, time_constant=lag).filter_commands(
            acting, m.opt.timestep, explicit=True
        )
    engine = Engine(asm.topology, dt=m.opt.timestep)
    state = mj_rod_state(asm, d)
    errors = []
    passive = state  # the same start without cable commands
    for t in range(steps):
        d.ctrl[asm.cable_actuators] = u[t]
        mujoco.mj_step(m, d)
        state = engine.step(state, asm.params, cables=acting[:, t])
        passive = engine.step(passive, asm.params)
        ref = mj_rod_state(asm, d)
        errors.append(
            max(float((getattr(state, k) - getattr(ref, k)).abs().max()) for k in ("p", "v", "q"))
            + float((state.omega - ref.omega).abs().max())
        )
    assert float((passive.p - ref.p).abs().max()) > 1e-2  # the commands move the rods
    assert errors[0] <= 1e-13
    assert max(errors) <= 1e-10, max(errors)


def test_cable_actuators_survive_the_mjcf_round_trip() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf(extra=actuators(0.02)))
    again = from_mjcf("<again>", xml=to_mjcf(asm.topology, asm.params, asm.options))
    assert again.topology.same_as(asm.topology)
    assert torch.equal(again.params.cable_gain, asm.params.cable_gain)
    assert again.cable_lag == 0.02


@pytest.mark.parametrize(
    ("change", "what"),
    [
        (lambda x: x.replace('gainprm="-40.0"', 'gainprm="-40.0" biastype="affine" biasprm="0 -5 0"'),
         "bias"),
        (lambda x: x.replace('gainprm="-40.0"', 'gainprm="-40.0" dyntype="integrator"'),
         "activation dynamics integrator"),
        (lambda x: x.replace('gainprm="-40.0"', 'gainprm="-40.0" forcelimited="true" forcerange="-1 1"'),
         "force or activation limit"),
    ],
)  # fmt: skip
def test_other_tendon_actuators_are_refused_by_name(change, what: str) -> None:
    xml = change(lab_mjcf(extra=actuators()))
    with pytest.raises(InputError, match=f"cable actuator 'a0' has .*{what}.*--ignore actuators"):
        from_mjcf("<lab>", xml=xml)


def test_different_filters_are_refused() -> None:
    xml = lab_mjcf(extra=actuators(0.03).replace('dynprm="0.03"/><general name="a2"',
                                                 'dynprm="0.05"/><general name="a2"'))  # fmt: skip
    with pytest.raises(InputError, match="different filters"):
        from_mjcf("<lab>", xml=xml)


@cache
def _cable_data(tmp: str, lag: float) -> tuple:
    path = Path(tmp) / f"lab_cables_{lag}.xml"
    path.write_text(lab_mjcf("mid", extra=actuators(lag)))
    spec = GenerateSpec(
        mjcf=str(path), n_train=4, n_val=0, n_test=1, steps=400, seed=3, control_std=1.0,
        control_hold=0.02,
    )  # fmt: skip
    return generate_dataset(spec)


def test_generate_drives_the_cable_actuators(tmp_path_factory: pytest.TempPathFactory) -> None:
    ds, truth = _cable_data(str(tmp_path_factory.mktemp("cables")), 0.03)
    train = ds.split("train")
    assert train.cable_control.shape == (4, 400, 3)
    assert 0.5 < float(train.cable_control.std()) < 1.5
    assert train.control.std() == 0.0  # no world-frame force actuators in this model
    assert [e["name"] for e in truth.effects] == ["control_lag"]
    assert truth.effects[0]["params"]["time_constant"] == 0.03
    assert truth.params.cable_gain.tolist() == list(GAINS)


def test_identify_recovers_the_cable_gains(tmp_path_factory: pytest.TempPathFactory) -> None:
    ds, truth = _cable_data(str(tmp_path_factory.mktemp("cables")), 0.0)
    anchor = {"mass[r0]": float(truth.params.mass[0])}
    est = SpringRodIdentifier(anchors=anchor).fit(ds)
    errors = group_errors(est.table_, truth.params)
    assert "cable_gain" in errors
    assert max(errors.values()) <= 1e-6, errors
    assert [r.name for r in est.table_ if r.group == "cable_gain"] == [
        f"cable_gain[c{c}]" for c in DRIVEN
    ]
    assert est.score(ds, "test")["one_step_position_error"] <= 1e-12


def test_identify_recovers_filtered_cable_gains_given_the_lag(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    ds, truth = _cable_data(str(tmp_path_factory.mktemp("cables")), 0.03)
    lag = ControlLag(ds.topology, time_constant=0.03)
    anchor = {"mass[r0]": float(truth.params.mass[0])}
    est = ExtendedIdentifier(effects=[lag], anchors=anchor).fit(ds)
    errors = group_errors(est.table_, truth.params)
    assert max(errors.values()) <= 1e-6, errors
    assert evaluate_model(ds.topology, est.params_, [lag], ds, "test")["one_step"] <= 1e-12
    # without the lag, the gains come out wrong
    plain = SpringRodIdentifier(anchors=anchor).fit(ds)
    assert group_errors(plain.table_, truth.params)["cable_gain"] > 1e-2


@pytest.mark.parametrize("lag", [0.0, 0.03])
def test_diagnose_names_the_cable_filter_as_control_lag(
    tmp_path_factory: pytest.TempPathFactory, lag: float
) -> None:
    """The residual loop finds the actuators' filter (and only when there is one)."""
    path = tmp_path_factory.mktemp("lag") / "lab.xml"
    path.write_text(lab_mjcf("mid", extra=actuators(lag)))
    spec = GenerateSpec(mjcf=str(path), n_train=4, n_val=2, n_test=2, steps=400, seed=5,
                        control_std=1.0, control_hold=0.02)  # fmt: skip
    ds, truth = generate_dataset(spec)
    settings = FitSettings(anchors={"mass[r0]": float(truth.params.mass[0])})
    with np.errstate(invalid="ignore", divide="ignore"):
        loop = EffectDiscovery(OneStepScorer(settings, horizon_s=0.1), 1,
                               ["control_lag", "linear_drag", "force_field"], log=lambda s: None)  # fmt: skip
        result = loop.fit(ds).result_
    if not lag:
        assert result.model.names == []
        return
    assert result.model.names == ["control_lag"]
    tau = float(result.model.effects[0].values["time_constant"])
    assert abs(tau - lag) <= 0.02 * lag, tau
    gains = result.model.params.cable_gain.numpy()
    assert np.allclose(gains, GAINS, rtol=1e-3), gains
    assert result.final_test["one_step"] <= 1e-3 * result.baseline_test["one_step"]
