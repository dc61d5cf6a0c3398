"""The open-loop check before ``identify`` and ``diagnose`` write a model: a model that
leaves the data when rolled out from measured states is never written silently."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import Cell, write_cell

from tensegrity_sr.cli import main as cli

#: stiffness times this: a spring-mass frequency far beyond what a 1 ms physics step
#: integrates (0.1 kg rods, springs of 1e3 N/m: omega ~ 1e5 rad/s)
BLOW_UP = 1e6


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """A small free-flight take at 120 Hz with 0.1 mm of noise, and its true parameters."""
    return write_cell(Cell("flight", 120.0, 1e-4, 0.0, "none"), tmp_path_factory.mktemp("cell"))


def test_the_true_model_passes_and_a_blowing_up_one_is_flagged(cell) -> None:
    from identification.data.dataset import read_dataset
    from identification.trajectory.open_loop_check import NOISE_LEVELS, open_loop_check
    from tensegrity_env.model import Model

    ds = read_dataset(cell.measured)
    p = cell.truth.params
    good = open_loop_check(Model(ds.topology, p, dt=ds.dt), ds, 1e-4, 1e-3)
    assert good is not None and not good.diverged
    assert good.splits == ("val", "test") and good.starts > 0 and good.non_finite == 0
    # the limit is the data's extent (a thrown robot: metres), far above the true model's error
    assert good.limit_m == max(good.extent_m, NOISE_LEVELS * 1e-4) and good.extent_m > 0.5
    assert good.worst_rms_m < 0.1 * good.limit_m
    bad = open_loop_check(Model(ds.topology, replace(p, stiffness=p.stiffness * BLOW_UP), dt=ds.dt),
                          ds, 1e-4, 1e-3)  # fmt: skip
    assert bad is not None and bad.diverged and bad.non_finite > 0
    assert "non-finite end caps" in bad.line() and "limit" in bad.line()


def test_a_model_further_off_than_the_data_spans_has_diverged() -> None:
    from identification.trajectory.open_loop_check import OpenLoopCheck

    def check(worst: float) -> OpenLoopCheck:
        return OpenLoopCheck(("val",), 4, 1.0, worst, 0.5, 0.6, 0.6, 1e-4)

    assert not check(0.59).diverged and check(0.61).diverged


def test_identify_writes_nothing_for_a_fit_that_diverges_open_loop(
    cell, tmp_path, capsys, monkeypatch
) -> None:
    """The fit's own windows (a fitted initial state each) can look fine while the model
    blows up from a measured state: here the fit reports 0.1 mm on its windows."""
    from identification.commands import identify_end_caps

    stiff = replace(cell.truth.params, stiffness=cell.truth.params.stiffness * BLOW_UP)

    class Fit:
        def __init__(self, **kwargs) -> None:
            pass

        def fit(self, dataset, split):
            return SimpleNamespace(params_=stiff, rms_=1e-4, mode_="absolute", notes_={}, stderr_={},
                                   topology_=dataset.topology, converged_=True, stages_=[])  # fmt: skip

    monkeypatch.setattr(identify_end_caps, "TrajectoryIdentifier", Fit)
    out = tmp_path / "p.json"
    assert cli(["identify", str(cell.measured), "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("error: the trajectory fit failed: the model diverges open-loop")
    assert "non-finite end caps" in err and "nothing written" in err
    assert not out.exists()


def _result(models):
    """A DiscoveryResult whose final model is ``models[0]``, the others earlier (newest first)."""
    from identification.discovery.judge import Candidate, Criteria
    from identification.discovery.loop import DiscoveryResult
    from identification.trajectory.fitted_model import FittedModel

    fitted = [FittedModel(m, 0) for m in models]
    cands = [Candidate("nothing", None, f) for f in fitted[1:]]
    return DiscoveryResult(method="multi_step", description="", iterations=[], model=fitted[0],
                           baseline_test={}, final_test={"before": 1.0}, test_labels={},
                           criteria=Criteria("held-out error", 0.1, True, 0.0), final_residual=None,  # type: ignore[arg-type]
                           earlier=cands)  # fmt: skip


class Scorer:
    noise = 1e-4

    def test_errors(self, cand):
        return {"scored_again": 1.0}


def test_diagnose_falls_back_to_the_last_model_that_does_not_diverge(cell, capsys) -> None:
    from identification.data.dataset import read_dataset
    from identification.discovery.open_loop import keep_not_diverged
    from tensegrity_env.model import Model

    ds = read_dataset(cell.measured)
    p = cell.truth.params
    good = Model(ds.topology, p, dt=ds.dt)
    bad = Model(ds.topology, replace(p, stiffness=p.stiffness * BLOW_UP), dt=ds.dt)
    kept = keep_not_diverged(_result([good, bad]), Scorer(), ds, 1e-3)
    assert kept.model.model is good and kept.final_test == {"before": 1.0}
    assert kept.open_loop.startswith("The final model rolled out: open-loop check")
    out = keep_not_diverged(_result([bad, bad, good]), Scorer(), ds, 1e-3)
    assert out.model.model is good and out.final_test == {"scored_again": 1.0}
    assert "diverges open-loop" in out.open_loop and "the declared model's fit" in out.open_loop
    assert "written instead is the last model that does not" in capsys.readouterr().out


def test_diagnose_refuses_when_every_model_diverges(cell) -> None:
    from identification.data.dataset import read_dataset
    from identification.discovery.open_loop import keep_not_diverged
    from tensegrity_env.io_utils import StageError
    from tensegrity_env.model import Model

    ds = read_dataset(cell.measured)
    p = cell.truth.params
    bad = Model(ds.topology, replace(p, stiffness=p.stiffness * BLOW_UP), dt=ds.dt)
    with pytest.raises(
        StageError, match=r"diagnose's models .* failed: the model diverges open-loop"
    ):
        keep_not_diverged(_result([bad, bad]), Scorer(), ds, 1e-3)


def test_the_check_skips_data_without_a_start() -> None:
    from identification.data.dataset import Dataset, Split
    from identification.trajectory.open_loop_check import open_loop_check
    from tensegrity_env.assemblies import icosahedron
    from tensegrity_env.model import Model

    asm = icosahedron()
    nodes = np.full((1, 3, 12, 3), np.nan)
    ds = Dataset(
        asm.topology, 1 / 120, {"train": Split(nodes=nodes, control=np.zeros((1, 2, 6, 3)))}
    )
    assert open_loop_check(Model(asm.topology, asm.params, dt=ds.dt), ds, 1e-4) is None


def test_worse_prediction_names_the_horizons_beyond_the_noise() -> None:
    from identification.trajectory.open_loop_check import OpenLoopCheck, worse_prediction

    dt = 0.05  # horizons 0.1, 0.25, 0.5, 1 s at steps 2, 5, 10, 20

    def check(rms: list[float]) -> OpenLoopCheck:
        return OpenLoopCheck(("val",), 4, 1.0, max(rms), 1.0, 1.0, 1.0, 1e-4, 0, tuple(rms), dt)

    old = check([1e-3] * 20)
    assert check([1e-3] * 20).at() == [1e-3] * 4
    assert worse_prediction(check([1.05e-3] * 20), old) == ""  # within the noise level
    better_early = check([5e-4] * 4 + [3e-3] * 16)  # better at 0.1 s, worse from 0.25 s on
    why = worse_prediction(better_early, old)
    assert why.startswith("end-cap RMS at 0.25 s 3 mm against 1 mm") and "0.1 s" not in why
    assert "1 s 3 mm" in why and "'val'" in why
    assert check([1e-3] * 8).at() == [1e-3, 1e-3, None, None]  # shorter rollouts: no value


@pytest.fixture(scope="module")
def models(cell):
    """The cell's dataset, its true model and one with springs 40 % stiffer (it stays with
    the data, further off the longer it is rolled out)."""
    from identification.data.dataset import read_dataset
    from tensegrity_env.model import Model

    ds = read_dataset(cell.measured)
    p = cell.truth.params
    return (
        ds,
        Model(ds.topology, p, dt=ds.dt),
        Model(ds.topology, replace(p, stiffness=p.stiffness * 1.4), dt=ds.dt),
    )


def test_diagnose_keeps_an_addition_only_where_held_out_prediction_does_not_get_worse(
    models, capsys
) -> None:
    from identification.discovery.open_loop import keep_predicting
    from identification.trajectory.open_loop_check import open_loop_check

    ds, good, off = models
    a, b = (
        open_loop_check(off, ds, 1e-4, 1e-3, ("val",)),
        open_loop_check(good, ds, 1e-4, 1e-3, ("val",)),
    )
    assert a is not None and b is not None and not a.diverged  # a poor model, not a diverged one
    assert a.at()[2] > 1.5 * b.at()[2]  # at 0.5 s (the held-out pieces are 0.6 s long)
    # the final model (with an effect) predicts worse than the declared fit: the declared one is written
    out = keep_predicting(_result([off, good]), Scorer(), ds, 1e-3)
    assert out.model.model is good and out.final_test == {"scored_again": 1.0}
    assert "predicts worse than the declared model's fit (no effects)" in out.open_loop
    assert out.open_loop.startswith("Written instead of the final model (no effects): the declared")
    assert "Written instead of" in capsys.readouterr().out
    # one that predicts better is kept as it is
    kept = keep_predicting(_result([good, off]), Scorer(), ds, 1e-3)
    assert kept.model.model is good and kept.final_test == {"before": 1.0} and kept.open_loop == ""
    # the newest model no worse than the one kept before it: declared (off) -> good -> off again
    out = keep_predicting(_result([off, good, off]), Scorer(), ds, 1e-3)
    assert out.model.model is good


def test_the_loop_refuses_a_refit_that_predicts_held_out_motion_worse(models) -> None:
    from identification.discovery.multi_step import MultiStepScorer

    ds, good, off = models
    scorer = SimpleNamespace(dataset=ds, noise=1e-4, settings=SimpleNamespace(physics_dt=1e-3))

    def cand(m):
        return SimpleNamespace(model=SimpleNamespace(model=m))

    why = MultiStepScorer.predicts_worse(scorer, cand(off), cand(good))  # type: ignore[arg-type]
    assert why.startswith("predicts held-out motion worse than the current model (end-cap RMS at")
    assert MultiStepScorer.predicts_worse(scorer, cand(good), cand(off)) == ""  # type: ignore[arg-type]


def test_recorded_rod_states_start_the_check_where_end_caps_cannot(tmp_path: Path) -> None:
    """The lab prism's cables attach off its rods' axes: two end caps do not give a rod's
    twist, but the recorded rod states do; the true model stays with the data from them."""
    from identification.data.dataset import read_dataset, read_ground_truth
    from identification.trajectory.open_loop_check import open_loop_check
    from tensegrity_env.model import Model

    robot = Path(__file__).resolve().parents[2] / "tensegrity_env" / "assets" / "lab_prism_force_actuators.xml"
    path = tmp_path / "lab.h5"
    assert cli(["generate", "--mjcf", str(robot), "--n-train", "1", "--n-val", "1", "--n-test", "1",
                "--steps", "300", "--seed", "3", "--control-std", "1", "--no-progress",
                "-o", str(path)]) == 0  # fmt: skip
    ds = read_dataset(path)
    assert ds.topology.off_axis_points() and ds.split("val").has_states
    truth = read_ground_truth(path)
    assert truth is not None
    model = Model.read(robot, dt=ds.dt)
    check = open_loop_check(Model(ds.topology, truth.params, model.effects, dt=ds.dt), ds, 1e-4)
    assert check is not None and check.starts > 0 and not check.diverged
    # the true model from the true states, well inside the limit (not at round-off: the
    # actuators' filter state at a start is not in the data and starts at rest)
    assert check.worst_rms_m < 0.1 * check.limit_m


def test_a_model_outside_the_physical_domain_is_never_kept(models) -> None:
    """An earlier model of the loop whose inertias break the triangle inequality predicts
    no worse, but is no rod: neither fallback keeps it."""
    from identification.discovery.open_loop import keep_not_diverged, keep_predicting
    from tensegrity_env.model import Model

    ds, good, off = models
    p = good.params
    inertia = p.inertia.clone()
    inertia[0] = inertia[0, 0] * inertia.new_tensor([1.0, 1.0, 3.0])  # I3 > I1 + I2
    unphysical = Model(ds.topology, replace(p, inertia=inertia), dt=ds.dt)
    # the final model (off) predicts worse than the declared one, which is not physical
    out = keep_predicting(_result([off, unphysical]), Scorer(), ds, 1e-3)
    assert out.model.model is off
    bad = Model(ds.topology, replace(p, stiffness=p.stiffness * BLOW_UP), dt=ds.dt)
    out = keep_not_diverged(_result([bad, unphysical, good]), Scorer(), ds, 1e-3)
    assert out.model.model is good


def test_a_fit_that_predicts_worse_than_its_start_at_every_horizon_is_not_written(cell) -> None:
    """The true model against a start model with springs at a third of the truth: the
    truth passes against it; that start, as a fit against the truth, is refused naming
    the horizons; a model that is worse only at some horizons is not judged here."""
    from identification.data.dataset import read_dataset
    from identification.trajectory.open_loop_check import (
        HORIZONS_S,
        check_not_worse_than_start,
        open_loop_check,
    )
    from tensegrity_env.io_utils import StageError
    from tensegrity_env.model import Model

    ds = read_dataset(cell.measured)
    p = cell.truth.params
    truth = Model(ds.topology, p, dt=ds.dt)
    soft = Model(ds.topology, replace(p, stiffness=p.stiffness / 3), dt=ds.dt)
    start_check = check_not_worse_than_start("fit", truth, soft, ds, 1e-4, 1e-3)
    assert start_check is not None and start_check.splits == ("val",)  # the test split unseen
    with pytest.raises(StageError) as e:
        check_not_worse_than_start("fit", soft, truth, ds, 1e-4, 1e-3)
    assert "predicts worse than the start model at every horizon" in str(e.value)
    reached = [h for h, x in zip(HORIZONS_S, open_loop_check(truth, ds, 1e-4, 1e-3, ("val",)).at(),
                                  strict=True) if x is not None]  # fmt: skip
    assert len(reached) >= 3 and all(f"at {h:g} s" in str(e.value) or f", {h:g} s" in str(e.value)
                                     for h in reached)  # fmt: skip
    assert check_not_worse_than_start("fit", soft, None, ds, 1e-4, 1e-3) is None
    # the soft model's errors as the truth's: within the noise of each other, so not worse
    same = open_loop_check(soft, ds, 1e-4, 1e-3, ("val",))
    assert same is not None and all(x is None or x > 1e-3 for x in same.at())
    assert check_not_worse_than_start("fit", soft, soft, ds, 1e-4, 1e-3) is not None
