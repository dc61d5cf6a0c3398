"""One-step scorer of the residual loop: regressions on rod states (exact on clean data).

Every candidate is fitted jointly with everything already in the model by the
extended regression (:func:`~identification.discovery.library.fit_model`), and scored
by its **held-out** one-step and rollout errors (validation split) and the **BIC** of
its training one-step errors ``n ln(SSE / n) + k ln(n)``. It is accepted by the gain
in the held-out one-step error (:data:`~identification.discovery.judge.ONE_STEP`).

The current model's residuals are looked at per element on the training split
(:mod:`identification.discovery.residuals`). When structure is left on noise-free
data, a small **residual network** (:mod:`identification.discovery.residual_network`)
is fitted jointly with the declared parameters and reported, if it lowers the
held-out (test) one-step error, as unexplained, NOT as a physical effect.

Linear drag is fitted in both forms (:mod:`tensegrity_env.effects.drag`): explicit, and
integrated implicitly as MuJoCo integrates a free joint's ``damping`` (its regression
columns at the velocities after the step); the form with the lower training BIC (the
same parameter count: the lower one-step error) is the candidate. Fitted explicitly,
joint damping b leaves a constant force ``b g dt`` upward on every rod (the drag of the
velocity gravity adds within the step) that a force field would pick up.

Test errors are measured on the **test** split, which selection never sees.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from identification.data.dataset import Dataset
from identification.discovery.judge import MIN_BIC_DROP, ONE_STEP, ROUND_OFF, Candidate, finite
from identification.discovery.library import (
    FitSettings,
    Proposal,
    fit_model,
    fit_proposal,
    propose,
    slack_probe,
)
from identification.discovery.residual_network import ResidualFit, fit_residual_network
from identification.discovery.residuals import (
    compute_residuals,
    plot_residuals,
    summarize,
    summary_table,
)
from identification.discovery.rollout_plots import rod_state_rollout_plot
from identification.discovery.scorer import LoopScorer, Residual
from identification.linear.extended import acting_split, evaluate_model
from identification.linear.features import cable_commands_at, drawn_transitions, transitions_of
from identification.report.tables import error_text
from identification.trajectory.fitted_model import FittedModel
from identification.trajectory.windows import STATE_KEYS
from tensegrity_env.effects import ImplicitLinearDrag, LinearDrag, ResidualNetwork, SlackSprings
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import Engine, State
from tensegrity_env.io_utils import InputError

#: training rod states per sample where candidates' forces are measured
SAMPLE_STRIDE = 10


def one_step_bic(dataset: Dataset, model: FittedModel, max_transitions: int = 20_000) -> float:
    """``n ln(SSE/n) + k ln(n)`` of the one-step position errors on the training split."""
    data = dataset.split("train")
    idx = drawn_transitions(data, max_transitions, 1)
    acting = acting_split(model.effects, data, dataset.dt)
    s0, s1, u = transitions_of(acting, idx)
    cables = cable_commands_at(acting, idx)
    with torch.no_grad():
        engine = Engine(dataset.topology, dataset.dt, effects=model.effects, native=True)
        pred = engine.step(s0, model.params, u, cables)
    err = (pred.p - s1.p).reshape(-1).numpy()
    n = err.size
    sse = float(np.sum(err**2))
    if not np.isfinite(sse):
        return float("inf")
    return n * np.log(max(sse / n, ROUND_OFF**2)) + model.n_params * np.log(n)


def predicted_change(dataset: Dataset, a: FittedModel, b: FittedModel, split: str) -> np.ndarray:
    """One-step velocity predictions of ``b`` minus ``a`` on a split's transitions, flattened."""
    data = dataset.split(split)
    idx = drawn_transitions(data, 5000, 2)
    out = []
    for m in (a, b):
        acting = acting_split(m.effects, data, dataset.dt)
        s0, _, u = transitions_of(acting, idx)
        cables = cable_commands_at(acting, idx)
        with torch.no_grad():
            engine = Engine(dataset.topology, dataset.dt, effects=m.effects, native=True)
            out.append(engine.step(s0, m.params, u, cables).v)
    return (out[1] - out[0]).reshape(-1).numpy()


def label(model: FittedModel) -> str:
    """``declared model + effect + ...``."""
    return "declared model" + "".join(f" + {n}" for n in model.names)


