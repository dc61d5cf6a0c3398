"""Options reach the code they name: each changes what runs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import clean_rolling
from plant_family import draw, family_initial_states, simulate_family, truth_of

from identification.commands.diagnose import multi_step_scorer
from identification.data.end_caps import dataset_from_end_caps
from identification.trajectory.floor_declared import floor_steps, on_floor
from identification.trajectory.identifier import TrajectoryIdentifier
from tensegrity_env.assemblies import icosahedron
from tensegrity_sr.cli import build_parser


@pytest.mark.parametrize("command", ["identify", "diagnose"])
def test_the_model_to_start_from_is_params_in_both_commands(command: str, capsys) -> None:
    parser = build_parser()
    new = parser.parse_args([command, "d.h5", "--params", "m.xml"])
    old = parser.parse_args([command, "d.h5", "--init", "m.xml"])
    assert new.params == old.params == Path("m.xml")
    with pytest.raises(SystemExit):
        parser.parse_args([command, "--help"])
    text = capsys.readouterr().out
    assert "--params" in text and "--init" not in text


def test_a_start_replaces_the_regression_where_the_trajectory_fit_begins() -> None:
    d = draw(1, "flight", rate=120.0)
    truth, topo = truth_of(d)
    clean = simulate_family(d, truth.xml, family_initial_states(d, 2, np.random.default_rng(0)), 0.3)
    noisy = clean.nodes + np.random.default_rng(1).normal(0.0, 1e-3, clean.nodes.shape)
    ds = dataset_from_end_caps(topo, 1 / d.rate, {"train": noisy})
    anchors = {"mass[rod0]": float(truth.params.mass[0])}
    kw = {"anchors": anchors, "max_iter": 0, "window": 12, "first_window": 12}
    given = TrajectoryIdentifier(start=truth.params, **kw).fit(ds).initial_params_.numpy()
    regressed = TrajectoryIdentifier(**kw).fit(ds).initial_params_.numpy()
    t = truth.params.numpy()
    for group in ("mass", "stiffness", "damping", "rest_length"):
        np.testing.assert_allclose(given[group], t[group], rtol=1e-12, err_msg=group)
    assert np.abs(regressed["stiffness"] / t["stiffness"] - 1).max() > 1e-3


@pytest.fixture(scope="module")
def floor_data():
    _, split = clean_rolling(0, duration=2.0)
    nodes = split.nodes + np.random.default_rng(2).normal(0.0, 1e-3, split.nodes.shape)
    ds = dataset_from_end_caps(icosahedron().topology, 1 / 120, {"train": nodes})
    assert on_floor(ds)
    return ds


def test_diagnose_window_reaches_the_floor_fits_and_the_header_prints_them(floor_data, capsys):
    parser = build_parser()
    default = multi_step_scorer(parser.parse_args(["diagnose", "d.h5"]), floor_data)
    head = capsys.readouterr().out
    assert floor_steps(floor_data.dt, default.settings) == 30  # 0.25 s, below --fit-window
    assert "on the floor: windows of up to 0.25 s (30 samples at 120 Hz)" in head
    for span, steps in (("0.1s", 12), ("0.05s", 6)):
        args = parser.parse_args(["diagnose", "d.h5", "--window", span])
        scorer = multi_step_scorer(args, floor_data)
        head = capsys.readouterr().out
        assert floor_steps(floor_data.dt, scorer.settings) == steps
        assert f"on the floor: windows of {span[:-1]} s ({steps} samples at 120 Hz)" in head


class Stop(Exception):
    """Raised where the fit would start: the header has been printed."""


@pytest.mark.parametrize(("extra", "span"), [((), "0.25 s (30 samples"),
                                             (("--window", "0.1s"), "0.1 s (12 samples")])
def test_identify_prints_the_floor_windows_it_fits_on(floor_data, tmp_path, capsys, monkeypatch,
                                                      extra, span):
    import identification.commands.identify_end_caps as command
    from identification.data.dataset import write_dataset
    from tensegrity_sr.cli import main

    seen = {}

    def stop(dataset, settings, split, **kw):
        seen["steps"] = floor_steps(dataset.dt, settings)
        raise Stop

    monkeypatch.setattr(command, "identify_on_floor", stop)
    path = write_dataset(tmp_path / "floor.h5", floor_data)
    with pytest.raises(Stop):
        main(["identify", str(path), "-o", str(tmp_path / "p.json"), *extra])
    head = capsys.readouterr().out
    assert f"ground contact fitted on 8 or more windows of up to {span} at 120 Hz)" in head, head
    assert seen["steps"] == int(span.split("(")[1].split()[0])


@pytest.mark.parametrize(("effort", "factor"), [("quick", 0.5), ("thorough", 2.0)])
def test_diagnose_effort_scales_the_fits_windows_and_iterations(floor_data, capsys, effort,
                                                                 factor):  # fmt: skip
    parser = build_parser()
    default = multi_step_scorer(parser.parse_args(["diagnose", "d.h5"]), floor_data).settings
    chosen = multi_step_scorer(parser.parse_args(["diagnose", "d.h5", "--effort", effort]),
                               floor_data).settings  # fmt: skip
    assert f"effort {effort}: windows {round(8 * factor)}" in capsys.readouterr().out
    for key in ("train_windows", "fit_windows", "floor_windows", "final_floor_windows",
                "final_iter"):  # fmt: skip
        assert getattr(chosen, key) == round(factor * getattr(default, key)), key
    assert default.second_start and chosen.second_start == (effort != "quick")  # floor: one start
    # an old per-knob option, hidden from --help, still replaces its preset value
    old = parser.parse_args(["diagnose", "d.h5", "--effort", effort, "--floor-windows", "5"])
    assert multi_step_scorer(old, floor_data).settings.floor_windows == 5


@pytest.mark.parametrize("effort", ["quick", "thorough"])
def test_identify_effort_reaches_the_floor_fit(floor_data, tmp_path, capsys, monkeypatch,
                                               effort):  # fmt: skip
    import identification.commands.identify_end_caps as command
    from identification.data.dataset import write_dataset
    from tensegrity_sr.cli import main

    seen = {}

    def stop(dataset, settings, split, **kw):
        seen["windows"] = settings.floor_windows
        seen["two starts"] = settings.second_start
        raise Stop

    monkeypatch.setattr(command, "identify_on_floor", stop)
    path = write_dataset(tmp_path / "floor.h5", floor_data)
    with pytest.raises(Stop):
        main(["identify", str(path), "-o", str(tmp_path / "p.json"), "--effort", effort])
    assert f"effort {effort}" in capsys.readouterr().out
    assert seen["windows"] == {"quick": 4, "thorough": 16}[effort]
    assert seen["two starts"] == (effort != "quick")  # quick: the floor fit from one start


def test_identify_effort_reaches_the_free_flight_fit(monkeypatch) -> None:
    import identification.commands.identify_end_caps as command

    seen = {}

    class Stop2(Exception):
        pass

    class Probe:
        def __init__(self, **kw):
            seen.update(kw)
            raise Stop2

    monkeypatch.setattr(command, "TrajectoryIdentifier", Probe)
    d = draw(1, "flight", rate=120.0)
    truth, topo = truth_of(d)
    clean = simulate_family(d, truth.xml, family_initial_states(d, 1, np.random.default_rng(0)), 0.3)
    ds = dataset_from_end_caps(topo, 1 / d.rate, {"train": clean.nodes})
    parser = build_parser()
    for effort, iters in (("quick", 10), ("thorough", 40)):
        args = parser.parse_args(["identify", "d.h5", "--effort", effort])
        from identification.commands.effort import apply_effort

        args.max_iter = apply_effort(args)["max_iter"]
        args.first_window = 0.1
        with pytest.raises(Stop2):
            command.run_end_caps(args, ds, {})
        assert seen["max_iter"] == iters
