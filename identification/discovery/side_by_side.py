"""The residual loop's candidates (or other independent fits) side by side, one worker
process each.

Every candidate of a pass is fitted from the same current model and independently of
the others, so the fits can run at once. Workers are **forked** from the running
loop: they start with its scorer, data and current model in memory (nothing is sent
to them but the candidate's index), and send back the fitted candidate or the
refusal that stopped it. A fork shares no state back: a fit's result depends only on
the current model and the candidate, so the candidates and their scores are the same
as fitted one after the other (``tests/unit/test_side_by_side.py``).

Where forking is unavailable (not Linux or macOS), or a worker dies (out of memory),
the candidates are fitted one after the other in the loop's own process.

:func:`side_by_side` does the same for any independent tasks (the two floor refits of
an accepted candidate).
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from functools import partial
from typing import Any, TypeVar

from identification.discovery.judge import Candidate
from identification.discovery.library import Proposal
from identification.discovery.scorer import CandidateSkipped
from tensegrity_env.io_utils import InputError

#: what stops one candidate's fit without stopping the loop (the candidate is skipped)
REFUSALS = (CandidateSkipped, RuntimeError, ValueError, InputError)

#: the tasks, set before the workers fork (read only in the workers)
_tasks: Sequence[Callable[[], Any]] | None = None

Outcome = Candidate[Any] | Exception
T = TypeVar("T")


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS says, else the count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def side_by_side(
    tasks: Sequence[Callable[[], T]], jobs: int, log: Callable[[str], None] = print
) -> list[T]:
    """``task()`` for every task, in ``jobs`` forked worker processes at most; the
    results in order (an exception a task raises is raised here)."""
    global _tasks
    workers = min(jobs, len(tasks))
    if workers > 1 and "fork" in multiprocessing.get_all_start_methods():
        _tasks = tasks
        try:
            context = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(workers, mp_context=context) as pool:
                return list(pool.map(_run_one, range(len(tasks))))
        except BrokenProcessPool:
            log("    a worker process died: the fits run one after the other")
        finally:
            _tasks = None
    return [task() for task in tasks]


def _run_one(index: int) -> Any:
    """The worker's task: the ``index``-th of the forked tasks."""
    assert _tasks is not None, "side_by_side sets the tasks before forking"
    return _tasks[index]()


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
    return side_by_side([partial(fitted, fit, p) for p in proposals], jobs, log)


def fitted(fit: Callable[[Proposal], Candidate[Any]], proposal: Proposal) -> Outcome:
    """``fit(proposal)`` with its wall time in ``seconds``, or the refusal that stopped it."""
    t0 = time.perf_counter()
    try:
        c = fit(proposal)
    except REFUSALS as e:
        return e
    c.seconds = time.perf_counter() - t0
    return c
