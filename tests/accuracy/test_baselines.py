"""The paper's baselines: each trains and beats a constant-velocity predictor one step."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
import torch

from identification.data.dataset import Dataset, GroundTruth
from identification.experiments.baselines import (
    ConstantVelocity,
    EnginePredictor,
    Interaction,
    InteractionInt,
    KoopmanConfig,
    KoopmanInt,
    TrainConfig,
)
from identification.experiments.baselines.common import Geometry
from identification.experiments.baselines.evaluate import one_step_errors, rollout_error_curve
from identification.experiments.baselines.koopman import incident_springs, monomial_powers
from identification.experiments.baselines.training import Standardizer
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.engine import Engine
from tensegrity_env.io_utils import InputError

#: A quick budget: enough to learn something, small enough for CI.
QUICK = TrainConfig(hidden=64, layers=2, lr=3e-3, batch=128, epochs=8, patience=3,
                    max_train=8_000, max_val=2_000)  # fmt: skip


@cache
def _icosahedron() -> tuple[Dataset, GroundTruth]:
    """Many short trajectories: varied states, few transitions."""
    spec = GenerateSpec(assembly="icosahedron", n_train=160, n_val=20, n_test=20, steps=50, seed=3)
    return generate_dataset(spec)


@cache
def _fitted(kind: str) -> object:
    ds, _ = _icosahedron()
    model = {
        "Interaction": lambda: Interaction(QUICK),
        "Interaction+Int": lambda: InteractionInt(QUICK),
        "Koopman+Int": lambda: KoopmanInt(KoopmanConfig(degree=2)),  # quick, as QUICK
    }[kind]()
    return model.fit(ds)


@pytest.mark.parametrize("kind", ["Interaction", "Interaction+Int", "Koopman+Int"])
def test_baseline_beats_constant_velocity_one_step_on_held_out_data(kind: str) -> None:
    ds, _ = _icosahedron()
    model = _fitted(kind)
    test = ds.split("test")
    got = one_step_errors(model, test, n=2_000)
    ref = one_step_errors(ConstantVelocity(ds.dt), test, n=2_000)
    # the dynamics live in the velocities: predicting "no change" has no skill there
    assert got["velocity"] < 0.7 * ref["velocity"], (got, ref)
    assert got["angular_velocity"] < ref["angular_velocity"], (got, ref)
    h = model.history_
    assert np.all(np.isfinite(h.val_loss))
    if kind != "Koopman+Int":  # the models with an integration module get positions right too
        assert h.best_epoch >= 0 and h.val_loss[h.best_epoch] < h.val_loss[0] + 1e-12
    if kind != "Interaction":
        assert got["position"] < ref["position"], (got, ref)


def test_rollout_curve_is_zero_for_the_true_engine_and_grows_for_constant_velocity() -> None:
    ds, truth = _icosahedron()
    test = ds.split("test")
    ours = rollout_error_curve(EnginePredictor(Engine(ds.topology, ds.dt), truth.params), test)
    cv = rollout_error_curve(ConstantVelocity(ds.dt), test, horizon=20)
    assert ours.shape == (test.n_transitions + 1,) and cv.shape == (21,)
    assert ours.max() < 1e-12
    assert cv[0] == 0 and np.all(np.diff(cv[1:]) > 0)


def test_koopman_spring_law_basis_contains_the_element_physics() -> None:
    """On the one-rod element the first-principles basis is exact (paper: ≈ ours)."""
    ds, _ = generate_dataset(GenerateSpec.from_preset("small", assembly="element"))
    model = KoopmanInt(KoopmanConfig(basis="spring_law", degree=2)).fit(ds)
    assert model.name == "Koopman+Int (spring-law basis)"
    err = one_step_errors(model, ds.split("test"), n=400)
    assert err["velocity"] < 1e-8 and err["angular_velocity"] < 1e-7
    assert model.history_.best == min(model.history_.ridge)


def test_koopman_polynomial_basis_approximates_but_cannot_express_the_spring_law() -> None:
    """The generic dictionary: better than "no change" on little data, far from exact."""
    ds, _ = generate_dataset(GenerateSpec.from_preset("small", assembly="element"))
    model = KoopmanInt(KoopmanConfig(basis="polynomial", degree=3)).fit(ds)
    assert model.name == "Koopman+Int"
    test = ds.split("test")
    err = one_step_errors(model, test, n=400)
    ref = one_step_errors(ConstantVelocity(ds.dt), test, n=400)
    assert err["velocity"] < 0.5 * ref["velocity"], (err, ref)
    assert err["velocity"] > 1e-6  # approximation error, not round-off


def test_koopman_rejects_an_unknown_basis() -> None:
    with pytest.raises(InputError, match="basis"):
        KoopmanInt(KoopmanConfig(basis="fourier"))


def test_koopman_incidence_and_monomials() -> None:
    ds, _ = _icosahedron()
    idx, sign, mask = incident_springs(Geometry(ds.topology))
    assert idx.shape == (6, 8) and bool(mask.all())  # 8 springs on every icosahedron rod
    assert torch.all((sign == 1) | (sign == -1))
    assert monomial_powers(2) == [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]


def test_standardizer_keeps_near_constant_features_quiet() -> None:
    x = torch.stack([torch.randn(1000), 1e-14 * torch.randn(1000)], dim=-1)
    norm = Standardizer(x)
    y = norm(x)
    assert abs(float(y[:, 0].std(correction=0)) - 1) < 1e-6
    assert float(y[:, 1].abs().max()) < 1e-9  # not blown up into unit-variance noise
    torch.testing.assert_close(norm.inverse(y), x)


def test_baselines_need_a_validation_split_and_a_fit() -> None:
    ds, _ = _icosahedron()
    no_val = Dataset(ds.topology, ds.dt, {"train": ds.split("train")})
    with pytest.raises(InputError, match="val"):
        Interaction(QUICK).fit(no_val)
    with pytest.raises(InputError, match="val"):
        KoopmanInt().fit(no_val)
    with pytest.raises(RuntimeError, match="fit"):
        InteractionInt(QUICK).predict(None)  # type: ignore[arg-type]
