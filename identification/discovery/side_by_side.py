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
the candidates are fitted one after the other in the loop's own process
(:func:`identification.trajectory.forked.side_by_side`, which also runs the two floor
refits of an accepted candidate).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

from identification.discovery.judge import Candidate
from identification.discovery.library import Proposal
from identification.discovery.scorer import CandidateSkipped
from identification.trajectory.forked import side_by_side
from tensegrity_env.effects.base import LinearEffect
from tensegrity_env.io_utils import InputError

#: what stops one candidate's fit without stopping the loop (the candidate is skipped)
REFUSALS = (CandidateSkipped, RuntimeError, ValueError, InputError)

Outcome = Candidate[Any] | Exception


def fit_side_by_side(
    fit: Callable[[Proposal], Candidate[Any]],
    proposals: Sequence[Proposal],
    jobs: int,
    log: Callable[[str], None] = print,
) -> list[Outcome]:
    """``fit(p)`` for every proposal, in ``jobs`` worker processes at most, the dearest
    first (:func:`expected_cost`: a worker freed by a cheap fit then takes the next
    one while a dear one runs, instead of a dear one starting last).

    Returns, per proposal in order, the candidate (its ``seconds`` set to its fit's wall
    time) or the refusal (:data:`REFUSALS`) that stopped its fit.
    """
    order = sorted(range(len(proposals)), key=lambda i: expected_cost(proposals[i]), reverse=True)
    done = side_by_side([partial(fitted, fit, proposals[i]) for i in order], jobs, log)
    by_index = dict(zip(order, done, strict=True))
    return [by_index[i] for i in range(len(proposals))]


def expected_cost(proposal: Proposal) -> tuple[bool, int]:
    """How dear a proposal's fit is expected to be, for ordering: one started from its
    own values (slack cables from their regression: on the floor, a floor fit afresh)
    above the rest, then more fitted coordinates above fewer (cubic stiffness, one per
    spring, took the longest of a floor pass)."""
    effect = proposal.effect
    coordinates = len(effect.theta_names()) if isinstance(effect, LinearEffect) else 0  # the abstract base: theta() holds its coordinates
    return proposal.start is not None, coordinates


def fitted(fit: Callable[[Proposal], Candidate[Any]], proposal: Proposal) -> Outcome:
    """``fit(proposal)`` with its wall time in ``seconds``, or the refusal that stopped it."""
    t0 = time.perf_counter()
    try:
        c = fit(proposal)
    except REFUSALS as e:
        return e
    c.seconds = time.perf_counter() - t0
    return c
