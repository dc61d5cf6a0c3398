"""The residual loop's candidates fitted side by side, one worker process each.

Every candidate of a pass is fitted from the same current model and independently of
the others, so the fits can run at once. Workers are **forked** from the running
loop: they start with its scorer, data and current model in memory (nothing is sent
to them but the candidate's index), and send back the fitted candidate or the
refusal that stopped it. A fork shares no state back: a fit's result depends only on
the current model and the candidate, so the candidates and their scores are the same
as fitted one after the other (``tests/unit/test_side_by_side.py``).

Where forking is unavailable (not Linux or macOS), or a worker dies (out of memory),
the candidates are fitted one after the other in the loop's own process.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from identification.discovery.judge import Candidate
from identification.discovery.library import Proposal
from identification.discovery.scorer import CandidateSkipped
from tensegrity_env.io_utils import InputError

#: what stops one candidate's fit without stopping the loop (the candidate is skipped)
REFUSALS = (CandidateSkipped, RuntimeError, ValueError, InputError)

#: the fit and its proposals, set before the workers fork (read only in the workers)
_job: tuple[Callable[[Proposal], Candidate[Any]], Sequence[Proposal]] | None = None

Outcome = Candidate[Any] | Exception


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS says, else the count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def fit_side_by_side(
    fit: Callable[[Proposal], Candidate[Any]],
    proposals: Sequence[Proposal],
    jobs: int,
    log: Callable[[str], None] = print,
) -> list[Outcome]:
    """``fit(p)`` for every proposal, in ``jobs`` worker processes at most.

    Returns, per proposal in order, the candidate (its ``seconds`` set to its fit's wall
    time) or the refusal (:data:`REFUSALS`) that stopped its fit.
    """
    global _job
    workers = min(jobs, len(proposals))
    if workers > 1 and "fork" in multiprocessing.get_all_start_methods():
        _job = (fit, proposals)
        try:
            context = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(workers, mp_context=context) as pool:
                return list(pool.map(_fit_one, range(len(proposals))))
        except BrokenProcessPool:
            log("    a worker process died: the candidates are fitted one after the other")
        finally:
            _job = None
    return [fitted(fit, p) for p in proposals]


def _fit_one(index: int) -> Outcome:
    """The worker's task: the ``index``-th proposal of the forked job."""
    assert _job is not None, "fit_side_by_side sets the job before forking"
    fit, proposals = _job
    return fitted(fit, proposals[index])


def fitted(fit: Callable[[Proposal], Candidate[Any]], proposal: Proposal) -> Outcome:
    """``fit(proposal)`` with its wall time in ``seconds``, or the refusal that stopped it."""
    t0 = time.perf_counter()
    try:
        c = fit(proposal)
    except REFUSALS as e:
        return e
    c.seconds = time.perf_counter() - t0
    return c
