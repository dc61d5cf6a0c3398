"""``diagnose``'s check before writing: the model it found rolled out open-loop, and the fallback.

The loop judges candidates on windows with fitted initial states; its final model can
still leave the data when rolled out from measured states
(:mod:`identification.trajectory.open_loop_check`). :func:`keep_not_diverged` checks the
final model and, where it diverges, the models the loop passed through before it (newest
first: before the final refit, each iteration's, the declared fit), and returns the
result with the first that does not diverge, saying so; where every one diverges,
nothing is written (:class:`~tensegrity_env.io_utils.StageError`).

The loop's criteria (held-out chi-square and BIC on short windows, each with a fitted
initial state) can pass an effect that absorbs a short window's misfit and predicts
worse over a longer horizon; the final refit is judged by nothing. :func:`keep_predicting`
walks the models the loop passed through, oldest first (the declared fit, each
iteration's, before the final refit, the final one), and keeps a newer model only where
its open-loop prediction of the validation split from measured states is no worse, at
every horizon the benchmarks read
(:data:`~identification.trajectory.open_loop_check.HORIZONS_S`), than the model kept
before it (by more than the noise level).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

from identification.data.dataset import Dataset
from identification.discovery.loop import DiscoveryResult
from identification.discovery.scorer import LoopScorer
from identification.trajectory.open_loop_check import (
    HORIZONS_S,
    OpenLoopCheck,
    check_not_worse_than_start,
    check_open_loop,
    open_loop_check,
    worse_prediction,
)
from identification.trajectory.stage_check import noise_level
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model

ADVICE = ("a fit on the free stretches only (import-mocap --segments), shorter windows "
          "(--window), or a smaller --physics-dt")  # fmt: skip


def _noise(scorer: LoopScorer[Any], dataset: Dataset) -> float:
    """The data's noise level [m]: the scorer's where it has one, else from the training
    split's rod lengths."""
    noise = getattr(scorer, "noise", None)
    if noise is None:
        noise = noise_level(dataset.split("train").nodes, rods=True)
    return float(noise)


def keep_not_diverged(
    result: DiscoveryResult,
    scorer: LoopScorer[Any],
    dataset: Dataset,
    physics_dt: float | None,
    log: Callable[[str], None] = print,
) -> DiscoveryResult:
    """``result`` with its ``open_loop`` line set, and where its model diverges open-loop,
    with the last earlier model that does not (its test errors scored again, no residual
    network: that was fitted beside the diverged model). ``physics_dt``: the longest
    physics step [s] of the rollouts. Raises ``StageError`` when every model diverges."""
    noise = _noise(scorer, dataset)
    final = open_loop_check(result.model.model, dataset, float(noise), physics_dt)
    if final is None:
        return result
    log(final.line())
    if not final.diverged:
        return replace(result, open_loop=f"The final model rolled out: {final.line()}.")
    for k, cand in enumerate(result.earlier):
        if not _physical(cand.model.model.params, dataset):
            continue
        check = open_loop_check(cand.model.model, dataset, float(noise), physics_dt)
        if check is not None and not check.diverged:
            last = k == len(result.earlier) - 1
            which = "the declared model's fit" if last else _label(cand.model.names)
            note = (f"The final model ({', '.join(result.model.names) or 'no effects'}) diverges "
                    f"open-loop ({final.line()}): written instead is the last model that does "
                    f"not, {which}: {check.line()}.")  # fmt: skip
            log(note)
            return replace(result, model=cand.model, final_test=scorer.test_errors(cand),
                           residual_network=None, open_loop=note)  # fmt: skip
    check_open_loop("diagnose's models (the final one and every one before it)", final, ADVICE)
    return result  # not reached: check_open_loop raised on the diverged final model


def _label(names: list[str]) -> str:
    return f"the model with {', '.join(names) or 'no effects'}"


def _physical(params: Any, dataset: Dataset) -> bool:
    """Whether ``params`` lie in the physical domain of ``dataset``'s topology
    (:meth:`~tensegrity_env.params.Params.validate`)."""
    try:
        params.validate(dataset.topology)
    except InputError:
        return False
    return True


