"""Candidates fitted side by side in forked workers score as fitted one after the other."""

from __future__ import annotations

import os
from functools import partial

import numpy as np
import pytest

from identification.discovery.library import Proposal
from identification.discovery.loop import EffectDiscovery
from identification.discovery.multi_step import MultiStepScorer
from identification.discovery.scorer import CandidateSkipped
from identification.discovery.side_by_side import fit_side_by_side
from identification.simulation.planted import PlantSpec, planted_dataset
from identification.trajectory.end_cap_data import TrajectorySettings
from identification.trajectory.forked import side_by_side
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import CubicStiffness, ForceField, LinearDrag

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _loop(jobs: int):
    """Linear drag (strong, 1 mm noise) against two candidates, from the true declared model;
    two iterations per fit: the serial and forked fits are equal at any count."""
    d = planted_dataset(PlantSpec("linear_drag", "strong", noise=0.001, seed=41, n_train=2,
                                  n_val=1, n_test=1, steps=200))  # fmt: skip
    s = TrajectorySettings(anchors={"mass[rod0]": float(d.ground_truth.params.mass[0])},
                           train_windows=4, val_windows=4, test_windows=4, base_iter=2,
                           candidate_iter=2, state_iter=3, final_iter=2, seed=41)  # fmt: skip
    scorer = MultiStepScorer(s, horizon_s=0.3, start=d.ground_truth.params)
    loop = EffectDiscovery(scorer, 1, ["linear_drag", "force_field"], log=lambda m: None,
                           jobs=jobs)  # fmt: skip
    with np.errstate(invalid="ignore", divide="ignore"):
        return loop.fit(d.dataset).result_


def test_candidates_fitted_in_workers_match_the_serial_fits() -> None:
    serial, forked = _loop(1), _loop(2)
    assert serial.model.names == forked.model.names == ["linear_drag"]
    one, two = serial.iterations[0], forked.iterations[0]
    assert [c.name for c in one.candidates] == [c.name for c in two.candidates]
    for a, b in zip(one.candidates, two.candidates, strict=True):
        assert b.gain == pytest.approx(a.gain, rel=1e-9)
        assert b.bic == pytest.approx(a.bic, rel=1e-12)
        assert b.seconds > 0  # timed in the worker
    drags = [next(e for e in r.model.effects if e.name == "linear_drag") for r in (serial, forked)]
    np.testing.assert_allclose(drags[1].theta().numpy(), drags[0].theta().numpy(), rtol=1e-9)


def _refuse_odd(p: Proposal):
    if p.name.endswith("1"):
        raise CandidateSkipped(f"{p.name} {os.getpid()}")
    raise ValueError(f"{p.name} {os.getpid()}")


def test_refusals_come_back_in_order_from_the_workers() -> None:
    proposals = [Proposal(f"p{i}", None, "") for i in range(3)]
    out = fit_side_by_side(_refuse_odd, proposals, jobs=2)
    assert [type(e) for e in out] == [ValueError, CandidateSkipped, ValueError]
    names, pids = zip(*(str(e).split() for e in out), strict=True)
    assert names == ("p0", "p1", "p2")
    assert str(os.getpid()) not in pids  # fitted in worker processes


def test_cli_rejects_jobs_below_one(tmp_path, capsys) -> None:
    from tensegrity_sr.cli import main as cli

    path = tmp_path / "noisy.h5"
    cli(["plant", "none", "--noise", "0.001", "--n-train", "1", "--n-val", "1", "--n-test", "1",
         "--steps", "50", "-o", str(path)])  # fmt: skip
    capsys.readouterr()
    assert cli(["diagnose", str(path), "--jobs", "0", "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "--jobs" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()  # refused before any work


def _square_in(i: int) -> tuple[int, int]:
    if i < 0:
        raise ValueError(f"negative {i}")
    return i * i, os.getpid()


def test_tasks_come_back_in_order_from_the_workers_and_their_errors_are_raised() -> None:
    out = side_by_side([partial(_square_in, i) for i in range(3)], jobs=2)
    assert [v for v, _ in out] == [0, 1, 4]
    assert os.getpid() not in {pid for _, pid in out}
    assert [v for v, _ in side_by_side([partial(_square_in, 3)], jobs=2)] == [9]  # one: here
    with pytest.raises(ValueError, match="negative -1"):
        side_by_side([partial(_square_in, 1), partial(_square_in, -1)], jobs=2)


def test_the_dearest_candidates_are_fitted_first_and_come_back_in_order() -> None:
    topo = icosahedron().topology
    proposals = [Proposal("force_field", ForceField(topo), ""),
                 Proposal("cubic_stiffness", CubicStiffness(topo), ""),
                 Proposal("skipped", None, "gate not passed"),
                 Proposal("linear_drag", LinearDrag(topo), ""),
                 Proposal("slack_springs", None, "", start={"springs": np.array([3])})]  # fmt: skip
    ran: list[str] = []

    def fit(p: Proposal):
        ran.append(p.name)
        raise CandidateSkipped(p.name)

    out = fit_side_by_side(fit, proposals, jobs=1)
    assert ran == ["slack_springs", "cubic_stiffness", "linear_drag", "force_field", "skipped"]
    assert [str(e) for e in out] == [p.name for p in proposals]
