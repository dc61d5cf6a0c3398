"""A tension-only spring slack throughout the data: slack at the declared model, it keeps
the declared values (the fit sees nothing of it); slack only at the fit (rest length
run past every measured length), it is written at its longest measured length with the
declared stiffness and damping."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from identification.commands.identify_end_caps import keep_declared
from identification.trajectory.floor_declared import FloorIdentification
from identification.trajectory.slack_in_data import never_taut, settle_slack
from tensegrity_env.ntrt import EXAMPLE_PRISM, from_ntrt


def test_a_cable_never_as_long_as_its_rest_length_keeps_its_declared_values(tmp_path: Path) -> None:
    (tmp_path / "prism.yaml").write_text(EXAMPLE_PRISM)
    robot = from_ntrt(tmp_path / "prism.yaml")
    topo, declared = robot.topology, robot.params
    rng = np.random.default_rng(0)
    nodes = robot.rest_caps[None, None] + rng.normal(
        0, 1e-4, (2, 50, 6, 3)
    )  # the built pose, 0.1 mm noise
    nodes[0, 10:20, 1] = np.nan  # gaps are no lengths
    rest = declared.rest_length.numpy().copy()
    length = np.linalg.norm(
        robot.rest_caps[topo.spring_nodes[:, 0]] - robot.rest_caps[topo.spring_nodes[:, 1]], axis=-1
    )
    rest[3] = length[3] + 0.01  # spring 3 a centimetre longer than it ever is: slack throughout
    effects = robot.declared_effects(ground=False)
    assert never_taut(nodes, topo, effects, rest) == [3]
    assert never_taut(nodes, topo, [], rest) == []  # a linear spring pushes when short: it is seen
    drifted = replace(
        declared, rest_length=torch.as_tensor(rest * 1e4), stiffness=declared.stiffness * 1e6
    )
    est = FloorIdentification(drifted, topo, {}, "absolute", {}, 0.0, True, [], effects[0])
    declared_rest = replace(declared, rest_length=torch.as_tensor(rest))
    # every spring's fitted rest length is past its measured lengths: 3 was slack at the
    # start, the others only at the fit
    other = nodes * 1.01  # another split of the recording, its lengths 1 % longer
    names = keep_declared(est, declared_rest, nodes, effects, [other])
    assert names == sorted(topo.springs[s].name for s in range(topo.n_springs))
    assert float(est.params_.rest_length[3]) == rest[3]
    assert float(est.params_.stiffness[3]) == float(declared.stiffness[3])
    longest = np.nanmax(np.linalg.norm(other[..., topo.spring_nodes[2, 0], :]
                                       - other[..., topo.spring_nodes[2, 1], :], axis=-1))  # fmt: skip
    # a lower bound: slack throughout the recording, as the fitted spring was
    assert float(est.params_.rest_length[2]) == pytest.approx(longest, rel=1e-12)
    assert float(est.params_.stiffness[2]) == float(declared.stiffness[2])
    assert "declared value is kept" in est.notes_[f"rest_length[{topo.springs[3].name}]"]
    assert "longest length in the recording" in est.notes_[f"rest_length[{topo.springs[2].name}]"]


def test_a_cable_taut_at_the_fit_is_left_as_fitted(tmp_path: Path) -> None:
    (tmp_path / "prism.yaml").write_text(EXAMPLE_PRISM)
    robot = from_ntrt(tmp_path / "prism.yaml")
    topo, declared = robot.topology, robot.params
    nodes = robot.rest_caps[None, None] + np.random.default_rng(2).normal(0, 1e-4, (1, 30, 6, 3))
    effects = robot.declared_effects(ground=False)
    fitted = replace(declared, stiffness=declared.stiffness * 1.5, damping=declared.damping * 2)
    params, notes = settle_slack(fitted, declared, nodes, topo, effects)
    assert notes == {}  # the NTRT prism's cables are taut at its built pose
    assert torch.equal(params.stiffness, fitted.stiffness)
    assert torch.equal(params.damping, fitted.damping)


def test_diagnose_fits_the_declared_model_with_its_tension_only_springs(
    tmp_path: Path, monkeypatch
) -> None:  # type: ignore[no-untyped-def]
    """``diagnose --params`` with an NTRT model: its cables' tension-only effect goes into
    the declared model's fit, which the loop's every later fit starts from."""
    import identification.discovery.multi_step as multi_step
    from identification.commands.diagnose import multi_step_scorer
    from identification.data.dataset import Dataset, Split
    from tensegrity_sr.cli import build_parser

    (tmp_path / "prism.yaml").write_text(EXAMPLE_PRISM)
    robot = from_ntrt(tmp_path / "prism.yaml")
    caps = robot.rest_caps[None, None] + np.random.default_rng(1).normal(0, 1e-4, (2, 40, 6, 3))
    data = Dataset(robot.topology, 1 / 120, {s: Split(nodes=caps, control=np.zeros((2, 39, 3, 3)))
                                             for s in ("train", "val", "test")})  # fmt: skip
    args = build_parser().parse_args(["diagnose", str(tmp_path / "take.h5"), "--params",
                                      str(tmp_path / "prism.yaml"), "-o", str(tmp_path / "out")])  # fmt: skip
    scorer = multi_step_scorer(args, data)
    seen: dict[str, object] = {}

    def declared(data, settings, start=None, effects=(), values=None):  # type: ignore[no-untyped-def]
        seen["effects"] = [e.name for e in effects]
        raise RuntimeError("stop")

    monkeypatch.setattr(multi_step, "fit_declared", declared)
    try:
        scorer.begin(data, lambda line: None)
    except RuntimeError:
        pass
    assert seen["effects"] == ["slack_springs"]


def test_diagnose_writes_a_cable_slack_at_its_fit_at_its_longest_recorded_length(
    tmp_path: Path,
) -> None:
    """``diagnose``'s final model: a cable whose fitted rest length runs past every
    measured length is settled as ``identify`` settles it, its standard errors dropped,
    and the report's section shows the values written."""
    from types import SimpleNamespace

    from identification.commands.diagnose import settle_slack_springs, slack_markdown
    from identification.data.dataset import Dataset, Split
    from identification.trajectory.fitted_model import FittedModel
    from tensegrity_env.model import Model

    (tmp_path / "prism.yaml").write_text(EXAMPLE_PRISM)
    robot = from_ntrt(tmp_path / "prism.yaml")
    topo, declared = robot.topology, robot.params
    caps = robot.rest_caps[None, None] + np.random.default_rng(3).normal(0, 1e-4, (1, 40, 6, 3))
    splits = {name: Split(nodes=caps * f, control=np.zeros((1, 39, 3, 3)))
              for name, f in (("train", 1.0), ("val", 1.0), ("test", 1.02))}  # fmt: skip
    data = Dataset(topo, 1 / 120, splits)
    rest = declared.rest_length.clone()
    rest[1] = 5866.0  # the fit ran this cable to its bound
    fitted = replace(declared, rest_length=rest, stiffness=declared.stiffness * 1e4)
    effects = tuple(robot.declared_effects(ground=False))
    name = topo.springs[1].name
    result = SimpleNamespace(model=FittedModel(
        Model(topo, fitted, effects, dt=1 / 120), 0,
        uncertainty={f"rest_length[{name}]": 38.7, f"rest_length[{topo.springs[0].name}]": 1e-3}))  # fmt: skip
    notes = settle_slack_springs(result, declared, data)
    p = result.model.params
    longest = np.linalg.norm(splits["test"].nodes[..., topo.spring_nodes[1, 0], :]
                             - splits["test"].nodes[..., topo.spring_nodes[1, 1], :], axis=-1).max()  # fmt: skip
    assert float(p.rest_length[1]) == pytest.approx(longest, rel=1e-12)  # the test split's, longer
    assert float(p.stiffness[1]) == float(declared.stiffness[1])
    assert float(p.stiffness[0]) == float(fitted.stiffness[0])  # a taut cable as fitted
    assert set(notes) == {f"{g}[{name}]" for g in ("stiffness", "damping", "rest_length")}
    assert f"rest_length[{name}]" not in result.model.uncertainty
    assert f"rest_length[{topo.springs[0].name}]" in result.model.uncertainty
    assert f"| rest_length[{name}] | {longest:.6g} |" in slack_markdown(result.model, notes)
