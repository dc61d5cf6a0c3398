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
