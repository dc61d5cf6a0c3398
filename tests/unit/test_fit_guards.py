"""The trajectory fit survives trial steps the engine cannot take."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from identification.trajectory import windowed_fit
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.windowed_fit import fit_windows
from identification.trajectory.windows import Windows, end_caps
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.engine import Engine, State, substeps_for
from tensegrity_env.io_utils import InputError


def _windows() -> tuple[Engine, ParamVector, Windows, torch.Tensor]:
    a = icosahedron()
    dt = 1 / 120
    engine = Engine(a.topology, dt, substeps=substeps_for(dt))
    rng = np.random.default_rng(0)
    p = torch.as_tensor(a.pose_p[None] + rng.normal(0, 0.01, (1, 6, 3)))
    q = torch.as_tensor(a.pose_q[None])
    v = torch.as_tensor(rng.normal(0, 0.3, (1, 6, 3)))
    w = torch.as_tensor(rng.normal(0, 1.0, (1, 6, 3)))
    truth = State(p, v, q, w)
    with torch.no_grad():
        roll = engine.rollout(truth, a.params, 12)
    obs = end_caps(engine, roll.p, roll.q)
    vec = ParamVector.at(a.topology, a.params)
    free = torch.zeros_like(vec.free)
    free[: a.topology.n_springs] = True  # the stiffnesses
    start = vec.start.clone()
    start[: a.topology.n_springs] += np.log(1.3)  # 30 % off
    vec = replace(vec, free=free, start=start)
    win = Windows(obs=obs, control=None, state=truth, traj=np.zeros(1, int), start=np.zeros(1, int))
    return engine, vec, win, vec.theta0()


def test_a_trial_step_the_engine_cannot_take_is_a_rejected_step(monkeypatch) -> None:
    engine, vec, win, theta = _windows()
    real = windowed_fit.window_sse
    calls = {"n": 0}

    def flaky(*args, **kwargs):  # the first two trials: an effect rejects NaN values
        calls["n"] += 1
        if calls["n"] <= 2:
            raise InputError("effect 'ground_contact': 'stiffness' contains NaN or inf")
        return real(*args, **kwargs)

    monkeypatch.setattr(windowed_fit, "window_sse", flaky)
    fit = fit_windows(engine, vec, win, theta, max_iter=10)
    assert calls["n"] > 2
    assert np.isfinite(fit.history).all()
    assert fit.history[-1] < 1e-4 * fit.history[0]  # the fit still heads to the truth
    assert np.median(np.abs(fit.theta.numpy() - (theta.numpy() - np.log(1.3)))) < 1e-2
