"""Progress bars over the long fits: one tick per Levenberg-Marquardt iteration with
the fit's own error, and none drawn in a forked worker."""

from __future__ import annotations

from dataclasses import replace
from typing import ClassVar

import numpy as np
import pytest
import torch

from identification.simulation.generate import GenerateSpec, generate_dataset
from identification.trajectory import forked, progress
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.progress import iteration_bar
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
from identification.trajectory.windows import STATE_KEYS, cut_windows
from tensegrity_env.engine import Engine

pytestmark = pytest.mark.usefixtures("one_torch_thread")


class Recorder:
    """Stands in for tqdm: keeps what the bar was told."""

    made: ClassVar[list[Recorder]] = []

    def __init__(self, **kwargs: object) -> None:
        self.kwargs, self.n, self.postfix, self.closed = kwargs, 0, [], False
        Recorder.made.append(self)

    def update(self, k: int) -> None:
        self.n += k

    def set_postfix_str(self, text: str, refresh: bool = True) -> None:
        self.postfix.append(text)

    def close(self) -> None:
        self.closed = True


@pytest.fixture
def bars(monkeypatch: pytest.MonkeyPatch) -> list[Recorder]:
    Recorder.made = []
    monkeypatch.setattr(progress, "tqdm", Recorder)
    return Recorder.made


def test_a_fit_ticks_once_per_iteration_with_its_own_error(bars: list[Recorder]) -> None:
    ds, truth = generate_dataset(GenerateSpec(n_train=1, n_val=0, n_test=0, steps=60, seed=0))
    split, topo = ds.split("train"), ds.topology
    grid = {k: getattr(split, k) for k in STATE_KEYS}
    windows = cut_windows(split.nodes, split.control, grid, 20)
    vec = ParamVector.at(topo, truth.params)
    vec = replace(vec, free=torch.ones_like(vec.free))  # every parameter fitted
    seen: list[float] = []
    with iteration_bar("joint fit", 4) as tick:
        options = FitOptions(max_iter=4, tol=0.0,
                             progress=lambda mse: (seen.append(mse), tick(mse)))  # fmt: skip
        done = fit(WindowedProblem(Engine(topo, ds.dt), vec, windows, vec.theta0() + 0.02), options)
    bar = bars[0]
    assert len(done.history) > 1 and bar.n == len(done.history) - 1 <= 4
    assert seen == done.history[1:]
    assert bar.postfix[-1] == f"end-cap RMS {np.sqrt(done.history[-1]) * 1e3:.3f} mm"
    assert bar.closed and bar.kwargs["total"] == 4 and bar.kwargs["disable"] is None


def test_no_bar_is_drawn_in_a_forked_worker(
    bars: list[Recorder], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(forked, "_in_worker", True)
    with iteration_bar("final refit", 20) as tick:
        tick(1e-6)
    assert bars[0].kwargs["disable"] is True and bars[0].closed
