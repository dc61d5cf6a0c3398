"""Independent tasks in forked worker processes: the window groups of a large windowed
fit (:mod:`identification.trajectory.windowed_fit`) and the residual loop's candidates
(:mod:`identification.discovery.side_by_side`).

Workers are **forked** from the running process: they start with its data and models
in memory (nothing is sent to them but a task's index) and send back the task's result.
A task running in a worker runs any tasks of its own one after the other: the cores are
taken by its siblings. Where forking is unavailable (not Linux or macOS), or a worker
dies (out of memory), the tasks run one after the other in the calling process.

How many workers the window groups of one fit get is set for a block of work with
:func:`window_workers` (the CLI's ``--jobs``), and only groups of at least
:data:`MIN_FORKED_WORK` go to workers (a fork costs CPU time; a trial point's errors
are far cheaper than a fork); the groups themselves depend only on the
fit's sizes (:func:`~identification.trajectory.windowed_fit.group_size`,
:func:`window_groups`), so a fit's arithmetic, and its result, is the same whatever the
number of workers.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from itertools import pairwise
from typing import Any

#: the tasks, set before the workers fork (read only in the workers)
_tasks: Sequence[Callable[[], Any]] | None = None
#: True in a forked worker: its own tasks run one after the other
_in_worker = False
#: workers for the window groups of one fit (:func:`window_workers`)
_window_jobs = 1
#: window groups of less work than this [assembly-samples: windows x rolled-out copies x
#: samples per window] run in the calling process: forking two workers costs as much CPU
#: as about 21,000 assembly-samples of a linearization, six times a trial point's errors
#: on the final floor refit's windows; from here the fork adds less than a tenth
#: (``bench_window_groups.py``; docs/decisions.md)
MIN_FORKED_WORK = 100_000


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS says, else the count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def side_by_side(
    tasks: Sequence[Callable[[], Any]], jobs: int, log: Callable[[str], None] = print
) -> list[Any]:
    """``task()`` for every task, in ``jobs`` forked worker processes at most; the
    results in order (an exception a task raises is raised here). Tasks may return
    different types (a caller unpacks the list)."""
    global _tasks
    workers = 1 if _in_worker else min(jobs, len(tasks))
    if workers > 1 and "fork" in multiprocessing.get_all_start_methods():
        _tasks = tasks
        try:
            context = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(workers, mp_context=context) as pool:
                return list(pool.map(_run_one, range(len(tasks))))
        except BrokenProcessPool:
            log("    a worker process died: the tasks run one after the other")
        finally:
            _tasks = None
    return [task() for task in tasks]


def _run_one(index: int) -> Any:
    """The worker's task: the ``index``-th of the forked tasks."""
    global _in_worker
    assert _tasks is not None, "side_by_side sets the tasks before forking"
    _in_worker = True
    return _tasks[index]()


@contextmanager
def window_workers(jobs: int) -> Iterator[None]:
    """Within the block, the window groups of a fit run in up to ``jobs`` workers."""
    global _window_jobs
    before, _window_jobs = _window_jobs, max(1, int(jobs))
    try:
        yield
    finally:
        _window_jobs = before


def window_jobs(work: int | None = None) -> int:
    """Workers the window groups of a fit may use here: 1 inside a worker, and 1 where
    each group's ``work`` [assembly-samples: windows x rolled-out copies x samples] is
    below :data:`MIN_FORKED_WORK` (None: large)."""
    if _in_worker or (work is not None and work < MIN_FORKED_WORK):
        return 1
    return _window_jobs


def in_worker() -> bool:
    """Whether this process is a forked worker (its siblings share the terminal)."""
    return _in_worker


def window_groups(size: int, most: int) -> list[slice]:
    """``size`` windows in the fewest groups of at most ``most``, of equal sizes (the
    first ones one larger); 48 windows at most 38 per group: two of 24."""
    n = max(1, -(-size // max(1, most)))
    base, extra = divmod(size, n)
    edges = [0]
    for k in range(n):
        edges.append(edges[-1] + base + (k < extra))
    return [slice(a, b) for a, b in pairwise(edges)]
