"""The closed loop: find the residual, trace it to the missing effect, add it, repeat.

Each iteration of :func:`diagnose`

1. looks at the current model's **residuals** on the training split
   (:mod:`identification.discovery.residuals`);
2. fits every **candidate** whose physical gate the data passes
   (:mod:`identification.discovery.candidates`), each jointly with everything already in
   the model, and scores it against "nothing is missing" (the current model) by
   the **held-out** one-step and rollout errors (validation split) and the
   **Bayesian information criterion** of the training one-step errors
   ``n ln(SSE / n) + k ln(n)``;
3. accepts the best candidate only if it lowers the BIC by at least
   :data:`MIN_BIC_DROP`, lowers the held-out one-step error by at least the
   fraction :data:`MIN_GAIN`, and its identified values are physical;
4. **flags** the attribution when the runner-up also passes and the two explain
   the same thing (their predicted changes correlate above
   :data:`AMBIGUOUS_CORRELATION` and their errors are within a factor
   :data:`AMBIGUOUS_RATIO`): the data cannot tell them apart;
5. stops when no candidate is accepted (the residual is noise, or nothing in the
   library explains it: then it is reported as unexplained);
6. when structure is left on noise-free data, fits a small **residual network**
   (:mod:`identification.discovery.residual_network`) jointly with the declared parameters and
   reports, if it lowers the held-out (test) one-step error, how much it absorbs: as
   unexplained, NOT as a physical effect. The loop's physical model is unchanged.

Errors before and after are measured on the **test** split, which selection never
sees.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from identification.data.dataset import Dataset
from identification.discovery.candidates import (
    FitSettings,
    FittedModel,
    Proposal,
    fit_model,
    fit_proposal,
    propose,
)
from identification.discovery.residual_network import ResidualFit, fit_residual_network
from identification.discovery.residuals import compute_residuals, plot_residuals, summarize
from identification.linear.extended import commands_for, evaluate_model
from identification.linear.features import transitions_of
from identification.report.tables import error_text
from tensegrity_env.effects import ResidualNetwork
from tensegrity_env.engine import Engine
from tensegrity_env.io_utils import InputError

#: a candidate must lower the BIC by this much ...
MIN_BIC_DROP = 10.0
#: ... and the held-out one-step error by this fraction
MIN_GAIN = 0.2
#: two accepted candidates whose predicted changes correlate above this ...
AMBIGUOUS_CORRELATION = 0.9
#: ... with held-out errors within this factor cannot be told apart
AMBIGUOUS_RATIO = 2.0
#: held-out one-step error [m] below which the residual is round-off (float64 at 1 ms);
#: errors and the BIC's mean square are floored there
ROUND_OFF = 1e-12


@dataclass
class Scored:
    """A fitted candidate (or the current model) and its scores.

    Attributes:
        name: the effect added (``"nothing"`` for the current model).
        model: the fitted model.
        val: held-out errors (see :func:`~identification.linear.extended.evaluate_model`).
        bic: information criterion of the training one-step errors.
        physical: the identified effect values pass their physical checks.
        seconds: fit wall time [s].
        gate: why the candidate may act here.
        accepted: it passes every test of :func:`_judge`.
        verdict: one line saying why it passes or not.
    """

    name: str
    model: FittedModel
    val: dict[str, Any]
    bic: float
    physical: bool = True
    seconds: float = 0.0
    gate: str = ""
    accepted: bool = False
    verdict: str = ""


@dataclass
class Iteration:
    """One pass of the loop.

    Attributes:
        before: the current model, scored.
        candidates: every candidate tried, scored (best first).
        skipped: candidates whose gate the data did not pass, with the reason.
        chosen: the accepted candidate, or None (the loop stops).
        ambiguous: the runner-up that cannot be told apart from ``chosen`` and the
            correlation of their predicted changes, or None.
        residual: residual summary of the current model (training split).
        plot: residual figure of the current model, if written.
        test_before, test_after: test-split errors of the model before and after.
    """

    before: Scored
    candidates: list[Scored]
    skipped: list[Proposal]
    chosen: Scored | None
    ambiguous: tuple[str, float] | None
    residual: dict[str, float]
    plot: Path | None
    test_before: dict[str, Any]
    test_after: dict[str, Any] | None = None


@dataclass
class DiagnoseResult:
    """Everything :func:`diagnose` found.

    Attributes:
        iterations: the loop's passes, in order.
        model: the final model.
        baseline_test, final_test: test-split errors of the declared model and the final one.
        final_residual: residual summary of the final model, and its plot.
        unexplained: why structure is left (empty if the residual is noise).
        residual_network: the residual network fitted to what is left, when it lowers
            the held-out (test) one-step error (see :mod:`identification.discovery.residual_network`;
            NOT a physical effect, not part of ``model``), else None.
    """

    iterations: list[Iteration]
    model: FittedModel
    baseline_test: dict[str, Any]
    final_test: dict[str, Any]
    final_residual: dict[str, float]
    final_plot: Path | None
    unexplained: str = ""
    settings: dict[str, Any] = field(default_factory=dict)
    residual_network: ResidualFit | None = None


def one_step_bic(dataset: Dataset, model: FittedModel, max_transitions: int = 20_000) -> float:
    """``n ln(SSE/n) + k ln(n)`` of the one-step position errors on the training split."""
    data = dataset.split("train")
    N, T = data.n_trajectories, data.n_transitions
    rng = np.random.default_rng(1)
    idx = np.sort(rng.choice(N * T, size=min(N * T, max_transitions), replace=False))
    s0, s1, _ = transitions_of(data, idx)
    u = commands_for(model.effects, torch.as_tensor(data.control), dataset.dt)[idx // T, idx % T]
    with torch.no_grad():
        pred = Engine(dataset.topology, dataset.dt, effects=model.effects).step(s0, model.params, u)
    err = (pred.p - s1.p).reshape(-1).numpy()
    n = err.size
    sse = float(np.sum(err**2))
    if not np.isfinite(sse):
        return float("inf")
    return n * np.log(max(sse / n, ROUND_OFF**2)) + model.n_params * np.log(n)


def predicted_change(dataset: Dataset, a: FittedModel, b: FittedModel, split: str) -> np.ndarray:
    """One-step predictions of ``b`` minus ``a`` on a split's transitions, flattened."""
    data = dataset.split(split)
    N, T = data.n_trajectories, data.n_transitions
    idx = np.sort(np.random.default_rng(2).choice(N * T, size=min(N * T, 5000), replace=False))
    s0, _, _ = transitions_of(data, idx)
    out = []
    for m in (a, b):
        u = commands_for(m.effects, torch.as_tensor(data.control), dataset.dt)[idx // T, idx % T]
        with torch.no_grad():
            out.append(
                Engine(dataset.topology, dataset.dt, effects=m.effects).step(s0, m.params, u).v
            )
    return (out[1] - out[0]).reshape(-1).numpy()


def _corr(x: np.ndarray, y: np.ndarray) -> float:
    sx, sy = x.std(), y.std()
    return float(np.mean((x - x.mean()) * (y - y.mean())) / (sx * sy)) if sx > 0 and sy > 0 else 0.0


def _score(
    dataset: Dataset, name: str, model: FittedModel, val_split: str, horizon_s: float
) -> Scored:
    val = evaluate_model(
        dataset.topology, model.params, model.effects, dataset, val_split, horizon_s
    )
    return Scored(name, model, val, one_step_bic(dataset, model),
                  physical=all(e.physical() for e in model.effects))  # fmt: skip


def diagnose(
    dataset: Dataset,
    settings: FitSettings,
    start_effects: Sequence[Any] = (),
    max_effects: int = 3,
    horizon_s: float = 1.0,
    candidates: Sequence[str] | None = None,
    plots: Path | None = None,
    log: Callable[[str], None] = print,
    residual_network: bool = True,
) -> DiagnoseResult:
    """Run the loop on a dataset with rod states (see the module docstring).

    ``residual_network``: when structure is left on noise-free data, fit a residual
    network to it (a few seconds; False: only say that structure is left).
    """
    val_split = "val" if "val" in dataset.splits else "test"
    test_split = "test" if "test" in dataset.splits else val_split
    if any(isinstance(e, ResidualNetwork) for e in start_effects):
        log("starting effects: a residual network is not a physical effect; left out")
        start_effects = [e for e in start_effects if not isinstance(e, ResidualNetwork)]
    model = fit_model(dataset, list(start_effects), settings)
    baseline = evaluate_model(
        dataset.topology, model.params, model.effects, dataset, test_split, horizon_s
    )
    current = _score(dataset, "nothing", model, val_split, horizon_s)
    log(f"declared model{' + ' + ', '.join(model.names) if model.names else ''}: held-out "
        f"one-step {error_text(current.val['one_step'], '.3e')}, {horizon_s:g}-s rollout "
        f"{error_text(current.val['rollout'], '.3e')}")  # fmt: skip
    iterations: list[Iteration] = []
    test_now = baseline
    for k in range(max_effects + 1):
        res = compute_residuals(
            dataset.topology, current.model.params, current.model.effects, dataset
        )
        summary = summarize(res)
        plot = None
        if plots is not None:
            plot = plot_residuals(res, plots / f"residuals_{k}.png",
                                  f"iteration {k}: residuals of {_label(current.model)}")  # fmt: skip
        if k == max_effects:
            return _finish(iterations, current, baseline, test_now, summary, plot, dataset,
                           settings, horizon_s, residual_network, log)  # fmt: skip
        proposals = propose(dataset, current.model, settings, candidates)
        tried: list[Scored] = []
        skipped = [p for p in proposals if p.effects is None]
        for p in proposals:
            if p.effects is None:
                continue
            t0 = time.perf_counter()
            try:
                fitted = fit_proposal(dataset, p, settings)
            except (RuntimeError, ValueError, InputError) as e:  # a singular or failed fit
                skipped.append(Proposal(p.name, None, f"fit failed: {e}"))
                continue
            s = _score(dataset, p.name, fitted, val_split, horizon_s)
            s.seconds, s.gate = time.perf_counter() - t0, p.gate
            _judge(s, current)
            log(f"  candidate {p.name:20s} one-step {error_text(s.val['one_step'], '.3e')}, "
                f"rollout {error_text(s.val['rollout'], '.3e')}, ΔBIC {s.bic - current.bic:+.3g}: {s.verdict} ({s.seconds:.1f} s)")  # fmt: skip
            tried.append(s)
        tried.sort(key=lambda s: (not s.accepted, _finite(s.val["one_step"])))
        chosen = tried[0] if tried and tried[0].accepted else None
        ambiguous = None
        if chosen is not None and len(tried) > 1 and tried[1].accepted:
            runner = tried[1]
            ratio = _finite(runner.val["one_step"]) / max(_finite(chosen.val["one_step"]), 1e-300)
            corr = _corr(
                predicted_change(dataset, current.model, chosen.model, val_split),
                predicted_change(dataset, current.model, runner.model, val_split),
            )
            if corr > AMBIGUOUS_CORRELATION and ratio < AMBIGUOUS_RATIO:
                ambiguous = (runner.name, corr)
        it = Iteration(current, tried, skipped, chosen, ambiguous, summary, plot, test_now)
        iterations.append(it)
        if chosen is None:
            return _finish(iterations, current, baseline, test_now, summary, plot, dataset,
                           settings, horizon_s, residual_network, log)  # fmt: skip
        test_now = evaluate_model(dataset.topology, chosen.model.params, chosen.model.effects,
                                  dataset, test_split, horizon_s)  # fmt: skip
        it.test_after = test_now
        log(f"added {chosen.name}" + (f" (cannot be told apart from {ambiguous[0]}, "
                                      f"correlation {ambiguous[1]:.2f})" if ambiguous else ""))  # fmt: skip
        current = chosen
    raise AssertionError("unreachable")


def _finite(x: float) -> float:
    return x if np.isfinite(x) else float("inf")


def _judge(s: Scored, current: Scored) -> None:
    floor = ROUND_OFF  # below it, differences are round-off
    gain = 1 - max(_finite(s.val["one_step"]), floor) / max(_finite(current.val["one_step"]), floor)
    drop = current.bic - s.bic
    if not s.physical:
        s.verdict = "rejected: identified values are unphysical"
    elif not np.isfinite(s.val["one_step"]) or drop < MIN_BIC_DROP:
        s.verdict = f"rejected: BIC does not drop by {MIN_BIC_DROP:g}"
    elif gain < MIN_GAIN:
        s.verdict = f"rejected: held-out one-step error improves only {gain:.0%}"
    else:
        s.accepted = True
        s.verdict = f"passes (one-step error -{gain:.1%})"


def _label(model: FittedModel) -> str:
    return "declared model" + ("".join(f" + {n}" for n in model.names))


def _finish(
    iterations: list[Iteration], current: Scored, baseline: dict[str, Any], test_now: dict[str, Any],
    summary: dict[str, float], plot: Path | None, dataset: Dataset, settings: FitSettings,
    horizon_s: float, residual_network: bool, log: Callable[[str], None],
) -> DiagnoseResult:  # fmt: skip
    err = current.val["one_step"]
    unexplained = ""
    network = None
    if err > ROUND_OFF and dataset.attrs.get("measurement_noise_std", 0) == 0:
        unexplained = (
            f"held-out one-step error {err:.2e} m is above round-off on noise-free data: "
            "structure remains that no candidate in the library explains"
        )
        if residual_network:
            network, note = _absorb(dataset, current.model, settings, horizon_s, log)
            unexplained += note
    return DiagnoseResult(
        iterations=iterations, model=current.model, baseline_test=baseline, final_test=test_now,
        final_residual=summary, final_plot=plot, unexplained=unexplained,
        settings={"anchors": dict(settings.anchors), "min_gain": MIN_GAIN,
                  "min_bic_drop": MIN_BIC_DROP}, residual_network=network,
    )  # fmt: skip


def _absorb(
    dataset: Dataset, model: FittedModel, settings: FitSettings, horizon_s: float,
    log: Callable[[str], None],
) -> tuple[ResidualFit | None, str]:  # fmt: skip
    """Fit the residual network; keep it if it lowers the test one-step error. (fit, note)"""
    val_split = "val" if "val" in dataset.splits else "test"
    test_split = "test" if "test" in dataset.splits else val_split
    try:
        fit = fit_residual_network(
            dataset, model, settings, val_split=val_split,
            eval_splits=tuple(dict.fromkeys((val_split, test_split))), horizon_s=horizon_s,
            seed=settings.seed, log=log,
        )  # fmt: skip
    except (RuntimeError, ValueError, InputError) as e:
        return None, f"; a residual network could not be fitted ({e})"
    b, a = fit.before[test_split]["one_step"], fit.after[test_split]["one_step"]
    if not np.isfinite(a) or a >= b:
        return None, (f"; a residual network does not absorb it (held-out one-step "
                      f"{b:.2e} m -> {a:.2e} m)")  # fmt: skip
    return fit, (
        f"; a residual network absorbs it: held-out (test) one-step {b:.2e} m -> {a:.2e} m "
        f"({b / a:.3g}x), NOT a physical effect (the declared parameters refitted with it "
        f"move by {', '.join(f'{k} {v:.0%}' for k, v in fit.moved.items())})"
    )
