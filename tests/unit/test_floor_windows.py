"""The floor fit's windows chosen on the data (identification.trajectory.floor_declared):
the state fit's expected residual, the halvings, and longer windows once the model fits."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import clean_rolling

from identification.data.end_caps import dataset_from_end_caps
from identification.trajectory.end_cap_data import (
    EndCapData,
    TrajectorySettings,
    declared_start,
    held_drag_axis,
)
from identification.trajectory.floor_declared import (
    MIN_FLOOR_STEPS,
    ROD_STATE,
    floor_rows,
    halvings,
    longer_windows,
    state_fit_ratio,
    state_fits,
    within,
)
from identification.trajectory.floor_fit import floor_contact, with_floor
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import GroundContact
from tensegrity_env.mjcf import from_mjcf
from tensegrity_env.mjcf_checks import FEATURES, IgnoredFeatureWarning


@pytest.mark.parametrize("steps", [4, 8, 30])
def test_a_least_squares_fit_of_the_state_leaves_the_noise_less_its_degrees_of_freedom(steps):
    rng = np.random.default_rng(0)
    n, sigma, rms = 6 * (steps + 1), 1e-3, []
    for _ in range(400):  # a rod's window: 6 coordinates per sample, 12 state unknowns
        a = rng.normal(size=(n, ROD_STATE))
        y = a @ rng.normal(size=ROD_STATE) + rng.normal(0.0, sigma, n)
        r = y - a @ np.linalg.lstsq(a, y, rcond=None)[0]
        rms.append(np.mean(r**2))
    assert np.sqrt(np.mean(rms)) / sigma == pytest.approx(state_fit_ratio(steps), rel=0.02)
    # so a short window's fit looks closer to the noise than a long one's
    assert state_fit_ratio(4) < state_fit_ratio(8) < state_fit_ratio(30) < 1.0
    assert within((0.9e-3, 30), 1e-3) and not within((1.2e-3, 4), 1e-3)


def test_windows_are_halved_down_to_the_fewest_steps() -> None:
    assert halvings(30) == [30, 15, 8, 4]
    assert halvings(12) == [12, 6, 4]
    assert halvings(MIN_FLOOR_STEPS) == [MIN_FLOOR_STEPS]


@pytest.fixture(scope="module")
def rolling():
    """Rolling icosahedron data (2 s, 120 Hz, 1 mm noise) and its declared-model vector
    at the true parameters and contact."""
    truth, split = clean_rolling(0, duration=2.0)
    nodes = split.nodes + np.random.default_rng(2).normal(0.0, 1e-3, split.nodes.shape)
    topo = icosahedron().topology
    data = EndCapData(dataset_from_end_caps(topo, 1 / 120, {"train": nodes, "test": nodes}),
                       TrajectorySettings())  # fmt: skip
    data.on_floor = True
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IgnoredFeatureWarning)
        contact = from_mjcf("<plant>", xml=truth.xml, ignore=tuple(FEATURES)).contact
    true_contact = GroundContact(topo, **{**contact, "height": 0.0})
    vec = declared_start(data, {}, truth.params, None, rod_keep=floor_rows(data))
    begin = floor_contact(topo, nodes, true_contact)
    return data, with_floor(vec, [], begin, held_drag_axis(data)), truth


def test_longer_windows_are_taken_where_their_states_fit_at_the_model(rolling) -> None:
    data, vec, _ = rolling
    at_truth = longer_windows(data, vec, vec.theta0(), 30, MIN_FLOOR_STEPS, 8, 1e-3)
    assert at_truth is not None and at_truth[0] > MIN_FLOOR_STEPS, at_truth
    steps, count, _ = at_truth
    tried = state_fits(data, vec, vec.theta0(), halvings(30), 8, 1e-3)
    share = tried[-1][2]  # the windows whose states fit; the others are left out
    assert 0.5 <= share <= 1.0
    # about the samples of 8 x 30 in the windows kept
    assert count == max(8, min(32, round(8 * 30 / steps / share)))
    assert tried[-1][1] == steps and within(tried[-1], 1e-3)
    assert not any(within(t, 1e-3) for t in tried[:-1])  # the longest within is taken
    assert longer_windows(data, vec, vec.theta0(), 30, steps, 8, 1e-3) is None


def test_near_medians_far_from_the_noise_are_each_a_choice(monkeypatch) -> None:
    """Where no window length's state fit reaches the noise, the start model's own error
    is what the medians show: every length within STUCK_WINDOW of the lowest (against its
    state_fit_ratio) is fitted and compared; one that reaches the noise is the one choice."""
    from identification.trajectory import floor_declared

    def fake(medians_mm):
        def fits(data, vec, theta, lengths, count, noise):
            return [(m * 1e-3, n, 1.0) for m, n in zip(medians_mm, lengths, strict=True)]

        return fits

    vec = type("V", (), {"theta0": lambda self: None})()
    # a real take's medians (mm) at 30, 15, 8 and 4 steps, 0.1 mm noise: all near
    monkeypatch.setattr(floor_declared, "state_fits", fake([9.26, 8.13, 7.42, 6.3]))
    choices, why = floor_declared.windows_from_data(None, vec, 30, 8, 1e-4)
    assert [m for m, _ in choices] == [4, 8, 15, 30] and "6.3 mm" in why  # the lowest first
    assert [n for _, n in choices] == [32, 30, 16, 8]  # about the samples of 8 x 30 each
    # a tumbling take's: the short windows far better, the only choice
    monkeypatch.setattr(floor_declared, "state_fits", fake([36.3, 30.5, 30.1, 15.9]))
    assert [m for m, _ in floor_declared.windows_from_data(None, vec, 30, 8, 1.4e-3)[0]] == [4]
    # the longest within the noise: the one choice, the search stops there
    monkeypatch.setattr(
        floor_declared, "state_fits", lambda *a: [(3e-3, 30, 1.0), (0.9e-3, 15, 0.75)]
    )
    assert floor_declared.windows_from_data(None, vec, 30, 8, 1e-3)[0] == [(15, 21)]  # 8 x 2 / 0.75


def test_the_fit_goes_on_to_longer_windows_that_half_its_windows_carry(monkeypatch) -> None:
    """From the fitted model the floor fit goes on to the longest length of which half the
    windows' states fit (the fit leaves the stuck ones out), else one length up where a
    quarter do (a continuation), else it stays."""
    from identification.trajectory import floor_declared

    monkeypatch.setattr(floor_declared, "bounded", lambda vec, theta: vec)
    log: list[str] = []
    data = type("D", (), {"log": lambda self, line: log.append(line)})()

    def shares(*tried):
        monkeypatch.setattr(floor_declared, "state_fits", lambda *a: list(tried))

    # 8 steps: median just above the limit scaled for the window, yet 62 % within it
    shares((7.6e-3, 30, 0.0), (3.5e-3, 15, 0.1), (1.43e-3, 8, 0.62))
    assert not within((1.43e-3, 8, 0.62), 0.986e-3)
    assert floor_declared.longer_windows(data, None, None, 30, 4, 8, 0.986e-3)[:2] == (
        8,
        32,
    )  # 4 x 8 at most
    # the longest such length is taken
    shares((7.6e-3, 30, 0.1), (1.3e-3, 15, 0.55), (1.1e-3, 8, 0.9))
    assert floor_declared.longer_windows(data, None, None, 30, 4, 8, 1e-3)[0] == 15
    # none carries half: one length up where a quarter of its windows fit
    shares((7.6e-3, 30, 0.0), (3.5e-3, 15, 0.1), (2e-3, 8, 0.3))
    assert floor_declared.longer_windows(data, None, None, 30, 4, 8, 1e-3)[0] == 8
    # fewer: stay
    shares((7.6e-3, 30, 0.0), (3.5e-3, 15, 0.1), (2e-3, 8, 0.2))
    assert floor_declared.longer_windows(data, None, None, 30, 4, 8, 1e-3) is None
    assert "stay at 4 steps" in log[-1]


def test_a_longer_window_fit_pulled_off_by_stuck_windows_is_not_kept() -> None:
    """A drawn plant's fit from the truth: 0.124 mm on 6-step windows (0.133 mm noise),
    0.446 mm on 25-step windows half of which were stuck: the shorter fit stays; a longer
    fit within 1.5 noise levels replaces it even where its RMS is higher."""
    from identification.trajectory.floor_declared import kept_longer

    def fit(rms_mm: float):  # only the last mean squared error matters here
        return type("W", (), {"history": [(rms_mm * 1e-3) ** 2]})()

    assert not kept_longer(fit(0.124), fit(0.446), 0.133e-3)
    assert kept_longer(fit(0.124), fit(0.145), 0.133e-3)  # within 1.5 noise levels
    assert kept_longer(fit(1.458), fit(1.715), 1.53e-3)  # a real-robot-like fit above the noise


@pytest.mark.parametrize("at_start", [True, False])
def test_stuck_windows_are_left_out_at_the_start_only_from_a_given_model(rolling, monkeypatch,
                                                                        at_start) -> None:  # fmt: skip
    """At a start model from a file the windows its states cannot reach are stuck and left
    out before the first fit; at the regression (``stuck_at_start=False``) their misfit is
    the model's own error, and every window goes into the first fit."""
    from identification.trajectory import floor_fit as ff

    data, vec, _ = rolling
    calls: list[int] = []

    def spy(engine, vec, theta, windows, stuck, log=lambda s: None, near=False):
        calls.append(windows.size)
        return windows.take(np.arange(windows.size - 1))  # one left out: its fit sees fewer

    monkeypatch.setattr(ff, "without_stuck", spy)
    windows = data.cut("train", MIN_FLOOR_STEPS, 4, 3)
    fit = ff.fit_on_floor(data.engine, vec, windows, vec.theta0(), 1, rounds=1, max_rounds=1,
                          stuck=1.5e-3, stuck_at_start=at_start)  # fmt: skip
    assert len(calls) == (1 if at_start else 0)
    assert fit.windows.size == windows.size - (1 if at_start else 0)


