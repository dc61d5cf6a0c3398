"""The trajectory fit survives trial steps the engine cannot take, and windows whose
error jumps."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from identification.trajectory import windowed_fit
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
from identification.trajectory.windows import Windows, end_caps
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.engine import Engine, State, substeps_for
from tensegrity_env.io_utils import InputError


def _windows(n: int = 1, noise: float = 0.0) -> tuple[Engine, ParamVector, Windows, torch.Tensor]:
    """``n`` windows of 12 steps from random states, end caps with ``noise`` [m]; the
    stiffnesses free and started 30 % off."""
    a = icosahedron()
    dt = 1 / 120
    engine = Engine(a.topology, dt, substeps=substeps_for(dt), native=True)  # C kernel: same physics
    rng = np.random.default_rng(0)
    p = torch.as_tensor(a.pose_p[None] + rng.normal(0, 0.01, (n, 6, 3)))
    q = torch.as_tensor(np.repeat(a.pose_q[None], n, axis=0))
    v = torch.as_tensor(rng.normal(0, 0.3, (n, 6, 3)))
    w = torch.as_tensor(rng.normal(0, 1.0, (n, 6, 3)))
    truth = State(p, v, q, w)
    with torch.no_grad():
        roll = engine.rollout(truth, a.params, 12)
    obs = end_caps(engine, roll.p, roll.q)
    obs = obs + noise * torch.as_tensor(rng.standard_normal(obs.shape))
    vec = ParamVector.at(a.topology, a.params)
    free = torch.zeros_like(vec.free)
    free[: a.topology.n_springs] = True  # the stiffnesses
    start = vec.start.clone()
    start[: a.topology.n_springs] += np.log(1.3)  # 30 % off
    vec = replace(vec, free=free, start=start)
    win = Windows(obs=obs, control=None, state=truth, traj=np.arange(n), start=np.zeros(n, int))
    return engine, vec, win, vec.theta0()


def _fit(engine: Engine, vec: ParamVector, win: Windows, theta: torch.Tensor, **options):
    """The windowed fit of the stiffnesses and states, 10 iterations at most."""
    return fit(WindowedProblem(engine, vec, win, theta), FitOptions(max_iter=10, **options))


def test_a_trial_step_the_engine_cannot_take_is_a_rejected_step(monkeypatch) -> None:
    engine, vec, win, theta = _windows()
    real = windowed_fit.window_sses
    calls = {"n": 0}

    def flaky(*args, **kwargs):  # the first two trials: an effect rejects NaN values
        calls["n"] += 1
        if calls["n"] <= 2:
            raise InputError("effect 'ground_contact': 'stiffness' contains NaN or inf")
        return real(*args, **kwargs)

    monkeypatch.setattr(windowed_fit, "window_sses", flaky)
    fit = _fit(engine, vec, win, theta)
    assert calls["n"] > 2
    assert np.isfinite(fit.history).all()
    assert fit.history[-1] < 1e-4 * fit.history[0]  # the fit still heads to the truth
    assert np.median(np.abs(fit.theta.numpy() - (theta.numpy() - np.log(1.3)))) < 1e-2


def test_a_window_whose_error_jumps_at_every_step_is_left_out_and_the_fit_goes_on(
    monkeypatch,
) -> None:
    # window 3's error jumps by 100 noise variances per sample wherever the stiffnesses
    # leave their start: an impact on the edge of a physics step, as on the floor
    engine, vec, win, theta = _windows(n=12, noise=1e-3)
    others = win.take(np.flatnonzero(win.traj != 3))
    without = _fit(engine, vec, others, theta, line_search=True)
    real = windowed_fit.window_sses
    start = theta.clone()

    def jumpy(engine, vec, win, basis, th, chunk):
        each, _ = real(engine, vec, win, basis, th, chunk)
        moved = not torch.equal(th, start)
        each = each + np.where((win.traj == 3) & moved, 100e-6 * win.residuals / win.size, 0.0)
        return each, float(each.sum())

    monkeypatch.setattr(windowed_fit, "window_sses", jumpy)
    stuck = _fit(engine, vec, win, theta)  # no line search: no way out
    assert torch.equal(stuck.theta, theta)
    lines: list[str] = []
    fit = _fit(engine, vec, win, theta, line_search=True, log=lines.append)
    assert fit.windows.size == 11 and 3 not in fit.windows.traj
    assert len(lines) == 1 and "1 windows left out" in lines[0]
    # from there it is the fit without that window: stiffnesses 30 % off at the start
    assert torch.allclose(fit.theta, without.theta, atol=1e-3)
    assert np.median(np.abs(without.theta.numpy() - (theta.numpy() - np.log(1.3)))) < 0.05
