"""One windowed problem, one fit: its sample times, the states-only problem, and the
method that matches whether the states are fitted."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from identification.trajectory.param_vector import ParamVector
from identification.trajectory.windowed_problem import (
    STALL_ITERS,
    FitOptions,
    WindowedProblem,
    fit,
    stalled,
)
from identification.trajectory.windows import Windows, end_caps
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import ControlLag, GroundContact
from tensegrity_env.engine import Engine, State, substeps_for

DT = 1 / 120


def _problem(n: int = 2, steps: int = 12) -> tuple[WindowedProblem, State]:
    """``n`` clean windows of ``steps`` steps from random states of the icosahedron, the
    states started 2 mm off, every stiffness free at its true value."""
    a = icosahedron()
    engine = Engine(a.topology, DT, substeps=substeps_for(DT), native=True)
    rng = np.random.default_rng(3)
    p = torch.as_tensor(a.pose_p[None] + rng.normal(0, 0.01, (n, 6, 3)))
    q = torch.as_tensor(np.repeat(a.pose_q[None], n, axis=0))
    truth = State(p, torch.as_tensor(rng.normal(0, 0.3, (n, 6, 3))), q,
                  torch.as_tensor(rng.normal(0, 1.0, (n, 6, 3))))  # fmt: skip
    with torch.no_grad():
        roll = engine.rollout(truth, a.params, steps)
    vec = ParamVector.at(a.topology, a.params)
    free = torch.zeros_like(vec.free)
    free[: a.topology.n_springs] = True
    start = np.array([0, 40])[:n]
    win = Windows(obs=end_caps(engine, roll.p, roll.q), control=None,
                  state=replace(truth, p=truth.p + 0.002), traj=np.arange(n), start=start)  # fmt: skip
    return WindowedProblem(engine, replace(vec, free=free), win), truth


def test_sample_times_are_the_data_s_own() -> None:
    problem, _ = _problem()
    times = problem.times
    assert times.shape == (2, 13)
    np.testing.assert_allclose(times[1], (40 + np.arange(13)) * DT)


def test_states_only_holds_the_model_where_it_is_and_finds_the_true_states() -> None:
    """The model held at its start (nothing free, no coordinates): on clean windows the
    fit of the states alone returns to the true states."""
    problem, truth = _problem()
    only = WindowedProblem.states_only(problem.engine, problem.vec, problem.start, problem.windows)
    assert not bool(only.vec.free.any()) and only.vec.coords is None and len(only.start) == 0
    torch.testing.assert_close(only.vec.start, problem.vec.start)
    done = fit(only, FitOptions.states(20, spin=True))
    assert done.history[-1] < 1e-6 * done.history[0]
    assert float((done.windows.state.p - truth.p).abs().max()) < 1e-6  # [m]


def test_the_method_follows_whether_the_states_are_fitted() -> None:
    problem, _ = _problem(n=1)
    with pytest.raises(ValueError, match="states must be held"):
        fit(problem, FitOptions.dense())
    with pytest.raises(ValueError, match="dense method"):
        fit(replace(problem, states_held=True), FitOptions())


def test_an_effects_only_problem_lists_its_coordinates_in_the_effects_order() -> None:
    a = icosahedron()
    problem, _ = _problem(n=1)
    contact, lag = GroundContact(a.topology), ControlLag(a.topology, time_constant=0.02)
    only = WindowedProblem.effects_only(Engine(a.topology, DT), a.params, [contact, lag],
                                        [(0, "friction"), (1, "time_constant")],
                                        problem.windows)  # fmt: skip
    assert only.states_held and only.vec.n_free == 0 and only.vec.coords is not None
    assert only.vec.coords.names() == ["ground_contact.friction", "control_lag.time_constant"]
    with pytest.raises(ValueError, match="order of their effects"):
        WindowedProblem.effects_only(Engine(a.topology, DT), a.params, [contact, lag],
                                     [(1, "time_constant"), (0, "friction")], problem.windows)  # fmt: skip


def test_stalled_sums_the_last_iterations_chi_square_decreases() -> None:
    assert STALL_ITERS == 3
    assert not stalled([0.1, 0.1, 0.1], None)  # no rule: never
    assert not stalled([0.1, 0.1], 1.0)  # too few iterations to say
    assert stalled([50.0, 0.5, 0.2, 0.2], 1.0)  # the last three: 0.9
    assert not stalled([0.5, 0.2, 0.2, 50.0], 1.0)  # still falling
    assert not stalled([0.4, 0.3, 0.3], 1.0)  # exactly 1: not below


def _noisy_off_start() -> WindowedProblem:
    """:func:`_problem` with 1 mm of noise on the end caps and the stiffnesses 5 % off."""
    problem, _ = _problem()
    noise = np.random.default_rng(4).normal(0.0, 1e-3, problem.windows.obs.shape)
    windows = replace(problem.windows, obs=problem.windows.obs + torch.as_tensor(noise))
    return replace(problem, windows=windows, theta=problem.start + 0.05)


def test_a_stall_rule_stops_a_fit_whose_error_no_longer_falls_by_it() -> None:
    """A rule no iteration can meet stops the fit after :data:`STALL_ITERS` iterations,
    reported as converged; a rule of 0 (an accepted step always lowers the error) leaves
    the fit as it is without one."""
    problem = _noisy_off_start()
    plain = fit(problem, FitOptions(max_iter=8))
    assert len(plain.history) - 1 > STALL_ITERS  # the rule below has something to cut
    cut = fit(problem, FitOptions(max_iter=8, stall=float("inf")))
    assert len(cut.history) - 1 == STALL_ITERS and cut.converged
    assert cut.history == plain.history[: STALL_ITERS + 1]  # the same iterations until then
    never = fit(problem, FitOptions(max_iter=8, stall=0.0))
    assert never.history == plain.history and torch.equal(never.theta, plain.theta)
