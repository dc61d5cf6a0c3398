"""The closed loop: find the residual, trace it to the missing effect, add it, repeat.

:class:`EffectDiscovery` is an effect library times a scorer (as in PySINDy, a
library times an optimizer). Each iteration

1. looks at the current model's **residuals**
   (:meth:`~identification.discovery.scorer.Reported.residual`);
2. fits every **candidate** of the effect library whose physical gate the data passes
   (:func:`~identification.discovery.library.propose`), each jointly with everything
   already in the model, and scores it against "nothing is missing" (the current
   model) on held-out data;
3. accepts the best candidate only if :func:`~identification.discovery.judge.judge`
   passes it (BIC, held-out gain, physical values), and flags the attribution when
   the runner-up also passes and the two explain the same thing; when the scorer's
   refit of it (:meth:`~identification.discovery.scorer.Scorer.accept`) leaves the
   physical domain it is rejected after all
   (:func:`~identification.discovery.judge.overrule`) and the next passing one tried;
   when it is an effect added earlier that the refit drives out of its domain, that
   effect stood in for the candidate: the candidate **in place of** it is fitted and
   judged against the current model first (:meth:`EffectDiscovery.replace`);
4. after an addition, takes a **backward step** (:meth:`EffectDiscovery.prune`): each
   effect the loop added before is fitted out of the new model and removed where the
   model without it does as well (it would not pass as a candidate against that model);
5. stops when no candidate is accepted: the residual is noise, or nothing in the
   library explains it (:meth:`~identification.discovery.scorer.Reported.leftover` says which).

Two scorers: :class:`~identification.discovery.one_step.OneStepScorer` (one-step
regressions on rod states) and :class:`~identification.discovery.multi_step.MultiStepScorer`
(multi-step prediction of measured end caps through the engine).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from identification.data.dataset import Dataset
from identification.discovery.judge import (
    MIN_BIC_DROP,
    Candidate,
    Criteria,
    RunnerUp,
    correlation,
    judge,
    overrule,
    runner_up,
    unphysical,
)
from identification.discovery.library import Proposal
from identification.discovery.negligible import force_ratio, group_power
from identification.discovery.residual_network import ResidualFit
from identification.discovery.scorer import CandidateSkipped, LoopScorer, Residual
from identification.discovery.side_by_side import fit_side_by_side, fitted
from identification.linear.regression import NotFittedError
from identification.trajectory.fitted_model import FittedModel
from tensegrity_env.engine import State


@dataclass
class Iteration:
    """One pass of the loop.

    Attributes:
        before: the current model, scored.
        candidates: every candidate tried, scored (best first).
        skipped: candidates whose gate the data did not pass (or whose fit failed).
        chosen: the accepted candidate, or None (the loop stops).
        runner_up: the second candidate that also passed, compared with ``chosen``.
        residual: what the current model leaves.
        test_before, test_after: test-split errors of the model before and after.
        added: ``chosen`` as the next current model (refitted where the scorer does).
        replaced: effects of ``before`` that ``chosen`` replaces (see
            :meth:`EffectDiscovery.replace`).
        removed: effects of ``before`` that the backward step removed once ``chosen``
            was in the model, each with the reason (:meth:`EffectDiscovery.prune`).
    """

    before: Candidate[Any]
    candidates: list[Candidate[Any]]
    skipped: list[Proposal]
    chosen: Candidate[Any] | None
    runner_up: RunnerUp | None
    residual: Residual
    test_before: dict[str, Any]
    test_after: dict[str, Any] | None = None
    added: Candidate[Any] | None = None
    replaced: list[str] = field(default_factory=list)
    removed: dict[str, str] = field(default_factory=dict)

    @property
    def ambiguous(self) -> tuple[str, float] | None:
        """The runner-up that cannot be told apart from ``chosen``, and the correlation."""
        r = self.runner_up
        return (r.name, r.correlation) if r is not None and r.ambiguous else None


@dataclass
class DiscoveryResult:
    """Everything the loop found.

    Attributes:
        method: the scorer (``"one_step"`` or ``"multi_step"``).
        description: how models were compared (one paragraph).
        iterations: the loop's passes, in order.
        model: the final model.
        baseline_test, final_test: test-split errors of the declared and the final model.
        test_labels: test error name -> (label, unit), in report order.
        criteria: how held-out gains were judged.
        final_residual: what the final model leaves.
        unexplained: why structure is left (empty if the residual is noise).
        settings: settings recorded beside the result.
        residual_network: a residual network fitted to what is left, when it lowers the
            held-out (test) one-step error (NOT a physical effect, not part of ``model``).
        rollout_plot: PNG of measured end caps against the declared and the final model
            rolled out over a test stretch, or None.
        earlier: the models the loop passed through before ``model``, newest first (the
            current model before the final refit, each iteration's, the declared fit).
        open_loop: what the open-loop check before writing found (one line or two), ``""``
            before it ran.
    """

    method: str
    description: str
    iterations: list[Iteration]
    model: FittedModel
    baseline_test: dict[str, Any]
    final_test: dict[str, Any]
    test_labels: dict[str, tuple[str, str]]
    criteria: Criteria
    final_residual: Residual
    unexplained: str = ""
    settings: dict[str, Any] = field(default_factory=dict)
    residual_network: ResidualFit | None = None
    rollout_plot: Path | None = None
    earlier: list[Candidate[Any]] = field(default_factory=list)
    open_loop: str = ""

    @property
    def added(self) -> list[str]:
        """Effects added, in order, less those a later one replaced or made unneeded (and
        those not in ``model``, where it is an earlier model the check fell back to)."""
        names: list[str] = []
        for it in self.iterations:
            if it.chosen is not None:
                names = [n for n in names if n not in it.replaced] + [it.chosen.name]
                names = [n for n in names if n not in it.removed]
        return [n for n in names if n in self.model.names]


class EffectDiscovery:
    """The residual loop: an effect library times a scorer (see the module docstring).

    Args:
        scorer: how models are fitted and compared
            (:class:`~identification.discovery.one_step.OneStepScorer` or
            :class:`~identification.discovery.multi_step.MultiStepScorer`).
        max_effects: most effects to add.
        candidates: only these effects of the library (None: all).
        plots: folder for each iteration's residual PNG (None: none written).
        log: where progress lines go.
        jobs: candidates fitted at once, each in a worker process
            (:mod:`~identification.discovery.side_by_side`; 1: one after the other).

    Attributes (after :meth:`fit`):
        result_: the :class:`DiscoveryResult`.
        model_: the final model (declared parameters and the effects added).
        iterations_: the loop's passes.
    """

    def __init__(
        self,
        scorer: LoopScorer[Any],
        max_effects: int = 3,
        candidates: Sequence[str] | None = None,
        plots: Path | None = None,
        log: Callable[[str], None] = print,
        jobs: int = 1,
    ) -> None:
        self.scorer = scorer
        self.max_effects = max_effects
        self.candidates = candidates
        self.plots = plots
        self.log = log
        self.jobs = jobs

    @property
    def model_(self) -> FittedModel:
        return self._fitted().model

    @property
    def iterations_(self) -> list[Iteration]:
        return self._fitted().iterations

    def _fitted(self) -> DiscoveryResult:
        if not hasattr(self, "result_"):
            raise NotFittedError("call EffectDiscovery.fit(dataset) before reading its results")
        return self.result_

    def fit(self, dataset: Dataset) -> EffectDiscovery:
        """Run the loop on ``dataset``; the result is in :attr:`result_`."""
        scorer, log = self.scorer, self.log
        current = start = scorer.begin(dataset, log)
        baseline = test_now = scorer.test_errors(current)
        iterations: list[Iteration] = []
        for k in range(self.max_effects + 1):
            residual = scorer.residual(current, k, self.plots)
            if k == self.max_effects:
                break
            it = self.iterate(current, residual, test_now, iterations[-1] if iterations else None)
            iterations.append(it)
            added = self.add(it)
            if added is None:
                break
            current = it.added = self.prune(it, set(start.model.names))
            test_now = it.test_after = scorer.test_errors(current)
            note = ""
            if it.runner_up is not None:
                r = it.runner_up
                note = (f" (runner-up {r.name}: predicted changes correlate {r.correlation:.3f}, "
                        f"{r.note}" + ("; CANNOT be told apart)" if r.ambiguous else ")"))  # fmt: skip
            instead = f" in place of {', '.join(it.replaced)}" if it.replaced else ""
            assert it.chosen is not None  # add() returned a model: one was chosen
            log(f"added {it.chosen.name}{instead}{note}")
            for name, why in it.removed.items():
                log(f"removed {name}: {why}")
        earlier = [it.added for it in reversed(iterations) if it.added is not None] + [start]
        final = scorer.finish(current)
        if final is not current:
            earlier = [current, *earlier] if current is not earlier[0] else earlier
            current, test_now = final, scorer.test_errors(final)
        unexplained, network = scorer.leftover(current)
        rollouts = None
        if self.plots is not None:
            rollouts = scorer.rollout_plot(start, current, self.plots / "rollout.png")
        self.result_ = DiscoveryResult(
            method=scorer.method, description=scorer.describe(), iterations=iterations,
            model=current.model, baseline_test=baseline, final_test=test_now,
            test_labels=scorer.test_labels(), criteria=scorer.criteria, final_residual=residual, unexplained=unexplained,
            settings=scorer.settings_summary(), residual_network=network, rollout_plot=rollouts,
            earlier=[c for c in earlier if c is not current],
        )  # fmt: skip
        return self

    def iterate(
        self,
        current: Candidate[Any],
        residual: Residual,
        test_now: dict[str, Any],
        last: Iteration | None = None,
    ) -> Iteration:
        """One pass: every candidate fitted, scored and judged; the best passing one chosen
        (``last``: the pass before, see :meth:`settled`)."""
        scorer = self.scorer
        skipped: list[Proposal] = []
        states = scorer.sample_states()
        to_fit: list[Proposal] = []
        for p in scorer.propose(current, self.candidates):
            why = self.settled(p.name, last)
            if why:
                p = Proposal(p.name, None, why)
            (skipped if p.effect is None else to_fit).append(p)
        tried, refused = self.fit_and_judge(scorer.fit_candidate, to_fit, current, states)
        skipped += refused
        looks = scorer.second_look(current, tried)
        again = [p for p in to_fit if p.name in looks]
        if again:
            self.log(f"  fitted again with everything free: {', '.join(p.name for p in again)}")
            joint, refused = self.fit_and_judge(scorer.fit_jointly, again, current, states)
            for p in refused:  # the screened candidate stays
                self.log(f"  candidate {p.name} fitted again: not used ({p.gate})")
            names = {c.name for c in joint}
            tried = [t for t in tried if t.name not in names] + joint
        chosen, second = self.choose(current, tried)
        return Iteration(current, tried, skipped, chosen, second, residual, test_now)

    def fit_and_judge(
        self,
        fit: Callable[[Candidate[Any], Proposal], Candidate[Any]],
        proposals: Sequence[Proposal],
        current: Candidate[Any],
        states: State | None,
    ) -> tuple[list[Candidate[Any]], list[Proposal]]:
        """``fit(current, p)`` for each proposal, side by side, each fitted candidate judged
        against ``current``; returns them and the refused proposals (the reason as gate)."""
        fits = fit_side_by_side(lambda p: fit(current, p), proposals, self.jobs, self.log)
        judged: list[Candidate[Any]] = []
        refused: list[Proposal] = []
        for p, c in zip(proposals, fits, strict=True):
            if isinstance(c, CandidateSkipped):  # e.g. its fit diverged: never judged
                refused.append(Proposal(p.name, None, str(c)))
            elif isinstance(c, Exception):  # a singular or failed fit
                refused.append(Proposal(p.name, None, f"fit failed: {c}"))
            else:
                c.gate = p.gate
                self.judged(c, current, states)
                judged.append(c)
        return judged, refused

    def settled(self, name: str, last: Iteration | None) -> str:
        """Why candidate ``name`` is not fitted again after ``last`` added an effect ("": it is).

        With held-out chi-square gains (differences of the held-out sum of squares), the
        gain of a candidate Y once the effect X added last is in the model is exactly
        ``gain(Y | X) = gain(Y) + gain(X | Y) - gain(X)`` (the noise estimate aside). A Y
        whose gain in the last pass was below ``-gain(X)`` (it made held-out prediction
        worse than the model without it, by more than X improved it) passes now only if
        ``gain(X | Y) > min_gain + 2 gain(X)``: with Y in the model, X would explain more
        than twice what it explains alone. Effects that mask each other that much stand
        in for each other, and a refit that shows it is handled where it happens
        (:meth:`replace`); a Y that hurt prediction does not do it. Such a Y is not
        fitted again (on floor data with planted linear drag, cubic stiffness's gain was
        -1186 beside linear drag's 710, and -1796 when fitted again after it). Gains
        that are fractions (the one-step scorer) have no such identity: always fitted.
        """
        if last is None or last.chosen is None or self.scorer.criteria.relative:
            return ""
        past = next((c for c in last.candidates if c.name == name), None)
        bound = -last.chosen.gain
        if past is None or not past.gain < bound:
            return ""
        fmt = self.scorer.criteria.format_gain
        return (f"not fitted again: its held-out gain {fmt(past.gain)} in the last pass is "
                f"below -{fmt(last.chosen.gain)}, minus that of {last.chosen.name}, added "
                "since (see EffectDiscovery.settled)")  # fmt: skip

    def judged(self, c: Candidate[Any], current: Candidate[Any], states: State | None) -> None:
        """Judge ``c`` against ``current`` (its force and power measured on ``states``),
        rank, log."""
        scorer, log = self.scorer, self.log
        size, power = math.nan, None
        drag = next((e for e in c.model.effects if e.name == c.name and e.dissipative), None)
        if states is not None:
            size = force_ratio(c.model, current.model, states)
            if drag is not None:
                power = group_power(drag, c.model.params, states)
        judge(c, current, scorer.gain(c, current), scorer.criteria, size, power)
        c.rank = scorer.rank(c)
        log("    " + "; ".join(e.describe() for e in c.model.effects))
        log(f"  candidate {c.name:20s} {scorer.summary(c)}, gain "
            f"{scorer.criteria.format_gain(c.gain)}, ΔBIC {-c.bic_drop:+.4g}: {c.verdict} "
            f"({c.seconds:.1f} s)")  # fmt: skip

    def choose(
        self, current: Candidate[Any], tried: list[Candidate[Any]]
    ) -> tuple[Candidate[Any] | None, RunnerUp | None]:
        """The best accepted candidate (None: none), and the runner-up if it also passed
        (``tried`` is sorted best first, accepted ones first)."""
        scorer = self.scorer
        tried.sort(key=lambda c: (not c.accepted, c.rank))
        chosen = tried[0] if tried and tried[0].accepted else None
        if chosen is None or len(tried) < 2 or not tried[1].accepted:
            return chosen, None
        runner = tried[1]
        corr = correlation(
            scorer.predicted_change(current, chosen), scorer.predicted_change(current, runner)
        )
        separation, note = scorer.separation(chosen, runner)
        return chosen, runner_up(runner.name, corr, separation, note, scorer.criteria)

    def add(self, it: Iteration) -> Candidate[Any] | None:
        """``it.chosen`` as the next current model (:meth:`~identification.discovery.scorer.Scorer.accept`), or None.

        A refit outside the physical domain (e.g. it drives an effect added earlier to a
        negative drag) overrules the choice: the candidate is rejected with the reason,
        and the next passing candidate, if any, is tried the same way.
        """
        while it.chosen is not None:
            chosen = it.chosen
            added = self.refit(chosen, it.before)
            if chosen.accepted:
                it.added = added
                return added
            earlier = set(it.before.model.names) - {chosen.name}
            stale = [e.name for e in added.model.effects if e.name in earlier and e.violation()]
            if stale and (replaced := self.replace(it, chosen, stale)) is not None:
                return replaced
            it.chosen, it.runner_up = self.choose(it.before, it.candidates)
        return None

    def refit(self, c: Candidate[Any], before: Candidate[Any]) -> Candidate[Any]:
        """``c`` as the next current model (the scorer's refit); a refit outside the
        physical domain, or one the scorer refuses (:meth:`~identification.discovery.scorer.Refined.refusal`), overrules
        ``c`` (``c.accepted`` turns False, logged, the scorer's data as before)."""
        added = self.scorer.accept(c)
        reason = unphysical(added.model, before.model)
        reason = f"is unphysical ({reason})" if reason else self.scorer.refusal(added, before)
        if reason:
            overrule(c, reason)
            self.scorer.undo_accept()
            self.log(f"  candidate {c.name}: {c.verdict}")
        return added

    def prune(self, it: Iteration, declared: set[str]) -> Candidate[Any]:
        """The backward step: ``it.added`` without the effects the loop added before
        ``it.chosen`` that it no longer needs (the names in ``declared``, the starting
        model's, always stay).

        Each such effect E is fitted out of the model as the scorer fits a candidate
        (:meth:`~identification.discovery.scorer.Scorer.fit_candidate` of the chosen
        effect with E and the chosen one left out) and scored against the model with it.
        E stays where it would pass as a candidate against the model without it: it
        lowers the held-out error by the scorer's minimum gain and the BIC by
        :data:`~identification.discovery.judge.MIN_BIC_DROP`. Otherwise the model
        without E, refitted as any chosen candidate is
        (:meth:`~identification.discovery.scorer.Scorer.accept`, physical domain and
        refusal checked), replaces it. Without this step an effect that stood in for
        part of the one chosen now stays beside it: on floor data with planted joint
        damping a quadratic drag, named first, stayed at a few percent of its screened
        size once linear drag was added.
        """
        scorer, current, chosen = self.scorer, it.added, it.chosen
        assert current is not None and chosen is not None
        crit = scorer.criteria
        effect = next(e for e in current.model.effects if e.name == chosen.name)
        for name in [n for n in current.model.names if n not in declared | {chosen.name}]:
            gate = f"without {name}, which was added before {chosen.name}"
            proposal = Proposal(chosen.name, effect, gate)
            now = current

            def without(p: Proposal, now: Candidate[Any] = now, name: str = name) -> Candidate[Any]:
                return scorer.fit_candidate(now, p, [name, p.name])

            c = fitted(without, proposal)
            if isinstance(c, Exception):
                self.log(f"  {gate}: not judged ({c})")
                continue
            gain, bic = -scorer.gain(c, current), c.bic - current.bic
            kept = gain >= crit.min_gain and bic >= MIN_BIC_DROP
            self.log(f"  {name} beside {chosen.name}: without it the {crit.measure} rises "
                     f"{crit.format_gain(gain)} and the BIC {bic:+.4g}: "
                     + ("stays" if kept else "removed"))  # fmt: skip
            if kept:
                continue
            c.gate, c.accepted = gate, True
            c.verdict = (f"{name} removed: it lowers the {crit.measure} by "
                         f"{crit.format_gain(gain)} and the BIC by {bic:.4g} beside "
                         f"{chosen.name}")  # fmt: skip
            reduced = self.refit(c, current)
            if c.accepted:
                it.removed[name] = c.verdict.split(": ", 1)[1]
                current = reduced
        return current

    def replace(
        self, it: Iteration, chosen: Candidate[Any], stale: list[str]
    ) -> Candidate[Any] | None:
        """``chosen`` in place of the effects ``stale`` of the current model, or None.

        The refit of ``chosen`` drove the effects ``stale``, added earlier, out of their
        physical domain (e.g. a negative linear drag beside quadratic drag): they stood
        in for it. The current model without them plus ``chosen``'s effect is fitted and
        judged against the current model like any candidate (and added to
        ``it.candidates``); if it passes and its refit stays physical it is the choice.
        """
        scorer = self.scorer
        effect = next(e for e in chosen.model.effects if e.name == chosen.name)
        gate = (f"in place of {', '.join(stale)}, which its refit drove out of the physical "
                "domain")  # fmt: skip
        proposal = Proposal(chosen.name, effect, gate)
        c = fitted(lambda p: scorer.fit_candidate(it.before, p, stale), proposal)
        if isinstance(c, Exception):
            self.log(f"  {chosen.name} {gate}: not judged ({c})")
            return None
        c.gate = gate
        self.judged(c, it.before, scorer.sample_states())
        it.candidates.append(c)
        if not c.accepted:
            return None
        added = self.refit(c, it.before)
        if not c.accepted:
            return None
        it.chosen, it.runner_up, it.added, it.replaced = c, None, added, stale
        return added
