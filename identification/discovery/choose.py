"""The choice of scorer for a dataset: one function that ``diagnose`` and the experiments call.

Rod states measured (MuJoCo data, or states a user computed) are scored by one-step
regressions (:class:`~identification.discovery.one_step.OneStepScorer`, on states
computed from end caps by :func:`~identification.data.end_caps.with_measured_states`
where a split has none); end caps only (motion capture) by multi-step prediction
through the engine (:class:`~identification.discovery.multi_step.MultiStepScorer`).
``method`` names one of them, or ``"auto"`` lets the data decide.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from identification.data.dataset import Dataset
from identification.data.end_caps import with_measured_states
from identification.discovery.scorer import LoopScorer

#: the ``method`` names: let the data decide, one-step regressions, trajectory fits
METHODS = ("auto", "regression", "trajectory")


def uses_trajectories(dataset: Dataset, method: str = "auto") -> bool:
    """Whether ``method`` on ``dataset`` is the multi-step (trajectory) scorer: named, or
    ``"auto"`` and some split has end caps only."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    end_caps_only = not all(s.has_states for s in dataset.splits.values())
    return method == "trajectory" or (method == "auto" and end_caps_only)


def choose_scorer(
    dataset: Dataset,
    method: str,
    regression: Callable[[Dataset], LoopScorer[Any]],
    trajectory: Callable[[Dataset], LoopScorer[Any]],
    smoothing: float = 0.01,
) -> tuple[Dataset, LoopScorer[Any]]:
    """The dataset the loop fits and the scorer that judges it (see the module docstring).

    Args:
        dataset: the measured data.
        method: one of :data:`METHODS` (:func:`uses_trajectories`).
        regression: makes the one-step scorer for the dataset with rod states.
        trajectory: makes the multi-step scorer for the measured dataset.
        smoothing: Gaussian smoothing std [s] of end caps into rod states, where a
            split has none and the one-step scorer is chosen.

    Only the chosen scorer is made (its settings' checks apply only then).
    """
    if uses_trajectories(dataset, method):
        return dataset, trajectory(dataset)
    states = with_measured_states(dataset, smoothing)
    return states, regression(states)
