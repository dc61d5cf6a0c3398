"""What a study leaves beside it: the best settings, a summary, two plots.

:func:`write_report` writes into the study's output folder::

    best_<algo>.yml                 the best complete trial's settings, a hyperparameter
                                    file (``tensegrity-sr train --hyperparams``)
    study.json                      every trial: number, state, value, success rate,
                                    parameters, wall time, run folder, host, and the
                                    hyperparameter file of an enqueued trial
    optimization_history.png        value per trial and best so far
    param_importances.png           importance of each parameter (fANOVA with
                                    scikit-learn installed, else PED-ANOVA)

Plots are drawn by :mod:`optuna.visualization.matplotlib` and need at least two
complete trials (importances: parameters that vary among them).
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from typing import Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from policies.tuning.objective import write_hyperparams
from tensegrity_env.io_utils import atomic_path, atomic_write_text


def trial_row(t: FrozenTrial) -> dict[str, Any]:
    """One trial as plain data."""
    value = t.value if t.value is not None and math.isfinite(t.value) else None
    return {
        "number": t.number,
        "state": t.state.name,
        "value": value,
        "success_rate": t.user_attrs.get("success_rate"),
        "params": t.params,
        "wall_s": t.user_attrs.get("wall_s"),
        "timesteps": t.user_attrs.get("timesteps"),
        "run_folder": t.user_attrs.get("run_folder"),
        "host": t.user_attrs.get("host"),
        "error": t.user_attrs.get("error"),
        "enqueued": t.user_attrs.get("enqueued"),
    }


def summary(study: optuna.Study, storage: str, settings: dict[str, Any]) -> dict[str, Any]:
    """The study as plain data: settings, counts per state, best trial, all trials."""
    trials = study.get_trials(deepcopy=False)
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    return {
        "study_name": study.study_name,
        "storage": storage,
        "direction": "maximize",
        "objective": "mean return of the last deterministic evaluation",
        "settings": settings,
        "counts": {s.name: sum(t.state == s for t in trials) for s in TrialState},
        "best": trial_row(study.best_trial) if complete else None,
        "trials": [trial_row(t) for t in trials],
    }


def save_figure(ax: Any, path: Path) -> Path:
    """Save the figure of ``ax`` as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    fig = ax.figure
    fig.set_size_inches(8, 5)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return path


def importance_evaluator() -> Any:
    """fANOVA (Optuna's default) where scikit-learn is installed, else PED-ANOVA."""
    import importlib.util

    if importlib.util.find_spec("sklearn") is not None:
        return optuna.importance.FanovaImportanceEvaluator(seed=0)
    return optuna.importance.PedAnovaImportanceEvaluator()


def plot_study(study: optuna.Study, out: Path) -> list[Path]:
    """Optimization history and parameter importances as PNG (those that can be drawn)."""
    import matplotlib

    matplotlib.use("Agg")
    from optuna.visualization import matplotlib as ovm

    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(complete) < 2:
        return []
    written = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        written.append(save_figure(ovm.plot_optimization_history(study), out / "optimization_history.png"))
        try:
            ax = ovm.plot_param_importances(study, evaluator=importance_evaluator())
            written.append(save_figure(ax, out / "param_importances.png"))
        except (ValueError, RuntimeError) as e:  # e.g. no parameter varies among the trials
            print(f"no parameter importances: {e}")
    return written


def write_report(
    study: optuna.Study, out: Path, algo: str, env_id: str, storage: str,
    settings: dict[str, Any],
) -> list[Path]:  # fmt: skip
    """Write best settings, summary and plots into ``out``; returns the files written."""
    written = []
    doc = summary(study, storage, settings)
    written.append(atomic_write_text(out / "study.json", json.dumps(doc, indent=2) + "\n"))
    best = doc["best"]
    if best is not None:
        entry = study.best_trial.user_attrs["hyperparams"]
        header = (
            f"best of study {study.study_name!r} ({storage}): trial {best['number']}, "
            f"mean return {best['value']:.3f}"
            + (f", success {best['success_rate']:.2f}" if best["success_rate"] is not None else "")
            + f"\nafter {settings.get('timesteps')} env steps; run folder {best['run_folder']}"
        )
        path = out / f"best_{algo}.yml"
        write_hyperparams(path, env_id, entry, header)
        written.append(path)
    written += plot_study(study, out)
    return written