class OneStepScorer(LoopScorer[FittedModel]):
    """Scores candidates by one-step regressions on rod states (see the module docstring).

    Args:
        settings: how models are fitted (anchors, starting params, contact windows).
        horizon_s: open-loop rollout horizon of the held-out and test errors [s].
        start_effects: effects the declared model starts with (a residual network is
            left out: it is not a physical effect).
        residual_network: when structure is left on noise-free data, fit a residual
            network to it (a few seconds; False: only say that structure is left).
    """

    criteria = ONE_STEP
    method = "one_step"

    def __init__(
        self,
        settings: FitSettings,
        horizon_s: float = 1.0,
        start_effects: Sequence[PhysicalEffect] = (),
        residual_network: bool = True,
    ) -> None:
        self.settings = settings
        self.horizon_s = horizon_s
        self.start_effects = list(start_effects)
        self.residual_network = residual_network

    # ------------------------------------------------------------------ fits and scores
    def begin(self, dataset: Dataset, log: Callable[[str], None]) -> Candidate[FittedModel]:
        self.dataset, self.log = dataset, log
        self.val_split = "val" if "val" in dataset.splits else "test"
        self.test_split = "test" if "test" in dataset.splits else self.val_split
        start = self.start_effects
        if any(e.name == ResidualNetwork.name for e in start):
            log("starting effects: a residual network is not a physical effect; left out")
            start = [e for e in start if e.name != ResidualNetwork.name]
        current = self.score("nothing", fit_model(dataset, start, self.settings))
        names = current.model.names
        log(f"declared model{' + ' + ', '.join(names) if names else ''}: held-out one-step "
            f"{error_text(current.heldout['one_step'], '.3e')}, {self.horizon_s:g}-s rollout "
            f"{error_text(current.heldout['rollout'], '.3e')}")  # fmt: skip
        return current

    def score(self, name: str, model: FittedModel) -> Candidate[FittedModel]:
        """``model`` scored: held-out errors (validation split) and the training BIC."""
        val = self.errors(model, self.val_split)
        return Candidate(
            name, model, model, heldout=val, bic=one_step_bic(self.dataset, model),
        )  # fmt: skip

    def sample_states(self) -> State | None:
        """Every :data:`SAMPLE_STRIDE`-th rod state of the training split."""
        split = self.dataset.split("train")
        arrays = [np.asarray(getattr(split, k))[:, ::SAMPLE_STRIDE] for k in STATE_KEYS]
        return State.from_numpy(*(a.reshape(-1, *a.shape[2:]) for a in arrays))

    def errors(self, model: FittedModel, split: str) -> dict[str, Any]:
        """One-step and rollout errors [m] of ``model`` on a split (``evaluate_model``)."""
        ds = self.dataset
        return evaluate_model(ds.topology, model.params, model.effects, ds, split, self.horizon_s)

    def test_errors(self, current: Candidate[FittedModel]) -> dict[str, Any]:
        return self.errors(current.model, self.test_split)

    def rollout_plot(
        self, before: Candidate[FittedModel], after: Candidate[FittedModel], path: Path
    ) -> Path:
        return rod_state_rollout_plot(
            self.dataset, self.test_split, self.horizon_s, before.model, after.model, path
        )

    def propose(
        self, current: Candidate[FittedModel], names: Sequence[str] | None
    ) -> list[Proposal]:
        ds, model = self.dataset, current.model

        def slack() -> Proposal:
            cables, gate = slack_probe(ds, model, self.settings)
            return Proposal("slack_springs", SlackSprings(ds.topology, springs=cables) if cables
                            else None, gate)  # fmt: skip

        gates = {"slack_springs": slack}
        if self.settings.fit_rest_length:
            gates["rest_length_offset"] = lambda: Proposal(
                "rest_length_offset", None,
                "rest lengths are fitted already (K*l0 in the regression)",
            )  # fmt: skip
        return propose(ds.split("train"), ds.topology, model.names, names, gates)

    def fit_candidate(
        self, current: Candidate[FittedModel], proposal: Proposal, drop: Sequence[str] = ()
    ) -> Candidate[FittedModel]:
        now = current.model
        if drop:
            keep = [e for e in now.effects if e.name not in drop]
            now = FittedModel(now.model.replace(effects=keep), now.n_params)
        scored = self.score(proposal.name, fit_proposal(self.dataset, now, proposal, self.settings))
        if type(proposal.effect) is LinearDrag:  # the implicit form too: keep the better fit
            implicit = replace(proposal, effect=ImplicitLinearDrag(self.dataset.topology))
            other = self.score(
                proposal.name, fit_proposal(self.dataset, now, implicit, self.settings)
            )
            if finite(other.bic) and not other.bic >= scored.bic:
                other.model.notes[proposal.name] = (
                    f"integrated implicitly (as MuJoCo's joint damping): its training BIC "
                    f"{other.bic:.6g} is below the explicit form's {scored.bic:.6g}"
                )  # fmt: skip
                scored = other
        return scored

    def gain(self, candidate: Candidate[FittedModel], current: Candidate[FittedModel]) -> float:
        """Fraction of the held-out one-step error removed (floored at round-off)."""
        now = max(finite(candidate.heldout["one_step"]), ROUND_OFF)
        return 1 - now / max(finite(current.heldout["one_step"]), ROUND_OFF)

    def rank(self, candidate: Candidate[FittedModel]) -> float:
        """The held-out one-step error."""
        return finite(candidate.heldout["one_step"])

    def summary(self, candidate: Candidate[FittedModel]) -> str:
        return (f"one-step {error_text(candidate.heldout['one_step'], '.3e')}, "
                f"rollout {error_text(candidate.heldout['rollout'], '.3e')}")  # fmt: skip

    def separation(
        self, chosen: Candidate[FittedModel], runner: Candidate[FittedModel]
    ) -> tuple[float, str]:
        """How many times the runner-up's held-out one-step error is the chosen one's."""
        ratio = finite(runner.heldout["one_step"]) / max(finite(chosen.heldout["one_step"]), 1e-300)
        return ratio, f"held-out one-step error {ratio:.3g}x the chosen one's"

    def predicted_change(
        self, current: Candidate[FittedModel], candidate: Candidate[FittedModel]
    ) -> np.ndarray:
        return predicted_change(self.dataset, current.model, candidate.model, self.val_split)

    def accept(self, chosen: Candidate[FittedModel]) -> Candidate[FittedModel]:
        return chosen  # fitted jointly already

    # ------------------------------------------------------------------ what is left
    def residual(self, current: Candidate[FittedModel], k: int, plots: Path | None) -> Residual:
        """Per-element residual signatures of the current model (training split)."""
        ds, model = self.dataset, current.model
        res = compute_residuals(ds.topology, model.params, model.effects, ds)
        numbers = summarize(res)
        plot = None
        if plots is not None:
            plot = plot_residuals(res, plots / f"residuals_{k}.png",
                                  f"iteration {k}: residuals of {label(model)}")  # fmt: skip
        text = "Residual signatures of the current model (training split):\n\n"
        return Residual(numbers, text + summary_table(numbers), plot)

    def leftover(self, current: Candidate[FittedModel]) -> tuple[str, ResidualFit | None]:
        """Structure left on noise-free data, and the residual network that absorbs it."""
        err = current.heldout["one_step"]
        if not (err > ROUND_OFF and self.dataset.attrs.get("measurement_noise_std", 0) == 0):
            return "", None
        unexplained = (
            f"held-out one-step error {err:.2e} m is above round-off on noise-free data: "
            "structure remains that no candidate in the library explains"
        )
        if not self.residual_network:
            return unexplained, None
        network, note = self.absorb(current.model)
        return unexplained + note, network

    def absorb(self, model: FittedModel) -> tuple[ResidualFit | None, str]:
        """Fit the residual network; keep it if it lowers the test one-step error. (fit, note)"""
        test = self.test_split
        try:
            fit = fit_residual_network(
                self.dataset, model, self.settings, val_split=self.val_split,
                eval_splits=tuple(dict.fromkeys((self.val_split, test))),
                horizon_s=self.horizon_s, seed=self.settings.seed, log=self.log,
            )  # fmt: skip
        except (RuntimeError, ValueError, InputError) as e:
            return None, f"; a residual network could not be fitted ({e})"
        b, a = fit.before[test]["one_step"], fit.after[test]["one_step"]
        if not np.isfinite(a) or a >= b:
            return None, (f"; a residual network does not absorb it (held-out one-step "
                          f"{b:.2e} m -> {a:.2e} m)")  # fmt: skip
        return fit, (
            f"; a residual network absorbs it: held-out (test) one-step {b:.2e} m -> {a:.2e} m "
            f"({b / a:.3g}x), NOT a physical effect (the declared parameters refitted with it "
            f"move by {', '.join(f'{k} {v:.0%}' for k, v in fit.moved.items())})"
        )

    # ------------------------------------------------------------------ report
    def describe(self) -> str:
        return (
            "Candidates are fitted jointly with the current model by regression on rod states "
            "and compared by held-out one-step errors (validation split) and the BIC of the "
            "training one-step errors. Test errors (test split, never used for selection): "
            "one-step: mean rod position error after one step; rollout: mean rod position "
            f"error after {self.horizon_s:g} s open-loop."
        )

    def test_labels(self) -> dict[str, tuple[str, str]]:
        return {"one_step": ("one-step", "m"), "rollout": (f"{self.horizon_s:g}-s rollout", "m")}

    def settings_summary(self) -> dict[str, Any]:
        return {"anchors": dict(self.settings.anchors), "min_gain": self.criteria.min_gain,
                "min_bic_drop": MIN_BIC_DROP}  # fmt: skip
