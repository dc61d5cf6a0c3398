"""On the floor, the loop's start (the screened reference, the declared model's held-out
score and its test score) runs side by side and gives what it gives one after the other;
the test split's states are fitted once."""

from __future__ import annotations

import os
from types import SimpleNamespace

import numpy as np
import pytest

from identification.discovery import multi_step
from identification.discovery.multi_step import MultiStepScorer
from identification.trajectory.end_cap_data import TrajectorySettings


class Fit:
    """A stand-in for a fitted model (picklable, as results from workers must be)."""

    def __init__(self, name: str, rms: float) -> None:
        self.name, self.rms, self.bic = name, rms, 100.0 * rms
        self.windows, self.effects = SimpleNamespace(size=8), ()

    def fitted_model(self, topology: object, dt: float) -> str:
        return f"model of {self.name}"


def _heldout(data, fit, split, iters, warm=None, fresh=False):
    """Per split and model: sum of squares [m^2], residuals and the pid that fitted it."""
    sse = {"val": 2.0e-4, "test": 3.0e-4}[split] * (1.0 + fit.rms) + (0 if warm is None else 1e-6)
    return sse, 100, (split, fit.name, os.getpid())


def _begin(jobs: int, monkeypatch: pytest.MonkeyPatch) -> tuple[MultiStepScorer, object]:
    base, final = Fit("base", 1.0e-3), Fit("final", 1.1e-3)
    monkeypatch.setattr(multi_step, "EndCapData", lambda dataset, settings: SimpleNamespace(
        on_floor=True, log=None, contact_start=None))  # fmt: skip
    monkeypatch.setattr(multi_step, "noise_level", lambda nodes, rods=False: 1.0e-3)
    monkeypatch.setattr(multi_step, "fit_declared", lambda data, s, start, effects=(): (final, base))
    monkeypatch.setattr(multi_step, "heldout", _heldout)
    monkeypatch.setattr(multi_step, "screen_candidate",
                        lambda data, now, effects, iters: Fit(f"reference of {now.name}", 1.05e-3))  # fmt: skip
    dataset = SimpleNamespace(split=lambda name: SimpleNamespace(nodes=np.zeros((1, 2, 12, 3))),
                              topology=None, dt=1 / 120)  # fmt: skip
    scorer = MultiStepScorer(TrajectorySettings(), jobs=jobs)
    return scorer, scorer.begin(dataset, lambda line: None)


def test_the_start_on_the_floor_is_the_same_side_by_side(monkeypatch) -> None:
    (one, serial), (two, forked) = _begin(1, monkeypatch), _begin(2, monkeypatch)
    for c in (serial, forked):
        assert c.fit.reference.name == "reference of base"  # screened from the selection fit
        assert c.fit.val_windows[:2] == ("val", "reference of base")
        assert c.model == "model of final"
    assert forked.fit.val_sse == serial.fit.val_sse
    assert forked.heldout == serial.heldout and forked.bic == serial.bic
    # the test split fitted at the start, in a worker with two jobs, and not again
    monkeypatch.setattr(multi_step, "heldout", None)  # a second fit would fail
    for scorer, c, here in ((one, serial, True), (two, forked, False)):
        errors = scorer.test_errors(c)
        assert errors["caps_rms"] == pytest.approx(np.sqrt(3.0e-4 * (1 + 1.1e-3) / 100))
        assert (scorer._tested[id(c.fit.final)][1][2][2] == os.getpid()) is here
