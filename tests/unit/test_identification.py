"""Linear-regression identification recovers known parameters and says what it cannot see."""

from __future__ import annotations

import json
from functools import cache

import numpy as np
import pytest
import torch

from identification.data.dataset import Dataset, GroundTruth, Split, write_dataset
from identification.linear.regression import NotFittedError, SpringRodIdentifier
from identification.report.tables import group_errors
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.engine import State
from tensegrity_env.model import Model
from tensegrity_sr.cli import main


@cache
def _data(assembly: str = "icosahedron", control_std: float = 1.0, n: int = 6, steps: int = 200):
    spec = GenerateSpec(
        assembly=assembly,
        n_train=n,
        n_val=0,
        n_test=2,
        steps=steps,
        seed=4,
        control_std=control_std,
    )
    return generate_dataset(spec)


def _anchor(truth: GroundTruth) -> dict[str, float]:
    return {"mass[rod0]": float(truth.params.mass[0])}


@pytest.mark.parametrize("assembly", ["icosahedron", "element"])
def test_recovers_every_parameter_from_clean_data(assembly: str) -> None:
    ds, truth = _data(assembly)
    est = SpringRodIdentifier(anchors=_anchor(truth)).fit(ds)
    errors = group_errors(est.table_, truth.params)
    assert set(errors) >= {
        "mass",
        "inertia",
        "stiffness",
        "damping",
        "rest_length",
        "control_gain",
    } - ({"mass"} if assembly == "element" else set())
    assert max(errors.values()) < 1e-6, errors
    assert est.unidentifiable() == []
    assert est.condition_number_ < 1e4
    score = est.score(ds, "test")
    assert score["one_step_position_error"] < 1e-12
    assert score["rollout_final_position_error"] < 1e-9


def test_without_anchor_reports_ratios_to_the_first_mass() -> None:
    ds, truth = _data()
    est = SpringRodIdentifier().fit(ds)
    assert est.mode_ == "ratios"
    scale = float(truth.params.mass[0])
    np.testing.assert_allclose(
        est.params_.stiffness.numpy(), truth.params.stiffness.numpy() / scale, rtol=1e-7
    )
    np.testing.assert_allclose(
        est.params_.mass.numpy(), truth.params.mass.numpy() / scale, rtol=1e-7
    )
    # the rest lengths are not affected by the scale
    np.testing.assert_allclose(
        est.params_.rest_length.numpy(), truth.params.rest_length.numpy(), rtol=1e-9
    )


def test_tiny_random_subset_is_enough() -> None:
    """The paper's 0.01 % experiment: ~73 transitions still give <= 1e-4."""
    ds, truth = _data()
    est = SpringRodIdentifier(anchors=_anchor(truth), max_transitions=73, seed=1).fit(ds)
    assert est.n_transitions_ == 73
    assert max(group_errors(est.table_, truth.params).values()) < 1e-4


def test_linear_network_solver_agrees_with_least_squares() -> None:
    ds, truth = _data()
    net = SpringRodIdentifier(solver="network", anchors=_anchor(truth)).fit(ds)
    errors = group_errors(net.table_, truth.params)
    assert errors["stiffness"] < 1e-3 and errors["mass"] < 1e-3 and errors["control_gain"] < 1e-3


def test_shared_parameters_option() -> None:
    ds, truth = _data()
    est = SpringRodIdentifier(shared=True, anchors={"mass": float(truth.params.mass.mean())}).fit(
        ds
    )
    assert est.layout_.names[:2] == ["mass", "inertia[x]"]
    # one stiffness for all: close to the mean of the true per-spring values
    k = est.params_.stiffness.numpy()
    assert np.all(k == k[0])
    assert abs(k[0] / float(truth.params.stiffness.mean()) - 1) < 0.15


def test_no_control_means_gain_not_identifiable() -> None:
    ds, truth = _data(control_std=0.0)
    est = SpringRodIdentifier(anchors=_anchor(truth)).fit(ds)
    assert est.unidentifiable() == ["control_gain"]
    row = next(r for r in est.table_ if r.name == "control_gain")
    assert row.status == "not identifiable" and "no control" in row.note
    assert max(group_errors(est.table_, truth.params).values()) < 1e-6


def test_structure_at_rest_is_reported_not_identifiable() -> None:
    """All at rest in equilibrium: accelerations vanish, so nothing but statics is seen."""
    ds, truth = _data("element", control_std=0.0)
    split = ds.split("train")
    at_rest = {k: np.repeat(getattr(split, k)[:, :1], 50, axis=1) for k in ("p", "q", "nodes")}
    zeros = {k: np.zeros_like(getattr(split, k)[:, :50]) for k in ("v", "omega")}
    # the element's nominal pose is its static equilibrium under gravity
    from tensegrity_env.assemblies import element

    asm = element()
    at_rest["p"][:] = asm.pose_p
    at_rest["q"][:] = asm.pose_q
    rest = Split(control=np.zeros_like(split.control[:, :49]), **at_rest, **zeros)
    rest = Split(
        nodes=rest.nodes, control=rest.control, p=rest.p, q=rest.q,
        v=rest.v, omega=rest.omega,
    )  # fmt: skip
    data = Dataset(ds.topology, ds.dt, {"train": rest})
    est = SpringRodIdentifier(anchors=_anchor(truth)).fit(data)
    missing = set(est.unidentifiable())
    assert {"damping[spring0]", "damping[spring1]", "control_gain"} <= missing
    assert any(name.startswith("inertia") for name in missing)
    for row in est.table_:
        if row.status == "not identifiable" and row.group in ("stiffness", "rest_length"):
            assert np.isnan(row.value)  # never an arbitrary number


