"""One windowed problem, one fit: its sample times, the states-only problem, and the
method that matches whether the states are fitted."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from identification.trajectory.param_vector import ParamVector
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
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
