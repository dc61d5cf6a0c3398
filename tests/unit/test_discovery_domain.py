"""The residual loop names nothing outside the physical domain.

A stub scorer stands in for the fits: each candidate's fit and its refit as the next
model (:meth:`Scorer.accept`) are given, so the test asserts the loop's decisions alone.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pytest

from identification.discovery import EffectDiscovery, FittedModel
from identification.discovery.judge import MIN_CHI2_GAIN, MULTI_STEP, Candidate
from identification.discovery.library import Proposal
from identification.discovery.residual_network import ResidualFit
from identification.discovery.scorer import LoopScorer, Residual
from tensegrity_env import assemblies
from tensegrity_env.effects import ForceField, LinearDrag, QuadraticDrag
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.model import Model

ICO = assemblies.icosahedron()


def model_with(*effects: PhysicalEffect) -> FittedModel:
    return FittedModel(Model(ICO.topology, ICO.params, list(effects)), n_params=6 * len(effects))


def drag(cls: type[LinearDrag] | type[QuadraticDrag], axial: float, se: float) -> PhysicalEffect:
    """Drag of 0.4 across the rods and ``axial`` ± ``se`` along them (natural units)."""
    return cls(ICO.topology, validate=False, translational=[0.4, 0.4, axial],
               uncertainty={"translational": [0.01, 0.01, se]})  # fmt: skip


class StubScorer(LoopScorer[None]):
    """Candidates with given fits, held-out gains and refits."""

    criteria = MULTI_STEP
    method = "stub"

    def __init__(
        self,
        fits: dict[str, tuple[FittedModel, float, FittedModel]],
        start: FittedModel | None = None,
        replacing: dict[str, tuple[FittedModel, float, FittedModel]] | None = None,
    ) -> None:
        self.fits = fits  # name -> (candidate fit, held-out gain, refit as the model)
        self.start = start or model_with()  # the current model at the start
        self.replacing = replacing or {}  # the same, for the candidate in place of others
        self.dropped: list[list[str]] = []

    def begin(self, dataset: Any, log: Callable[[str], None]) -> Candidate[None]:
        return Candidate("nothing", None, self.start, bic=0.0)

    def entry(self, c: Candidate[None]) -> tuple[FittedModel, float, FittedModel]:
        return (self.replacing if "in place of" in c.gate else self.fits)[c.name]

    def test_errors(self, current: Candidate[None]) -> dict[str, Any]:
        return {}

    def propose(self, current: Candidate[None], names: Sequence[str] | None) -> list[Proposal]:
        return [Proposal(n, m.effects[-1], "stub") for n, (m, _, _) in self.fits.items()]

    def fit_candidate(
        self, current: Candidate[None], proposal: Proposal, drop: Sequence[str] = ()
    ) -> Candidate[None]:
        if drop:
            self.dropped.append(list(drop))
        c = Candidate(proposal.name, None, model_with(), bic=-500.0, gate=proposal.gate)
        c.model = self.entry(c)[0]
        return c

    def gain(self, candidate: Candidate[None], current: Candidate[None]) -> float:
        return self.entry(candidate)[1]

    def rank(self, candidate: Candidate[None]) -> float:
        return -candidate.gain

    def summary(self, candidate: Candidate[None]) -> str:
        return ""

    def separation(self, chosen: Candidate[None], runner: Candidate[None]) -> tuple[float, str]:
        return chosen.gain - runner.gain, ""

    def predicted_change(self, current: Candidate[None], candidate: Candidate[None]) -> np.ndarray:
        return np.zeros(3)

    def accept(self, chosen: Candidate[None]) -> Candidate[None]:
        return Candidate(chosen.name, None, self.entry(chosen)[2], bic=chosen.bic)

    def residual(self, current: Candidate[None], k: int, plots: Any) -> Residual:
        return Residual({}, "")

    def leftover(self, current: Candidate[None]) -> tuple[str, ResidualFit | None]:
        return "", None

    def describe(self) -> str:
        return "stub"

    def test_labels(self) -> dict[str, tuple[str, str]]:
        return {}

    def settings_summary(self) -> dict[str, Any]:
        return {}


LINEAR_OK = model_with(drag(LinearDrag, 0.1, 0.01))
#: the refit drove the axial drag to -0.131 N*s/m, 5 standard errors below 0
LINEAR_NEGATIVE = model_with(drag(LinearDrag, -0.131, 0.0267))
QUADRATIC_OK = model_with(drag(QuadraticDrag, 0.09, 0.008))


def run(fits: dict[str, tuple[FittedModel, float, FittedModel]], **kw: Any) -> EffectDiscovery:
    lines: list[str] = []
    loop = EffectDiscovery(StubScorer(fits, **kw), max_effects=1, log=lines.append)
    loop.fit(None)  # type: ignore[arg-type]
    loop.lines = lines  # type: ignore[attr-defined]
    return loop


def test_a_candidate_fitted_with_negative_drag_is_not_named():
    loop = run({"linear_drag": (LINEAR_NEGATIVE, 1e4, LINEAR_NEGATIVE),
                "quadratic_drag": (QUADRATIC_OK, 50.0, QUADRATIC_OK)})  # fmt: skip
    assert loop.result_.added == ["quadratic_drag"]
    verdicts = {c.name: c.verdict for c in loop.iterations_[0].candidates}
    assert verdicts["linear_drag"].startswith(
        "rejected: unphysical (effect 'linear_drag': 'translational' must be >= 0"
    )
    assert "[2] = -0.131 ± 0.027 N*s/m" in verdicts["linear_drag"]


@pytest.mark.parametrize("quadratic_refit", [QUADRATIC_OK, LINEAR_NEGATIVE])
def test_a_refit_that_leaves_the_domain_overrules_the_choice(quadratic_refit):
    """The best candidate passes on its own fit, but its refit as the model is unphysical:
    it is rejected with the reason and the next passing candidate is tried the same way."""
    loop = run({"linear_drag": (LINEAR_OK, 1e4, LINEAR_NEGATIVE),
                "quadratic_drag": (QUADRATIC_OK, 50.0, quadratic_refit)})  # fmt: skip
    it = loop.iterations_[0]
    verdicts = {c.name: c.verdict for c in it.candidates}
    assert verdicts["linear_drag"] == (
        "rejected: its refit as the model is unphysical (effect 'linear_drag': 'translational' "
        "must be >= 0 (drag opposes motion), got [2] = -0.131 ± 0.027 N*s/m)"
    )
    if quadratic_refit is QUADRATIC_OK:
        assert loop.result_.added == ["quadratic_drag"] and it.added is not None
        assert loop.model_.names == ["quadratic_drag"]
    else:  # nothing passes in the physical domain: nothing is named, the declared model stays
        assert loop.result_.added == [] and it.chosen is None and it.added is None
        assert verdicts["quadratic_drag"].startswith("rejected: its refit as the model")
        assert loop.model_.names == [] and loop.model_.model.violation() == ""
    assert any("candidate linear_drag: rejected: its refit" in ln for ln in loop.lines)


@pytest.mark.parametrize("gain_alone", [60.0, 1.0])
def test_an_earlier_effect_driven_out_of_its_domain_is_replaced(gain_alone):
    """Linear drag stood in for quadratic drag: the joint refit drives it negative. The
    candidate in place of it is fitted and judged against the current model; it is the
    choice only if it passes on its own."""
    joint = model_with(drag(LinearDrag, 0.1, 0.01), drag(QuadraticDrag, 0.09, 0.008))
    joint_refit = model_with(drag(LinearDrag, -0.131, 0.0267), drag(QuadraticDrag, 0.09, 0.008))
    loop = run({"quadratic_drag": (joint, 1e3, joint_refit)}, start=LINEAR_OK,
               replacing={"quadratic_drag": (QUADRATIC_OK, gain_alone, QUADRATIC_OK)})  # fmt: skip
    it = loop.iterations_[0]
    assert loop.scorer.dropped == [["linear_drag"]]
    first, alone = it.candidates
    assert first.verdict.startswith("rejected: its refit as the model is unphysical (effect "
                                    "'linear_drag'")  # fmt: skip
    assert alone.gate.startswith("in place of linear_drag")
    if gain_alone >= MULTI_STEP.min_gain:
        assert alone.accepted and it.chosen is alone and it.replaced == ["linear_drag"]
        assert loop.model_.names == ["quadratic_drag"] and loop.result_.added == ["quadratic_drag"]
        assert any(
            ln.startswith("added quadratic_drag in place of linear_drag") for ln in loop.lines
        )
    else:  # quadratic drag alone does not beat linear drag: the current model stays
        assert not alone.accepted and "drops only 1" in alone.verdict
        assert it.chosen is None and loop.model_.names == ["linear_drag"]


# A second look: a scorer may fit the most promising screened candidates again with
# everything free (Refined.second_look, Refined.fit_jointly); they are judged on that fit.

FORCE_FIELD = model_with(ForceField(ICO.topology, force=[0.0, 0.0, 0.1]))


class LookingScorer(StubScorer):
    """Screened gains below the threshold; fitted jointly, ``joint`` gains."""

    def __init__(self, screened: dict[str, float], joint: dict[str, float], looks: list[str]):
        models = {
            "linear_drag": LINEAR_OK,
            "quadratic_drag": QUADRATIC_OK,
            "force_field": FORCE_FIELD,
        }
        super().__init__({n: (models[n], g, models[n]) for n, g in screened.items()})
        self.joint, self.looks = joint, looks
        self.looked: list[str] = []
        self.seen: list[list[tuple[str, float]]] = []

    def second_look(self, current: Candidate[None], tried: Sequence[Candidate[None]]) -> list[str]:
        self.seen.append([(c.name, c.gain) for c in tried])
        return self.looks

    def fit_jointly(self, current: Candidate[None], proposal: Proposal) -> Candidate[None]:
        self.looked.append(proposal.name)
        c = self.fit_candidate(current, proposal)
        c.heldout = {"jointly": 1.0}
        return c

    def gain(self, candidate: Candidate[None], current: Candidate[None]) -> float:
        if "jointly" in candidate.heldout:
            return self.joint[candidate.name]
        return super().gain(candidate, current)


def run_looking(scorer: LookingScorer) -> tuple[EffectDiscovery, list[str]]:
    lines: list[str] = []
    loop = EffectDiscovery(scorer, max_effects=1, log=lines.append, jobs=1)
    loop.fit(None)  # type: ignore[arg-type]
    return loop, lines


def test_a_candidate_fitted_again_jointly_is_judged_on_that_fit_and_named():
    low = MIN_CHI2_GAIN / 2
    scorer = LookingScorer({"linear_drag": low, "quadratic_drag": low / 2, "force_field": -1.0},
                           {"linear_drag": 40 * MIN_CHI2_GAIN}, ["linear_drag"])  # fmt: skip
    loop, lines = run_looking(scorer)
    assert scorer.seen[0] == [("linear_drag", low), ("quadratic_drag", low / 2),
                              ("force_field", -1.0)]  # fmt: skip
    assert scorer.looked == ["linear_drag"]
    assert "  fitted again with everything free: linear_drag" in lines
    assert loop.result_.added == ["linear_drag"]
    judged = {c.name: c for c in loop.iterations_[0].candidates}
    assert judged["linear_drag"].gain == 40 * MIN_CHI2_GAIN  # the joint fit replaced the screen
    assert judged["quadratic_drag"].gain == low / 2 and not judged["quadratic_drag"].accepted


def test_without_a_second_look_the_screens_decide():
    low = MIN_CHI2_GAIN / 2
    scorer = LookingScorer({"linear_drag": low, "quadratic_drag": low / 2},
                           {"linear_drag": 40 * MIN_CHI2_GAIN}, [])  # fmt: skip
    loop, lines = run_looking(scorer)
    assert scorer.looked == [] and loop.result_.added == []
    assert not any("fitted again" in line for line in lines)


class RefusingScorer(StubScorer):
    """A stub whose refits of ``refused`` are refused (they fit worse than the current
    model)."""

    def __init__(self, fits: dict[str, tuple[FittedModel, float, FittedModel]], refused: set[str]):
        super().__init__(fits)
        self.refused, self.undone = refused, 0

    def refusal(self, added: Candidate[None], before: Candidate[None]) -> str:
        return "fits the floor windows worse" if added.name in self.refused else ""

    def undo_accept(self) -> None:
        self.undone += 1


@pytest.mark.parametrize("refused", [{"linear_drag"}, {"linear_drag", "quadratic_drag"}])
def test_a_refit_the_scorer_refuses_overrules_the_choice_and_is_undone(refused):
    """Linear drag, chosen first, is refused after its refit: the scorer forgets that
    refit and the next passing candidate is refitted the same way."""
    scorer = RefusingScorer({"linear_drag": (LINEAR_OK, 1e4, LINEAR_OK),
                             "quadratic_drag": (QUADRATIC_OK, 50.0, QUADRATIC_OK)}, refused)  # fmt: skip
    loop = EffectDiscovery(scorer, max_effects=1, log=lambda line: None)
    loop.fit(None)  # type: ignore[arg-type]
    verdicts = {c.name: c.verdict for c in loop.iterations_[0].candidates}
    for name in refused:
        assert verdicts[name] == "rejected: its refit as the model fits the floor windows worse"
    assert scorer.undone == len(refused)
    assert loop.result_.added == ([] if len(refused) == 2 else ["quadratic_drag"])


# The backward step (EffectDiscovery.prune): after an addition, each effect added before
# is fitted out of the model and removed where the model does as well without it.

BOTH_DRAGS = model_with(drag(QuadraticDrag, 0.09, 0.008), drag(LinearDrag, 0.1, 0.01))


class PruningScorer(StubScorer):
    """Quadratic drag passes first; linear drag passes beside it; the model without the
    quadratic drag loses ``loss`` of held-out chi-square and ``bic`` of BIC."""

    def __init__(self, loss: float, bic: float) -> None:
        super().__init__({"quadratic_drag": (QUADRATIC_OK, 60.0, QUADRATIC_OK),
                          "linear_drag": (LINEAR_OK, 50.0, LINEAR_OK)})  # fmt: skip
        self.second = {"linear_drag": (BOTH_DRAGS, 40.0, BOTH_DRAGS)}
        self.without = (LINEAR_OK, -loss, LINEAR_OK)
        self.bic_without = bic

    def propose(self, current: Candidate[None], names: Sequence[str] | None) -> list[Proposal]:
        have = set(current.model.names)
        return [p for p in super().propose(current, names) if p.name not in have]

    def entry(self, c: Candidate[None]) -> tuple[FittedModel, float, FittedModel]:
        if c.gate.startswith("without"):
            return self.without
        if c.name == "linear_drag" and getattr(self, "pass_two", False):
            return self.second["linear_drag"]
        return super().entry(c)

    def fit_candidate(
        self, current: Candidate[None], proposal: Proposal, drop: Sequence[str] = ()
    ) -> Candidate[None]:
        self.pass_two = "quadratic_drag" in current.model.names
        c = super().fit_candidate(current, proposal, drop)
        without = c.gate.startswith("without")
        c.bic = current.bic + (self.bic_without if without else -500.0)
        return c


@pytest.mark.parametrize(("loss", "bic", "removed"), [(3.0, -40.0, True), (300.0, 250.0, False)])
def test_an_effect_the_next_one_makes_unneeded_is_removed(loss, bic, removed):
    scorer = PruningScorer(loss, bic)
    lines: list[str] = []
    loop = EffectDiscovery(scorer, max_effects=2, log=lines.append, jobs=1)
    loop.fit(None)  # type: ignore[arg-type]
    first, second = loop.iterations_[:2]
    assert first.chosen.name == "quadratic_drag" and second.chosen.name == "linear_drag"
    assert scorer.dropped[-1] == ["quadratic_drag", "linear_drag"]  # fitted out of the model
    if removed:
        assert list(second.removed) == ["quadratic_drag"]
        assert loop.model_.names == ["linear_drag"] and loop.result_.added == ["linear_drag"]
        assert any(ln.startswith("removed quadratic_drag: it lowers the held-out chi-square by 3")
                   for ln in lines)  # fmt: skip
    else:
        assert second.removed == {}
        assert loop.result_.added == ["quadratic_drag", "linear_drag"]
        assert "  quadratic_drag beside linear_drag: without it the held-out chi-square rises " \
               "300 and the BIC +250: stays" in lines
