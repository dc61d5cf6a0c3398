"""Control forces h * f_u: h identified with the other modules frozen, long horizons."""

from __future__ import annotations

from functools import cache

import numpy as np
import torch

from identification.experiments.long_horizon import long_horizon_errors
from identification.linear.regression import SpringRodIdentifier
from identification.report.tables import group_errors
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.engine import Engine

FROZEN = ("stiffness", "damping", "rest_length", "mass", "inertia")


@cache
def _perturbed():
    spec = GenerateSpec.from_preset("perturbed", n_train=2, n_test=1, steps=2000, seed=9)
    return generate_dataset(spec)


@cache
def _free():
    return generate_dataset(GenerateSpec(n_train=6, n_val=0, n_test=1, steps=200, seed=2))


def test_h_identified_with_other_modules_frozen_from_a_fit_without_control() -> None:
    free, truth = _free()
    base = SpringRodIdentifier(anchors={"mass[rod0]": float(truth.params.mass[0])}).fit(free)
    assert base.unidentifiable() == ["control_gain"]  # no control in that data
    perturbed, truth_p = _perturbed()
    est = SpringRodIdentifier(init_params=base.params_, freeze=FROZEN).fit(perturbed)
    h, h_true = float(est.params_.control_gain), float(truth_p.params.control_gain)
    assert abs(h / h_true - 1) <= 1e-4
    for field in FROZEN:  # frozen parameters did not move
        assert torch.equal(getattr(est.params_, field), getattr(base.params_, field))


def test_joint_fit_on_perturbed_data_keeps_every_parameter() -> None:
    perturbed, truth = _perturbed()
    est = SpringRodIdentifier(anchors={"mass[rod0]": float(truth.params.mass[0])}).fit(perturbed)
    assert max(group_errors(est.table_, truth.params).values()) < 1e-6


def test_wrong_h_gives_a_much_larger_long_horizon_error() -> None:
    perturbed, truth = _perturbed()
    engine = Engine(perturbed.topology, perturbed.dt)
    split = perturbed.split("test")
    good = long_horizon_errors(engine, truth.params, split)
    wrong = truth.params.replace(control_gain=truth.params.control_gain * 1.1)
    bad = long_horizon_errors(engine, wrong, split)
    assert good["position"][2000] <= 1e-3  # <= 1 mm after 2,000 steps
    assert bad["position"][2000] > 100 * max(good["position"][2000], 1e-9)
    assert bad["position"][2000] > 1e-3
    assert np.all(np.isfinite(bad["orientation"]))
