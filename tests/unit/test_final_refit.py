"""The final refit replaces the model only where it stays as well pinned as the last fit."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from identification.discovery import multi_step, refits
from identification.discovery.candidate_fits import EndCapFits
from identification.discovery.judge import Candidate
from identification.discovery.library import Proposal
from identification.discovery.multi_step import MultiStepScorer
from identification.trajectory.end_cap_data import TrajectorySettings
from tensegrity_env.effects import GroundContact


def _effect(name: str) -> SimpleNamespace:
    """A stand-in effect: its name, and that it is no constraint (not the contact)."""
    return SimpleNamespace(name=name, constraint=False)


def _scorer(
    refit_stderr: np.ndarray, monkeypatch: pytest.MonkeyPatch, lines: list[str], step: float = 0.1
):
    refitted = SimpleNamespace(
        rms=1.0e-3, stderr=refit_stderr, windows=SimpleNamespace(size=24), iterations=20,
        converged=False,
        fitted_model=lambda topology, dt: "refitted model",
        theta=torch.tensor([0.5, -0.2 + step, 1.0], dtype=torch.float64),
    )  # fmt: skip
    monkeypatch.setattr(refits, "refit_many", lambda *a, **k: refitted)
    monkeypatch.setattr(refits, "unphysical", lambda model: "")
    scorer = MultiStepScorer(TrajectorySettings())
    scorer.data, scorer.noise, scorer.log = None, 1.0e-3, lines.append
    scorer.dataset = SimpleNamespace(topology=None, dt=1 / 120)
    last = SimpleNamespace(vec=None, theta=torch.tensor([0.5, -0.2, 1.0], dtype=torch.float64),
                           stderr=np.array([0.01, 0.02, np.inf]))  # fmt: skip
    current = Candidate("nothing", EndCapFits(last, last), "model")
    return scorer, current


@pytest.mark.parametrize(
    ("stderr", "kept"),
    [
        (np.array([0.01, 0.02, np.inf]), True),  # the same directions pinned
        (np.array([0.01, np.inf, np.inf]), False),  # one the last fit pinned is lost
    ],
)
def test_a_refit_that_loses_a_standard_error_is_not_used(stderr, kept, monkeypatch) -> None:
    lines: list[str] = []
    scorer, current = _scorer(stderr, monkeypatch, lines)
    windows = SimpleNamespace(steps=30)
    out = refits.refit(scorer, current, windows)
    assert (out.model == "refitted model") is kept
    assert (out is current) is not kept
    assert ("1 standard errors the last fit pinned are infinite" in lines[-1]) is not kept


def test_the_final_refit_stops_once_its_error_stops_falling(monkeypatch) -> None:
    """The final refit asks its joint fit to stop on :data:`refits.FINAL_STALL` (the rule
    itself: ``test_windowed_problem.py``)."""
    asked: list[dict] = []
    lines: list[str] = []
    scorer, current = _scorer(np.array([0.01, 0.02, np.inf]), monkeypatch, lines)
    done = refits.refit_many.__call__  # the stand-in _scorer put there
    monkeypatch.setattr(refits, "refit_many", lambda *a, **k: asked.append(k) or done())
    refits.refit(scorer, current, SimpleNamespace(steps=30))
    assert asked[0]["stall"] == refits.FINAL_STALL == 1.0
    assert asked[0]["bar"] == "final refit"


@pytest.mark.parametrize(("step", "stayed"), [(0.1, False), (1e-12, True)])
def test_a_refit_whose_parameters_did_not_move_says_so(step, stayed, monkeypatch) -> None:
    lines: list[str] = []
    scorer, current = _scorer(np.array([0.01, 0.02, np.inf]), monkeypatch, lines, step)
    out = refits.refit(scorer, current, SimpleNamespace(steps=30))
    assert out.model == "refitted model"  # kept either way: the same model, more windows
    assert ("its parameters stayed at the last fit's" in lines[-1]) is stayed
    assert "(20 iterations, ran out;" in lines[-1]


@pytest.mark.parametrize(("final_windows", "refitted"), [(24, True), (8, False)])
def test_on_the_floor_the_final_refit_takes_more_floor_windows_than_selection(
    final_windows, refitted, monkeypatch
) -> None:
    scorer = MultiStepScorer(TrajectorySettings(floor_windows=8, final_floor_windows=final_windows))
    cuts: list[tuple] = []
    scorer.data = SimpleNamespace(
        on_floor=True, dt=1 / 120, floor_steps=None,
        cut=lambda *a, **k: cuts.append((a, k)) or SimpleNamespace(steps=a[1]),
    )  # fmt: skip
    scorer.noise = 1.0e-3
    monkeypatch.setattr(refits, "refit", lambda scorer, current, windows, within: (
        "refitted", windows.steps, within))  # fmt: skip
    out = scorer.finish("current")
    if refitted:
        (name, steps, count, _), kw = cuts[0]
        assert (name, count, kw["lift_off"]) == ("train", 24, 12)
        assert out[:2] == ("refitted", steps) and steps == 30  # at most 0.25 s at 120 Hz
        assert out[2] == pytest.approx(1.5e-3)  # windows stuck above 1.5x the noise left out
    else:
        assert out == "current" and not cuts


def test_the_joint_refit_gets_only_the_windows_within_the_given_rms(monkeypatch) -> None:
    """``refit_many(within=...)`` fits the states, then hands the joint fit only the windows
    ``windows_within`` kept; without ``within`` every window."""
    from identification.trajectory import presets

    passed: list = []
    fitted = SimpleNamespace(theta="theta", origin=None)
    monkeypatch.setattr(presets, "fit_states",
                        lambda *a, **k: SimpleNamespace(windows="states fitted"))  # fmt: skip
    monkeypatch.setattr(presets, "windows_within",
                        lambda eng, vec, w, theta, rms: (SimpleNamespace(size=20, of=(w, rms)),
                                                         np.ones(24)))  # fmt: skip
    monkeypatch.setattr(presets, "fit_trajectory",
                        lambda data, vec, w, theta, iters, progress=None, stall=None:
                        passed.append(w) or fitted)  # fmt: skip
    monkeypatch.setattr(presets, "sees_roll", lambda engine: False)
    data = SimpleNamespace(engine=None, spin=True, roll=False, log=lambda line: None)
    vec = SimpleNamespace(engine=lambda engine, theta: "engine",
                          held_at=lambda theta: SimpleNamespace(theta0=lambda: 0))
    theta = SimpleNamespace(detach=lambda: theta)
    s = TrajectorySettings()
    presets.refit_many(data, vec, theta, s, 20, windows="windows", within=1.5e-3)
    presets.refit_many(data, vec, theta, s, 20, windows="windows")
    assert passed[0].of == ("states fitted", 1.5e-3) and passed[1] == "states fitted"


def test_on_the_floor_slack_cables_are_fitted_afresh_from_their_regression(monkeypatch) -> None:
    """A cable hypothesis on the floor: one floor fit from the segmented regression's
    values and the current contact, the current cables (and dropped effects) replaced,
    not adopted by the data; then the selection windows from the current model's fitted
    states."""
    calls: dict = {}

    def fake_floor_fit(data, s, start, effects, values=None, contact=None):
        calls["floor"] = ([e.name for e in effects], values, contact)
        return SimpleNamespace(fit=SimpleNamespace(vec="floor vec", theta="floor theta"))

    def fake_fit_trajectory(data, vec, windows, theta, iters):
        calls["trajectory"] = (vec, windows, theta)
        return SimpleNamespace(origin=None)

    monkeypatch.setattr(multi_step, "floor_fit", fake_floor_fit)
    monkeypatch.setattr(multi_step, "fit_trajectory", fake_fit_trajectory)
    monkeypatch.setattr(refits, "adopt_floor_fit",
                        lambda *a: pytest.fail("a candidate's floor fit was adopted"))  # fmt: skip
    scorer = MultiStepScorer(TrajectorySettings())
    scorer.data = SimpleNamespace(on_floor=True)
    scorer.start = scorer.contact = None
    monkeypatch.setattr(scorer, "score_candidate",
                        lambda name, fit, current, floor: (name, fit, floor))  # fmt: skip
    contact = GroundContact.__new__(GroundContact)  # (only its type is looked at)
    now = SimpleNamespace(
        effects=[contact, *map(_effect, ("slack_springs", "linear_drag", "force_field"))],
        start_effects=[], windows="current states",
    )  # fmt: skip
    current = Candidate("nothing", EndCapFits(now, now), "model")
    proposal = Proposal("slack_springs", _effect("slack_springs"), "gate", start={"k": "regressed"})
    name, fit, floor = scorer.fit_candidate(current, proposal, drop=("force_field",))
    assert calls["floor"] == (["linear_drag", "slack_springs"], {"k": "regressed"}, contact)
    assert calls["trajectory"] == ("floor vec", "current states", "floor theta")
    assert name == "slack_springs" and fit.origin == "floor theta" and floor is not None


def _trajfit(rms: float, converged: bool) -> SimpleNamespace:
    m = 1000
    return SimpleNamespace(vec="vec", theta=rms, windows="windows", sse=rms**2 * m, m=m,
                           rms=rms, converged=converged, origin=None)  # fmt: skip


@pytest.mark.parametrize(
    ("rms", "converged", "rounds", "expected"),
    [
        ([1.34e-3, 1.20e-3, 1.12e-3], False, 2, 1.12e-3),  # two more rounds, both paying
        ([1.34e-3, 1.20e-3, 1.05e-3, 1.0e-3], False, 2, 1.05e-3),  # at most MORE_ROUNDS
        ([1.34e-3, 1.338e-3], False, 1, 1.338e-3),  # < 1 % of the SSE: stops, keeps the lower
        ([1.34e-3, 1.35e-3], False, 1, 1.34e-3),  # a round that rose is not used
        ([1.34e-3], True, 0, 1.34e-3),  # the last fit met its stopping rule
        ([1.08e-3], False, 0, 1.08e-3),  # within FIT_WELL times the noise
    ],
)
def test_an_accepted_floor_refit_goes_on_only_while_it_is_short_of_the_data(
    rms, converged, rounds, expected, monkeypatch
) -> None:
    fits = iter([_trajfit(r, False) for r in rms[1:]])
    calls: list = []

    def fake_fit_trajectory(data, vec, windows, theta, iters):
        calls.append((vec, windows, theta, iters))
        return next(fits)

    monkeypatch.setattr(refits, "fit_trajectory", fake_fit_trajectory)
    scorer = MultiStepScorer(TrajectorySettings(base_iter=10))
    scorer.data, scorer.noise, scorer.log = None, 1.0e-3, lambda line: None
    out = refits.fitted_on(scorer, _trajfit(rms[0], converged))
    assert len(calls) == rounds
    assert out.rms == pytest.approx(expected)
    assert all(c[3] == 10 for c in calls) and (not calls or calls[0][2] == rms[0])


@pytest.mark.parametrize(
    ("on_floor", "m_added", "rms_added", "refused"),
    [
        (True, 1000, 1.074e-3, True),  # worse than the current model on the same windows
        (True, 1000, 1.030e-3, False),
        (True, 900, 1.074e-3, False),  # other windows: not comparable
        (False, 1000, 1.074e-3, False),  # in flight the check is not made
    ],
)
def test_an_accepted_floor_refit_worse_than_the_current_model_is_refused(
    on_floor, m_added, rms_added, refused
) -> None:
    scorer = MultiStepScorer(TrajectorySettings())
    scorer.data = SimpleNamespace(on_floor=on_floor, windows={"fit": "before"},
                                  contact_box=None, roll=False)  # fmt: skip
    scorer.dataset = SimpleNamespace(splits={})  # no validation split: no open-loop comparison
    before = _trajfit(1.039e-3, True)
    added = replace_rms(_trajfit(rms_added, True), m_added)
    reason = scorer.refusal(Candidate("quadratic_drag", EndCapFits(added, added), "model"),
                            Candidate("nothing", EndCapFits(before, before), "model"))  # fmt: skip
    assert bool(reason) is refused
    if refused:
        assert "worse than the current model (end-cap RMS 1.074 mm against 1.039 mm)" in reason


def replace_rms(fit: SimpleNamespace, m: int) -> SimpleNamespace:
    fit.sse, fit.m = fit.rms**2 * m, m
    return fit


def test_an_overruled_accept_leaves_the_data_as_before() -> None:
    scorer = MultiStepScorer(TrajectorySettings())
    data = SimpleNamespace(windows={"fit": "before", "train": "train"}, contact_box=None,
                           roll=False)  # fmt: skip
    scorer.data = data
    scorer._before_accept = (dict(data.windows), data.contact_box, data.roll)
    data.windows["fit"], data.contact_box, data.roll = "afresh", {"stiffness": (1, 2)}, True
    scorer.undo_accept()
    assert data.windows == {"fit": "before", "train": "train"}
    assert data.contact_box is None and data.roll is False
