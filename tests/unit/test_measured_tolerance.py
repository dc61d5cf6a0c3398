"""Models within the identification targets: how the floor checks are read."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import measured_tolerance
from measured_plant import Cell, true_model, write_cell
from measured_tolerance import TOLERANCES, tolerance_reference, within_targets


def test_models_within_targets_stay_within_them_and_physical():
    truth = true_model(Cell("floor", 120.0, 1e-3, 0.0, "none")).params
    t = truth.numpy()
    seen = {g: [] for g in ("mass", "stiffness", "damping", "inertia")}
    for seed in range(20):
        params, contact = within_targets(truth, np.random.default_rng(seed))
        p = params.numpy()
        for g in seen:
            rel = p[g] / t[g] - 1.0
            assert np.all(np.abs(rel) <= TOLERANCES[g] + 1e-12), g
            seen[g].append(rel)
        # one factor per rod: the principal moments keep their ratios (and the triangle
        # inequality), the rest of the parameters are untouched
        ratio = p["inertia"] / t["inertia"]
        assert np.allclose(ratio, ratio[:, :1])
        np.testing.assert_array_equal(p["rest_length"], t["rest_length"])
        for k, name in (("stiffness", "contact stiffness"), ("damping", "contact damping"),
                        ("friction", "friction")):  # fmt: skip
            assert abs(contact[k] - 1.0) <= TOLERANCES[name]
    # the draws fill the band rather than sitting at its centre
    for g, rels in seen.items():
        assert np.max(np.abs(np.concatenate([r.ravel() for r in rels]))) > 0.8 * TOLERANCES[g]
    a, _ = within_targets(truth, np.random.default_rng(3))
    b, _ = within_targets(truth, np.random.default_rng(3))
    np.testing.assert_array_equal(a.numpy()["stiffness"], b.numpy()["stiffness"])


def test_with_zero_tolerance_the_reference_is_the_true_model(tmp_path, monkeypatch):
    """No error allowed: the reference models are the truth, whose checks are round-off."""
    monkeypatch.setattr(measured_tolerance, "TOLERANCES", dict.fromkeys(TOLERANCES, 0.0))
    data = write_cell(Cell("floor", 120.0, 1e-3, 0.0, "none"), tmp_path / "cell")
    ref = tolerance_reference(data, n_models=1)
    assert ref["rolling_median"] < 1e-8 and ref["drop_median"] < 1e-8, ref
    assert ref["drop_passes"] == 1
