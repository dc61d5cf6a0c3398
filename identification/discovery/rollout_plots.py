"""The report's rollout figure: measured end caps against the declared and the final
model, rolled out open-loop over a test stretch (:func:`plot_end_cap_rollouts`).

On rod states the stretch is the first test trajectory from its measured first state;
on end caps only, the first test window, from the initial state each model fits to it
(the window's states are fitted with the model held, as the held-out errors are).
"""

from __future__ import annotations

from pathlib import Path

import torch

from identification.data.dataset import Dataset
from identification.linear.extended import acting_split
from identification.report.plots import plot_end_cap_rollouts
from identification.trajectory.end_cap_data import (
    EndCapData,
    TrajFit,
    predicted_caps,
)
from identification.trajectory.fitted_model import FittedModel
from identification.trajectory.windows import STATE_KEYS, Windows, end_caps
from tensegrity_env.engine import Engine, State

#: the two models of the figure, in panel order
LABELS = ("declared model", "diagnosed model")


def rod_state_rollout_plot(
    dataset: Dataset,
    split: str,
    horizon_s: float,
    before: FittedModel,
    after: FittedModel,
    path: Path,
) -> Path:
    """``split``'s first trajectory against ``before`` and ``after`` rolled out from its
    measured first state over ``horizon_s`` [s] (the commands that act, lag included)."""
    data = dataset.split(split)
    steps = min(data.n_transitions, max(1, round(horizon_s / dataset.dt)))
    init = State(*(torch.as_tensor(getattr(data, k)[:1, 0]) for k in STATE_KEYS))
    models = {}
    for label, m in zip(LABELS, (before, after), strict=True):
        acting = acting_split(m.effects, data, dataset.dt)
        control = torch.as_tensor(acting.control[:1, :steps])
        cables = acting.cable_control
        cables_t = None if cables is None else torch.as_tensor(cables[:1, :steps])
        engine = Engine(dataset.topology, dataset.dt, effects=m.effects, native=True)
        with torch.no_grad():
            roll = engine.rollout(init, m.params, steps, control, cables_t)
        models[label] = end_caps(engine, roll.p, roll.q)[0].numpy()
    title = (f"{split} trajectory 0, open loop from its first state "
             f"({', '.join(after.names) or 'nothing'} added)")  # fmt: skip
    return plot_end_cap_rollouts(dataset.dt, data.nodes[0, : steps + 1], models, path, title)


def end_cap_rollout_plot(
    data: EndCapData,
    before: TrajFit,
    after: TrajFit,
    fitted: tuple[Windows, Windows],
    path: Path,
) -> Path:
    """The first test window against ``before`` and ``after``, each rolled out from the
    initial state it fits to the window (``fitted``: the test windows with the states
    each fits, as :func:`~identification.trajectory.end_cap_data.heldout` returns them)."""
    windows = data.windows["test"]
    models = {}
    for label, fit, states in zip(LABELS, (before, after), fitted, strict=True):
        models[label] = predicted_caps(data, fit, states)[0].numpy()
    names = [e.name for e in after.effects]
    title = (f"test window 0 ({windows.steps * data.dataset.dt:g} s), open loop from the state "
             f"each model fits to it ({', '.join(names) or 'nothing'} added)")  # fmt: skip
    return plot_end_cap_rollouts(data.dataset.dt, windows.obs[0].numpy(), models, path, title)