def keep_predicting(
    result: DiscoveryResult,
    scorer: LoopScorer[Any],
    dataset: Dataset,
    physics_dt: float | None,
    log: Callable[[str], None] = print,
) -> DiscoveryResult:
    """``result``, or where its model predicts the validation split open-loop worse than
    a model the loop passed through before it, the newest model that does not (see the
    module docstring; its test errors scored again, no residual network). Unchanged where
    the data has no validation split or nothing was rolled out, and on recorded rod states:
    there the loop's own held-out errors start from the exact states, where a rollout from
    a mid-trajectory start would miss what the data does not hold (an actuator filter's
    state). A model outside the physical domain is never kept."""
    if "val" not in dataset.splits or not result.earlier or dataset.split("val").has_states:
        return result
    noise = _noise(scorer, dataset)
    chain: list[Any] = [*reversed(result.earlier), None]  # oldest first; None: the final model
    if any(c is not None and c.model is result.model for c in chain):  # fell back already
        chain = chain[
            : next(i for i, c in enumerate(chain) if c is not None and c.model is result.model) + 1
        ]
    checks: list[OpenLoopCheck | None] = []
    for c in chain:
        model = result.model.model if c is None else c.model.model
        physical = _physical(model.params, dataset)
        checks.append(open_loop_check(model, dataset, float(noise), physics_dt, ("val",))
                      if physical or c is None else None)  # fmt: skip

    def label(i: int) -> str:
        names = (result.model if chain[i] is None else chain[i].model).names
        if chain[i] is None:
            return f"the final model ({', '.join(names) or 'no effects'})"
        if i == 0:
            return f"the declared model's fit ({', '.join(names) or 'no effects'})"
        if i == len(chain) - 2 and names == result.model.names:
            return "the same model before the final refit"
        return _label(names)

    # the oldest model rolled out (one outside the physical domain is not) is kept first
    kept = next((i for i, c in enumerate(checks) if c is not None), len(chain) - 1)
    lines = []
    for i in range(kept + 1, len(chain)):
        new, old = checks[i], checks[kept]
        if new is None or old is None:
            continue
        why = worse_prediction(new, old)
        if why:
            lines.append(f"{label(i)} predicts worse than {label(kept)}: {why}")
        else:
            kept = i
    if checks[-1] is not None:
        errs = ", ".join("-" if v is None else f"{v * 1e3:.3g}" for v in checks[-1].at())
        log(
            f"held-out prediction on 'val' at {', '.join(f'{h:g}' for h in HORIZONS_S)} s: "
            f"end-cap RMS {errs} mm ({label(len(chain) - 1)})"
        )
    if chain[kept] is None or kept == len(chain) - 1:
        return result
    cand = chain[kept]
    errs = ", ".join("-" if v is None else f"{v * 1e3:.3g}" for v in checks[kept].at())  # type: ignore[union-attr]
    note = (
        f"Written instead of {label(len(chain) - 1)}: {label(kept)}, the newest model "
        f"that predicts the validation split open-loop no worse than the one kept before it "
        f"(end-cap RMS {errs} mm at {', '.join(f'{h:g}' for h in HORIZONS_S)} s); "
        + "; ".join(lines)
        + "."
    )
    log(note)
    prefix = f"{result.open_loop} " if result.open_loop else ""
    return replace(result, model=cand.model, final_test=scorer.test_errors(cand), residual_network=None,
                   open_loop=prefix + note)  # fmt: skip


def check_against_start(
    result: DiscoveryResult,
    scorer: LoopScorer[Any],
    dataset: Dataset,
    physics_dt: float | None,
    start: Model,
) -> None:
    """Raise :class:`~tensegrity_env.io_utils.StageError` where the model to be written
    predicts the validation split open-loop worse than the ``start`` model the user gave
    at every horizon (:func:`~identification.trajectory.open_loop_check.check_not_worse_than_start`);
    on recorded rod states nothing is checked (as :func:`keep_predicting`)."""
    if any(dataset.split(s).has_states for s in dataset.splits):
        return
    check_not_worse_than_start("diagnose", result.model.model, start, dataset,
                               _noise(scorer, dataset), physics_dt)  # fmt: skip
