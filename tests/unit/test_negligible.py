"""Negligible effects: the force a candidate adds on the rods, in rod weights."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from identification.discovery import FittedModel
from identification.discovery.judge import ONE_STEP, Candidate, judge
from identification.discovery.negligible import NEGLIGIBLE, force_ratio, group_power
from tensegrity_env import assemblies
from tensegrity_env.effects import ControlLag, ForceField, LinearDrag
from tensegrity_env.engine import State
from tensegrity_env.model import Model

ICO = assemblies.icosahedron()


def _model(effects=()) -> FittedModel:
    return FittedModel(Model(ICO.topology, ICO.params, list(effects)), n_params=0)


def _states(n: int = 16, seed: int = 0) -> State:
    rng = np.random.default_rng(seed)
    R = ICO.topology.n_rods
    q = np.repeat(ICO.pose_q[None], n, 0)
    return State.from_numpy(np.repeat(ICO.pose_p[None], n, 0), rng.normal(size=(n, R, 3)), q,
                            rng.normal(size=(n, R, 3)))  # fmt: skip


def test_a_uniform_force_is_its_size_in_rod_weights() -> None:
    force = torch.tensor([0.003, 0.0, 0.004])  # 5 mN on every rod
    ratio = force_ratio(_model([ForceField(ICO.topology, force=force)]), _model(), _states())
    weight = ICO.params.mass.double() * 9.81
    expected = float(((0.005 / weight) ** 2).mean().sqrt())
    assert ratio == pytest.approx(expected, rel=1e-3)
    assert ratio < NEGLIGIBLE


def test_drag_torque_counts_as_a_force_at_the_rod_end() -> None:
    drag = LinearDrag(ICO.topology, translational=[0, 0, 0], rotational=[0.5, 0.5, 0])
    ratio = force_ratio(_model([drag]), _model(), _states())
    assert ratio > NEGLIGIBLE


def test_control_lag_is_not_measured() -> None:
    assert math.isnan(force_ratio(_model([ControlLag(ICO.topology)]), _model(), _states()))


def test_judge_reports_a_negligible_effect_and_rejects_it() -> None:
    current = Candidate("nothing", None, _model(), bic=0.0)
    small = Candidate("force_field", None, _model(), bic=-100.0)
    judge(small, current, 0.9, ONE_STEP, size=2e-4)
    assert not small.accepted
    assert small.verdict.startswith("negligible: its force on the rods is 0.02% of their weight")
    big = Candidate("force_field", None, _model(), bic=-100.0)
    judge(big, current, 0.9, ONE_STEP, size=0.02)
    assert big.accepted


def test_isotropic_drag_removes_b_v_squared() -> None:
    """Linear drag b on every axis: the power its translational part adds is -b |v|^2 per
    rod, summed over the rods, mean over the states; its rotational part removes too."""
    states = _states()
    drag = LinearDrag(ICO.topology, translational=[0.3, 0.3, 0.3], rotational=[0.01, 0.01, 0.01])
    power = group_power(drag, ICO.params, states)
    expected = -0.3 * float(states.v.double().pow(2).sum((-1, -2)).mean())
    assert power["translational"] == pytest.approx(expected, rel=1e-9)
    assert power["rotational"] < 0


def test_judge_rejects_a_drag_part_that_adds_energy_even_within_its_standard_errors() -> None:
    """Translational drag of about -0.1 N*s/m ± 0.05 beside a positive rotational one
    passes the params file's sign check (within 3 standard errors of 0) and may remove
    energy as a whole, but its translational part adds energy: not drag."""
    se = {"translational": [0.05, 0.05, 0.05], "rotational": [0.05, 0.05, 0.05]}
    values = {"translational": [-0.1, -0.04, -0.09], "rotational": [0.5, 0.5, 0.0]}
    drag = LinearDrag(ICO.topology, uncertainty=se, **values)
    pushing = _model([drag])
    assert pushing.model.violation() == ""
    states, current = _states(), Candidate("nothing", None, _model(), bic=0.0)
    power = group_power(drag, ICO.params, states)
    assert power["translational"] > 0 > power["rotational"]
    assert sum(power.values()) < 0  # as a whole it removes energy
    c = Candidate("linear_drag", None, pushing, bic=-100.0)
    judge(c, current, 30.0, ONE_STEP, size=0.02, power=power)
    assert not c.accepted
    assert c.verdict.startswith("rejected: unphysical (linear_drag: its translational part adds")
    resisting = LinearDrag(ICO.topology, translational=[0.1, 0.04, 0.09], rotational=[0, 0, 0])
    ok = Candidate("linear_drag", None, _model([resisting]), bic=-100.0)
    judge(ok, current, 30.0, ONE_STEP, size=0.02,
          power=group_power(resisting, ICO.params, states))  # fmt: skip
    assert ok.accepted


def test_a_drag_part_at_round_off_adds_no_energy() -> None:
    """A part at round-off of zero (a coefficient of -1e-14 N*s/m) puts in ~1e-15 W:
    no energy the data could tell, and no reason to call the drag unphysical."""
    states, current = _states(), Candidate("nothing", None, _model(), bic=0.0)
    se = {"translational": [0.05, 0.05, 0.05], "rotational": [0.05, 0.05, 0.05]}
    drag = LinearDrag(ICO.topology, uncertainty=se, translational=[-1e-14, 0.0, 0.0],
                      rotational=[0.1, 0.1, 0.0])  # fmt: skip
    power = group_power(drag, ICO.params, states)
    assert power["translational"] == 0.0 and power["rotational"] < 0
    c = Candidate("linear_drag", None, _model([drag]), bic=-100.0)
    judge(c, current, 30.0, ONE_STEP, size=0.02, power=power)
    assert c.accepted, c.verdict
