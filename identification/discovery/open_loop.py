"""``diagnose``'s check before writing: the model it found rolled out open-loop, and the fallback.

The loop judges candidates on windows with fitted initial states; its final model can
still leave the data when rolled out from measured states
(:mod:`identification.trajectory.open_loop_check`). :func:`keep_not_diverged` checks the
final model and, where it diverges, the models the loop passed through before it (newest
first: before the final refit, each iteration's, the declared fit), and returns the
result with the first that does not diverge, saying so; where every one diverges,
nothing is written (:class:`~tensegrity_env.io_utils.StageError`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

from identification.data.dataset import Dataset
from identification.discovery.loop import DiscoveryResult
from identification.discovery.scorer import LoopScorer
from identification.trajectory.open_loop_check import check_open_loop, open_loop_check
from identification.trajectory.stage_check import noise_level

ADVICE = ("a fit on the free stretches only (import-mocap --segments), shorter windows "
          "(--window), or a smaller --physics-dt")  # fmt: skip


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
    noise = getattr(scorer, "noise", None)
    if noise is None:
        noise = noise_level(dataset.split("train").nodes, rods=True)
    final = open_loop_check(result.model.model, dataset, float(noise), physics_dt)
    if final is None:
        return result
    log(final.line())
    if not final.diverged:
        return replace(result, open_loop=f"The final model rolled out: {final.line()}.")
    for k, cand in enumerate(result.earlier):
        check = open_loop_check(cand.model.model, dataset, float(noise), physics_dt)
        if check is not None and not check.diverged:
            which = "the declared model's fit" if k == len(result.earlier) - 1 else (
                f"the model with {', '.join(cand.model.names) or 'no effects'}")  # fmt: skip
            note = (f"The final model ({', '.join(result.model.names) or 'no effects'}) diverges "
                    f"open-loop ({final.line()}): written instead is the last model that does "
                    f"not, {which}: {check.line()}.")  # fmt: skip
            log(note)
            return replace(result, model=cand.model, final_test=scorer.test_errors(cand),
                           residual_network=None, open_loop=note)  # fmt: skip
    check_open_loop("diagnose's models (the final one and every one before it)", final, ADVICE)
    return result  # not reached: check_open_loop raised on the diverged final model