def test_the_two_starts_are_compared_on_the_groups_the_end_caps_pin(rolling) -> None:
    """The largest relative difference is taken over masses, perpendicular inertias and
    stiffnesses only (a spring damping the data barely sees may differ more), and the
    check warns above STARTS_APART."""
    from identification.trajectory.floor_declared import (
        STARTS_APART,
        StartCheck,
        largest_difference,
    )

    _, vec, _ = rolling
    names = [vec.names()[i] for i in np.flatnonzero(vec.free.numpy())]
    a = vec.theta0()
    b = a.clone()
    b[names.index("mass[rod2]")] += np.log(1.05)
    b[names.index("inertia_perp[rod4]")] -= np.log(1.02)
    b[names.index("damping[spring3]")] += np.log(3.0)  # not compared
    name, difference = largest_difference(vec, a, b)
    assert name == "mass[rod2]" and difference == pytest.approx(0.05, rel=1e-9)
    assert largest_difference(vec, b, a) == (name, pytest.approx(difference, rel=1e-12))
    assert largest_difference(vec, a, a)[1] == 0.0
    apart = StartCheck(name, difference, (1.1e-3, 1.0e-3), 1, "val windows of 30 steps")
    near = StartCheck(name, 0.9 * STARTS_APART, (1.0e-3, 1.0e-3), 0, "val windows of 30 steps")
    assert apart.apart and not near.apart
    assert "two minima" in apart.line() and "kept the second" in apart.line()
    assert apart.as_dict()["largest_difference"] == {"name": "mass[rod2]", "relative": difference}


