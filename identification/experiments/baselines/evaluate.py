"""Errors of any predictor on held-out trajectories: one step and fed-back rollouts."""

from __future__ import annotations

import numpy as np
import torch

from identification.data.dataset import Split
from identification.experiments.baselines.common import Predictor, sample_transitions
from tensegrity_env.engine import State


def one_step_errors(
    model: Predictor, split: Split, n: int = 20_000, seed: int = 0, chunk: int = 5_000
) -> dict[str, float]:
    """Mean one-step errors over ``n`` random transitions of ``split``.

    Returns ``position`` [m], ``velocity`` [m/s] and ``angular_velocity`` [rad/s]: the
    mean over transitions and rods of the Euclidean norm of the error of the next state.
    """
    s0, s1, _ = sample_transitions(split, n, seed)
    sums = {"position": 0.0, "velocity": 0.0, "angular_velocity": 0.0}
    with torch.no_grad():
        for lo in range(0, s0.batch_size, chunk):
            sl = slice(lo, lo + chunk)
            pred, true = model.predict(s0.index(sl)), s1.index(sl)
            for key, a, b in (
                ("position", pred.p, true.p),
                ("velocity", pred.v, true.v),
                ("angular_velocity", pred.omega, true.omega),
            ):
                sums[key] += float(torch.linalg.vector_norm(a - b, dim=-1).sum())
    count = s0.batch_size * s0.p.shape[1]
    return {k: v / count for k, v in sums.items()}


def initial_states(split: Split) -> State:
    """The first state of every trajectory, (N, R, ·) float64."""
    return State.from_numpy(*(getattr(split, k)[:, 0] for k in ("p", "v", "q", "omega")))


def rollout_error_curve(model: Predictor, split: Split, horizon: int | None = None) -> np.ndarray:
    """Mean rod position error [m] against horizon, (H+1,), of open-loop rollouts.

    Each trajectory starts from its recorded first state and the model's predictions
    are fed back for ``horizon`` steps (all recorded steps when None). The error at
    step k is ``|p_k - p_true_k|`` averaged over trajectories and rods; a rollout that
    has left the finite numbers counts as ``inf`` from then on.
    """
    T = split.n_transitions if horizon is None else min(horizon, split.n_transitions)
    assert split.p is not None
    truth = torch.as_tensor(split.p[:, : T + 1])
    state = initial_states(split)
    curve = np.zeros(T + 1)
    with torch.no_grad():
        for t in range(1, T + 1):
            state = model.predict(state)
            err = torch.linalg.vector_norm(state.p - truth[:, t], dim=-1)
            err = torch.where(torch.isfinite(err), err, torch.full_like(err, float("inf")))
            curve[t] = float(err.mean())
    return curve