def test_frozen_modules_fit_only_the_control_gain() -> None:
    ds, truth = _data()
    wrong = truth.params.replace(control_gain=torch.tensor(7.0, dtype=torch.float64))
    freeze = ("stiffness", "damping", "rest_length", "mass", "inertia")
    est = SpringRodIdentifier(init_params=wrong, freeze=freeze).fit(ds)
    assert est.mode_ == "frozen"
    assert abs(float(est.params_.control_gain) / float(truth.params.control_gain) - 1) < 1e-9
    for field in freeze:
        assert torch.equal(getattr(est.params_, field), getattr(wrong, field)), field


def test_estimator_needs_fit_first() -> None:
    ds = _data()[0]
    s = ds.split("test")
    state = State.from_numpy(s.p[:, 0], s.v[:, 0], s.q[:, 0], s.omega[:, 0])
    with pytest.raises(NotFittedError):
        SpringRodIdentifier().predict(state)


def test_identify_command_writes_a_params_file(tmp_path, capsys) -> None:
    ds, truth = _data()
    path = write_dataset(tmp_path / "d.h5", ds, truth)
    out = tmp_path / "params.json"
    code = main(
        [
            "identify",
            str(path),
            "--anchor",
            f"mass[rod0]={float(truth.params.mass[0])!r}",
            "-o",
            str(out),
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "stiffness[spring0]" in text and "N/m" in text and "rel. error" in text
    model = Model.load(out)
    topology, params, doc = model.topology, model.params, json.loads(out.read_text())
    assert topology.same_as(ds.topology) and model.effects == ()
    assert doc["identifiability"]["mode"] == "anchored"
    assert max(doc["relative_error_vs_ground_truth"].values()) < 1e-6
    np.testing.assert_allclose(params.stiffness.numpy(), truth.params.stiffness.numpy(), rtol=1e-7)
    json.dumps(doc)  # plain JSON
    # a bad anchor is one clear line and exit 2
    code = main(["identify", str(path), "--anchor", "mass[nope]=1", "-o", str(tmp_path / "b.json")])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and err.startswith("error:") and "mass[nope]" in err


@pytest.mark.parametrize("assembly", ["icosahedron", "element"])
@pytest.mark.parametrize("known_rest_length", [False, True])
def test_c_normal_equations_equal_the_pytorch_design(assembly: str, known_rest_length) -> None:
    """The one-pass C kernel builds the same AᵀA as the PyTorch design blocks (with control)."""
    from identification.linear.design import (
        ParameterLayout,
        accumulate_normal,
        rod_blocks,
        rod_slots,
    )
    from identification.linear.features import transition_features, transitions_of
    from identification.linear.native_normal import NativeUnavailable, local_gram_native

    ds, truth = _data(assembly)
    data = ds.split("train")
    layout = ParameterLayout.build(ds.topology, fit_rest_length=not known_rest_length)
    slots = rod_slots(layout)
    g = torch.tensor([0.0, 0.0, -9.81], dtype=torch.float64)
    rest = truth.params.rest_length.double() if known_rest_length else None
    index = np.random.default_rng(0).choice(data.control.shape[0] * 200, 500, replace=False)
    P = layout.n_params
    torch_normal = torch.zeros(P + 1, P + 1, dtype=torch.float64)
    s0, s1, u = transitions_of(data, index)
    feat = transition_features(ds.topology, s0, s1, u, ds.dt)
    accumulate_normal(rod_blocks(feat, slots, g, rest), slots, P, torch_normal)
    assert float(feat.control.abs().max()) > 0.1  # the control column is exercised
    try:
        gram = local_gram_native(ds.topology, data, index, slots, g, ds.dt, rest)
    except NativeUnavailable as e:
        pytest.skip(f"no C compiler: {e}")
    from identification.linear.design import scatter_local_gram

    c_normal = torch.zeros_like(torch_normal)
    scatter_local_gram(gram, slots, c_normal)
    scale = torch.sqrt(torch.diagonal(torch_normal))
    used = scale > 0  # padded and discarded columns stay zero in both
    assert torch.equal(c_normal[~used], torch.zeros_like(c_normal[~used]))
    rel = (c_normal - torch_normal)[used][:, used].abs() / torch.outer(scale[used], scale[used])
    assert float(rel.max()) < 1e-12


def test_both_backends_identify_the_same_parameters() -> None:
    ds, truth = _data()
    native = SpringRodIdentifier(anchors=_anchor(truth), backend="auto").fit(ds)
    reference = SpringRodIdentifier(anchors=_anchor(truth), backend="torch").fit(ds)
    assert reference.backend_ == "torch"
    assert max(group_errors(native.table_, truth.params).values()) < 1e-6
    for field in ("stiffness", "damping", "rest_length", "mass", "inertia", "control_gain"):
        a, b = getattr(native.params_, field), getattr(reference.params_, field)
        assert torch.allclose(a, b, rtol=1e-7, atol=0), field  # I_z is round-off sensitive


def test_unidentifiable_reasons_say_why_once() -> None:
    """The table's status already reads 'not identifiable': each reason says only why."""
    from identification.data.end_caps import RodAxes
    from identification.linear.regression import ParameterRow
    from identification.report.tables import parameter_table
    from identification.trajectory.identifier import TrajectoryIdentifier
    from tensegrity_env.assemblies import icosahedron

    topo = icosahedron().topology
    notes = TrajectoryIdentifier.notes(topo, RodAxes.of(topo), has_control=False)
    assert "control_gain" in notes and len(notes) == 1 + topo.n_rods
    rows = [ParameterRow(name, "group", 0, 1.0, float("nan"), "unit", "not identifiable", note)
            for name, note in notes.items()]  # fmt: skip
    for line in parameter_table(rows).splitlines():
        assert line.count("not identifiable") <= 1, line
