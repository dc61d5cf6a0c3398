"""The residual loop's interface to the data: how models are fitted and scored.

:class:`Scorer` is the core the loop runs on: begin with the declared model, propose
the library's gated candidates, fit a candidate, accept the chosen one, and the
held-out test errors. Beside it, three small interfaces: :class:`Judged` (how two
fits' held-out errors compare, read by the judge), :class:`Reported` (what the report
shows) and :class:`Refined` (optional steps with defaults: a second look, a refusal,
a final refit). :class:`LoopScorer` is all four, what
:class:`~identification.discovery.loop.EffectDiscovery` takes;
:class:`~identification.discovery.one_step.OneStepScorer` (one-step regressions on rod
states) and :class:`~identification.discovery.multi_step.MultiStepScorer` (multi-step
prediction of measured end caps through the engine) implement it.
:func:`~identification.discovery.choose.choose_scorer` picks one for a dataset.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from identification.data.dataset import Dataset
from identification.discovery.judge import Candidate, Criteria
from identification.discovery.library import Proposal
from identification.discovery.residual_network import ResidualFit
from tensegrity_env.engine import State

F = TypeVar("F")


class CandidateSkipped(Exception):
    """A scorer's refusal to judge a candidate; the message says why (one line)."""


@dataclass
class Residual:
    """What the current model leaves: numbers, the same as markdown, and a figure.

    Attributes:
        numbers: residual signatures by name (the scorer's).
        markdown: the same for the report.
        plot: PNG of the residuals, if written.
    """

    numbers: dict[str, float]
    markdown: str
    plot: Path | None = None


class Scorer(ABC, Generic[F]):
    """The loop's core: how models are fitted on one kind of data.

    ``F`` is what the scorer fits (kept in :attr:`Candidate.fit`). :meth:`begin` binds
    a dataset; every other method works on the dataset last begun.
    """

    #: how the held-out gain is judged
    criteria: Criteria
    #: the scorer's name in reports and params files
    method: str

    @abstractmethod
    def begin(self, dataset: Dataset, log: Callable[[str], None]) -> Candidate[F]:
        """The declared model fitted on ``dataset`` and scored (named ``"nothing"``)."""

    @abstractmethod
    def propose(self, current: Candidate[F], names: Sequence[str] | None) -> list[Proposal]:
        """The library's candidates not in ``current`` (``names``: only these), gated."""

    @abstractmethod
    def fit_candidate(
        self, current: Candidate[F], proposal: Proposal, drop: Sequence[str] = ()
    ) -> Candidate[F]:
        """``current`` plus the proposed effect, fitted jointly and scored on held-out
        data; ``drop``: effects of ``current`` left out (the candidate in place of them).

        Raises :class:`CandidateSkipped` when the fit cannot be judged (it diverged).
        """

    @abstractmethod
    def accept(self, chosen: Candidate[F]) -> Candidate[F]:
        """The chosen candidate as the next current model (refitted where the scorer does)."""

    @abstractmethod
    def test_errors(self, current: Candidate[F]) -> dict[str, Any]:
        """Errors [m] of ``current``'s model on the test split (never used for selection)."""


class Judged(ABC, Generic[F]):
    """How two scored candidates' held-out errors compare (read by the judge)."""

    @abstractmethod
    def gain(self, candidate: Candidate[F], current: Candidate[F]) -> float:
        """How much ``candidate`` lowers the held-out error (the criteria's unit)."""

    @abstractmethod
    def rank(self, candidate: Candidate[F]) -> float:
        """Its place among the passing (and among the failing) candidates, lower is better."""

    @abstractmethod
    def summary(self, candidate: Candidate[F]) -> str:
        """Its held-out errors, for the log."""

    @abstractmethod
    def separation(self, chosen: Candidate[F], runner: Candidate[F]) -> tuple[float, str]:
        """How far apart two passing candidates' held-out errors are, and in words."""

    @abstractmethod
    def predicted_change(self, current: Candidate[F], candidate: Candidate[F]) -> np.ndarray:
        """What ``candidate`` changes in the predictions of ``current`` (held-out data)."""


class Reported(ABC, Generic[F]):
    """What the report shows of a scorer's fits."""

    @abstractmethod
    def residual(self, current: Candidate[F], k: int, plots: Path | None) -> Residual:
        """The residual of ``current`` (iteration ``k``; its PNG under ``plots``)."""

    @abstractmethod
    def leftover(self, current: Candidate[F]) -> tuple[str, ResidualFit | None]:
        """Why structure is left (empty: the residual is noise), and a residual network
        that absorbs it (NOT a physical effect) or None."""

    @abstractmethod
    def describe(self) -> str:
        """How models are compared, one paragraph for the report."""

    @abstractmethod
    def test_labels(self) -> dict[str, tuple[str, str]]:
        """Test error name -> (label, unit ``"m"`` or ``"mm"``), in report order."""

    @abstractmethod
    def settings_summary(self) -> dict[str, Any]:
        """The settings worth recording beside the result."""

    def rollout_plot(self, before: Candidate[F], after: Candidate[F], path: Path) -> Path | None:
        """A PNG at ``path``: measured end caps of a test stretch against the open-loop
        rollouts of ``before`` (the declared model) and ``after`` (the final one); None
        where the scorer draws none."""
        return None


class Refined(Generic[F]):
    """Optional steps of the loop, each with a default that leaves it out."""

    def second_look(self, current: Candidate[F], tried: Sequence[Candidate[F]]) -> list[str]:
        """Names of candidates of ``tried`` (judged against ``current``) to fit again with
        :meth:`fit_jointly` before one is chosen (default: none)."""
        return []

    def fit_jointly(self, current: Candidate[F], proposal: Proposal) -> Candidate[F]:
        """``current`` plus the proposed effect fitted with everything free, where
        ``fit_candidate`` holds part of the model (default: ``fit_candidate``)."""
        return self.fit_candidate(current, proposal)  # type: ignore[attr-defined]  # a mixin: LoopScorer's Scorer side has it

    def refusal(self, added: Candidate[F], before: Candidate[F]) -> str:
        """Why ``added`` (``accept``'s refit of a chosen candidate) cannot replace
        ``before``, as a clause after "its refit as the model"; "" if it can (default)."""
        return ""

    def undo_accept(self) -> None:
        """Forget what the last ``accept`` changed in the scorer's own state (its result
        was overruled); default: nothing to forget."""

    def sample_states(self) -> State | None:
        """Rod states sampled from the training data, where candidates' forces are
        measured (:func:`~identification.discovery.negligible.force_ratio`); None: not
        measured."""
        return None

    def finish(self, current: Candidate[F]) -> Candidate[F]:
        """The final model, refitted where the scorer does before it is reported (default:
        ``current`` as it is)."""
        return current


class LoopScorer(Scorer[F], Judged[F], Reported[F], Refined[F]):
    """A scorer the loop runs: the core with its comparisons, report and refinements."""