def test_the_start_whose_model_carries_the_states_further_is_kept(rolling, monkeypatch) -> None:
    """compare_starts judges both fitted models on the same held-out windows and keeps the
    lower median state fit (the first on a tie)."""
    from identification.trajectory import floor_declared

    data, vec, _ = rolling
    a = vec.theta0()
    b = a.clone()
    b[0] += np.log(1.2)
    scores = {float(a[0]): 2e-3, float(b[0]): 1e-3}
    monkeypatch.setattr(floor_declared, "judged",
                        lambda d, v, t, n, c, s: (scores[float(t[0])], "val windows"))  # fmt: skip
    check = floor_declared.compare_starts(data, vec, [a, b], 30, 8, 1e-3)
    assert check.kept == 1 and check.judged == (2e-3, 1e-3) and check.apart
    assert floor_declared.compare_starts(data, vec, [a, a], 30, 8, 1e-3).kept == 0


@pytest.mark.parametrize("given, second", [(False, True), (False, False), (True, True)])
def test_the_floor_fit_runs_its_second_start_only_from_the_regression(rolling, monkeypatch,
                                                                       given, second) -> None:  # fmt: skip
    """floor_fit from the regression runs the windowed fit twice (the second from the
    spread of soft contacts), compares the two and keeps the one the judge prefers; from
    a given model, or with ``second_start`` off, it runs once and compares nothing."""
    from identification.trajectory import floor_declared
    from identification.trajectory.windowed_fit import WindowFit

    data, _, truth = rolling
    calls: list[tuple[bool, bool]] = []
    returned = []

    def one_start(d, v, s, choices, longest, count, noise, stuck_at_start=True, spread=False):
        calls.append((stuck_at_start, spread))
        names = [v.names()[i] for i in np.flatnonzero(v.free.numpy())]
        theta = v.theta0().clone()
        theta[names.index("mass[rod2]")] += np.log(1.1) * spread  # the second start's mass 10 % up
        returned.append(theta)
        windows = d.cut("train", 8, 2, 3)
        return WindowFit(theta, windows, [1e-6], np.zeros(theta.numel()), float("nan"), True), 8

    scores: list[float] = []

    def judge(d, v, theta, longest, count, noise):
        scores.append(1e-3 if len(scores) else 2e-3)  # the second start's model judged better
        return scores[-1], "train windows of 8 steps"

    monkeypatch.setattr(floor_declared, "windowed_floor_fit", one_start)
    monkeypatch.setattr(floor_declared, "judged", judge)
    s = TrajectorySettings(floor_window=8, floor_windows=2, second_start=second)
    fitted = floor_declared.floor_fit(data, s, start=truth.params if given else None)
    if given or not second:
        assert calls == [(given, False)] and fitted.starts is None and not scores
        return
    assert calls == [(False, False), (False, True)]
    check = fitted.starts
    assert check is not None and check.kept == 1 and check.apart
    assert check.name == "mass[rod2]" and check.difference == pytest.approx(0.1, rel=1e-9)
    assert fitted.fit.theta is returned[1] and fitted.fit.origin is returned[1]
