"""Multi-step scorer of the residual loop: prediction of measured end caps through the engine.

With noisy end caps (motion capture, ~1 mm), accelerations from differences are
useless and smoothing biases the regression (more than the effects looked for), so
models are compared by **multi-step prediction of the measured end caps**
(:mod:`identification.trajectory.end_cap_data`, :mod:`identification.trajectory.presets`):

1. every candidate is fitted **jointly** (declared parameters, the candidate's and the
   current effects' parameters, each window's initial state) on windows of the
   training split, starting from the current model;
2. it is scored on **held-out** windows (validation split): only the windows' initial
   states are fitted there, parameters held, so the held-out sum of squares
   ``SSE_val`` measures prediction; and by the **BIC** of the training fit,
   ``m ln(SSE/m) + k ln m`` (``k``: global parameters; the window states are common
   to every model);
3. it is accepted by the held-out chi-square ``SSE_val / σ̂²`` it removes (``σ̂``: the
   candidate's held-out RMS, the noise estimate;
   :data:`~identification.discovery.judge.MULTI_STEP`); two passing candidates are
   told apart by the difference of their chi-square gains.

Linear drag is proposed in its implicit form
(:class:`~tensegrity_env.effects.ImplicitLinearDrag`): at the engine's physics step it
equals the explicit form to a relative ``h b / M`` per step where both are stable,
stays stable for stiff damping about a thin rod's own axis, and equals MuJoCo's
free-joint damping.

Slack cables are named by a segmented regression on the smoothed end caps
(:mod:`identification.discovery.slack_hypothesis`) and fitted from it.

A rod's **roll** about its own axis is invisible to end caps, but box-form quadratic
drag depends on it (``sees_roll``): once such an effect is accepted, the windows'
states include each rod's roll in every later fit and score.

Errors before and after are measured on the **test** split: the held-out end-cap
RMS (which cannot fall below the noise) and, when the clean trajectories are known
(planted data), the one-step and rollout errors against them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import numpy as np

from identification.data.dataset import Dataset
from identification.discovery.candidate_fits import EndCapFits
from identification.discovery.end_cap_residuals import (
    plot_window_residuals,
    summarize_window_residuals,
    window_residuals,
)
from identification.discovery.judge import MIN_BIC_DROP, MULTI_STEP, Candidate
from identification.discovery.library import Proposal, propose
from identification.discovery.negligible import NEGLIGIBLE
from identification.discovery.refits import final_refit, floor_refit
from identification.discovery.residual_network import ResidualFit
from identification.discovery.rollout_plots import end_cap_rollout_plot
from identification.discovery.scorer import CandidateSkipped, LoopScorer, Residual
from identification.discovery.slack_hypothesis import fit_slack, slack_hypothesis
from identification.linear.extended import evaluate_model
from identification.report.tables import error_text
from identification.trajectory.airborne import contact_gate
from identification.trajectory.end_cap_data import (
    EndCapData,
    TrajectorySettings,
    TrajFit,
    fit_trajectory,
    fixed_engine,
    heldout,
    predicted_caps,
)
from identification.trajectory.floor_declared import FloorFit, floor_fit
from identification.trajectory.forked import side_by_side
from identification.trajectory.open_loop_check import open_loop_check, worse_prediction
from identification.trajectory.presets import fit_declared, fit_joint, refit_many, screen_candidate
from identification.trajectory.stage_check import check_stage, fit_diverged, noise_level
from identification.trajectory.window_states import fit_states
from identification.trajectory.windows import STATE_KEYS, Windows, sees_roll
from tensegrity_env.effects import GroundContact, ImplicitLinearDrag
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import State
from tensegrity_env.params import Params

#: smoothed training samples per sample where candidates' forces are measured
SAMPLE_STRIDE = 4
#: on the floor, a current model whose training and held-out end-cap RMS are both above
#: this many times the noise level misses something (see
#: :meth:`MultiStepScorer.second_look`); a model with nothing missing fits to about 1
MISFIT = 1.25
#: candidates fitted again with everything free then, largest held-out gain first
SECOND_LOOKS = 2
#: candidates told apart only when fitted the same way: one looked at again brings the
#: other (see :meth:`MultiStepScorer.second_look`)
RIVALS = {"linear_drag": "quadratic_drag", "quadratic_drag": "linear_drag"}


class MultiStepScorer(LoopScorer[EndCapFits]):
    """Scores candidates by multi-step prediction of end caps (see the module docstring).

    Args:
        settings: windows, iterations, smoothing, anchors and seed of the fits.
        horizon_s: rollout horizon of the test errors against ``clean`` [s].
        start: declared parameters to start from (a params file); None: from the
            regression on smoothed end caps.
        clean: the same trajectories without noise, with rod states (planted data),
            for the test errors against the truth; never used for fitting or selection.
        contact: where a floor fit starts the ground contact (a params file's; None:
            the default start, see :mod:`identification.trajectory.floor_declared`).
        jobs: fits run at once, each in a worker process (the two floor refits of an
            accepted candidate; :mod:`~identification.discovery.side_by_side`).
        effects: what the declared model holds beyond linear springs and a floor (a
            params file's: an NTRT model's tension-only springs), fitted with it and kept
            in every model the loop compares.
    """

    criteria = MULTI_STEP
    method = "multi_step"

    def __init__(
        self,
        settings: TrajectorySettings,
        horizon_s: float = 1.0,
        start: Params | None = None,
        clean: Dataset | None = None,
        contact: GroundContact | None = None,
        jobs: int = 1,
        effects: Sequence[PhysicalEffect] = (),
    ) -> None:
        self.settings = settings
        self.effects = list(effects)
        self.jobs = jobs
        self.horizon_s = horizon_s
        self.start = start
        self.clean = clean
        self.contact = contact
        self._tested: dict[int, tuple[TrajFit, tuple[float, int, Windows]]] = {}
        #: the data's training windows, contact range and rolls before the last accept
        self._before_accept: tuple[dict[str, Windows], Any, bool] | None = None

    def begin(self, dataset: Dataset, log: Callable[[str], None]) -> Candidate[EndCapFits]:
        self.dataset, self.log = dataset, log
        self.data = EndCapData(dataset, self.settings)
        self.data.log = log
        self.data.contact_start = self.contact
        t0 = time.perf_counter()
        self.noise = noise_level(dataset.split("train").nodes, rods=True)
        log(f"noise level estimated from the training end caps: {self.noise * 1e3:.3g} mm")
        final, base = fit_declared(self.data, self.settings, self.start, self.effects)
        log(f"declared model: end-cap RMS {final.rms * 1e3:.3f} mm on {final.windows.size} "
            f"training windows ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
        for fit in (final, base):
            check_stage("the declared model's fit", fit.rms, self.noise, "shorter windows "
                        "(--window), a smaller --physics-dt, or a starting params file "
                        "(--params)")  # fmt: skip
        fits = EndCapFits(base, final)
        if not self.data.on_floor:
            return self.score("nothing", self.with_reference(fits))
        # Independent of each other, so side by side (with --jobs): the screened reference,
        # the model's held-out score (its states start the reference's) and its test score.
        referenced, first, tested = side_by_side([
            lambda: self.with_reference(fits),
            lambda: self.score("nothing", fits),
            lambda: heldout(self.data, final, "test", self.settings.state_iter),
        ], self.jobs, self.log)  # fmt: skip
        self._tested[id(referenced.final)] = (referenced.final, tested)
        return self.score("nothing", referenced, first.fit)

    def with_reference(self, fits: EndCapFits) -> EndCapFits:
        """``fits`` of the current model with its reference: the model refitted as every
        candidate will be (:func:`fit_joint`, from ``fits.fit``'s origin and windows, the
        candidates' iterations), so a candidate's gain and BIC drop measure its effect,
        not the iterations it had on top of the current fit: without it, the current
        model refitted with nothing added gains in held-out chi-square and BIC, and a
        candidate with coefficients near zero passes. On the floor the reference is
        screened as the candidates are (:func:`screen_candidate`: the contact held, the
        linear effects' coordinates and the states fitted): against the current model as
        fitted, every screened candidate gains on floor data with nothing planted. Not on
        floor data without a touchdown (its candidates are fitted with the contact, see
        :meth:`fit_candidate`).
        """
        now = fits.fit
        if self.data.on_floor:
            return replace(fits, reference=screen_candidate(self.data, now, now.effects,
                                                       self.settings.candidate_iter))  # fmt: skip
        if contact_gate(self.data.train, self.data.topology)[0]:
            return fits
        return replace(fits, reference=fit_joint(self.data, now, now.effects,
                                                self.settings.candidate_iter))  # fmt: skip

    def score(
        self, name: str, fits: EndCapFits, near: EndCapFits | None = None, fresh: bool = False
    ) -> Candidate[EndCapFits]:
        """Held-out (validation) end-cap errors of ``fits.scored``, states only fitted.

        On the floor a candidate's states start from ``near``'s (the current model's)
        fitted ones: refitted from smoothing, each model's windows stop in other basins
        (the impacts make the error jump), which gives a copy of the current model (a
        candidate whose coefficients stay near zero) a held-out chi-square gain on floor
        data with nothing planted; from the current model's states, none.
        ``fresh``: from smoothing too, each window keeping the better state (an accepted
        model, the next candidates' ``near``; see :func:`heldout`).
        """
        warm = near.val_windows if near is not None and self.data.on_floor else None
        fits.val_sse, fits.val_m, fits.val_windows = heldout(
            self.data, fits.scored, "val", self.settings.state_iter, warm, fresh
        )
        final, ds = fits.final, self.dataset
        return Candidate(
            name, fits, final.fitted_model(ds.topology, ds.dt),
            heldout={"caps_rms": float(np.sqrt(fits.val_sse / max(fits.val_m, 1)))},
            bic=fits.scored.bic,
        )  # fmt: skip

    def rollout_plot(
        self, before: Candidate[EndCapFits], after: Candidate[EndCapFits], path: Path
    ) -> Path:
        fitted = (self.tested(before.fit.final)[2], self.tested(after.fit.final)[2])
        return end_cap_rollout_plot(self.data, before.fit.final, after.fit.final, fitted, path)

    def tested(self, fit: TrajFit) -> tuple[float, int, Windows]:
        """:func:`heldout` of ``fit`` on the test split, fitted once per fit."""
        if id(fit) not in self._tested:  # the fit is kept with its score: its id stays its own
            self._tested[id(fit)] = (fit, heldout(self.data, fit, "test", self.settings.state_iter))
        return self._tested[id(fit)][1]

    def test_errors(self, current: Candidate[EndCapFits]) -> dict[str, Any]:
        """Test-split errors: held-out end-cap RMS [m]; against the clean truth if given."""
        fit = current.fit.final
        sse, m, _ = self.tested(fit)
        out = {"caps_rms": float(np.sqrt(sse / m))}
        if self.clean is not None:
            topo = self.data.topology
            ev = evaluate_model(topo, fit.params, fit.effects, self.clean, "test", self.horizon_s)
            out.update(one_step=float(ev["one_step"]), rollout=float(ev["rollout"]))
        return out

    # ------------------------------------------------------------------ candidates
    def propose(
        self, current: Candidate[EndCapFits], names: Sequence[str] | None
    ) -> list[Proposal]:
        data = self.data
        fit = current.fit.fit
        control = bool(np.any(data.train.control != 0))
        lag = "not yet available for end-cap-only data" if control else "no control in this data"
        gates: dict[str, Callable[[], Proposal]] = {
            "slack_springs": lambda: slack_hypothesis(data, fit, self.settings.anchors),
            "rest_length_offset": lambda: Proposal(
                "rest_length_offset", None, "rest lengths are fitted already"
            ),
            "control_lag": lambda: Proposal("control_lag", None, lag),
            "linear_drag": lambda: Proposal(
                "linear_drag",
                ImplicitLinearDrag(data.topology),
                "acts everywhere, opposing v and ω; integrated implicitly",
            ),
        }
        have = [e.name for e in fit.effects]
        return propose(data.train, data.topology, have, names, gates, again=("slack_springs",))

    def fit_candidate(
        self, current: Candidate[EndCapFits], proposal: Proposal, drop: Sequence[str] = ()
    ) -> Candidate[EndCapFits]:
        s, now = self.settings, current.fit.fit
        assert proposal.effect is not None
        keep = [e for e in now.start_effects if e.name not in drop]
        if proposal.start is not None and self.data.on_floor:
            return self.fit_jointly(current, proposal, drop)
        if proposal.start is not None:
            fit = fit_slack(self.data, s, now, proposal, keep)
        elif self.data.on_floor:
            held = [e for e in now.effects if e.name not in drop]
            fit = screen_candidate(self.data, now, [*held, proposal.effect], s.candidate_iter)
        else:
            fit = fit_joint(self.data, now, [*keep, proposal.effect], s.candidate_iter)
        return self.score_candidate(proposal.name, fit, current)

    def score_candidate(
        self, name: str, fit: TrajFit, current: Candidate[EndCapFits], floor: FloorFit | None = None
    ) -> Candidate[EndCapFits]:
        """Candidate ``name`` fitted as ``fit`` (from ``floor``, if fitted afresh), scored
        against ``current``; :class:`CandidateSkipped` if the fit diverged."""
        if fit_diverged(fit.rms, self.noise):
            raise CandidateSkipped(f"its fit diverged (end-cap RMS {fit.rms * 1e3:.3g} mm)")
        return self.score(name, EndCapFits(fit, fit, floor=floor), current.fit)

    def second_look(
        self, current: Candidate[EndCapFits], tried: Sequence[Candidate[EndCapFits]]
    ) -> list[str]:
        """On the floor, where no screened candidate passes and the current model fits both
        the training windows and the held-out ones worse than :data:`MISFIT` times the
        noise level: the
        :data:`SECOND_LOOKS` candidates with the largest positive held-out gains and a
        force that is not negligible, to be fitted with the declared model and the contact
        free (:meth:`fit_jointly`).

        A screen holds the declared parameters and the contact where the current model's
        fit left them; where that fit made up for a missing effect they stay there, and the
        effect cannot show (a declared fit that made up for a missing drag with its
        common scale and the contact's stiffness leaves no screen passing). Both errors
        must be high: the held-out windows' states are fitted from smoothing and from the
        last model's, the better kept, while the training windows keep the states of
        their joint fit, which through the impacts can stop in other basins, so the
        training error alone can be high for a model that misses nothing.

        A drag looked at again brings its rival (:data:`RIVALS`) if that was screened with a
        force that is not negligible, whatever its screened gain: the two are compared on
        fits made the same way (screened, the true drag can rank below its rival, which
        fitted again alone would then pass).
        """
        if not self.data.on_floor or any(c.accepted for c in tried):
            return []
        misfit = min(current.fit.final.rms, current.heldout["caps_rms"])
        if not misfit > MISFIT * self.noise:
            return []
        # (a negligible force cannot be what the model misses: its gain is the states')
        forceful = [c for c in tried if not c.size < NEGLIGIBLE]
        # (slack cables were fitted with everything free already: a floor fit of their own)
        hopeful = sorted((c for c in forceful if c.gain > 0 and c.fit.floor is None),
                         key=lambda c: -c.gain)  # fmt: skip
        names = [c.name for c in hopeful[:SECOND_LOOKS]]
        screened = {c.name for c in forceful}
        rivals = [RIVALS[n] for n in names if RIVALS.get(n) in screened - set(names)]
        return names + rivals

    def fit_jointly(
        self, current: Candidate[EndCapFits], proposal: Proposal, drop: Sequence[str] = ()
    ) -> Candidate[EndCapFits]:
        """The floor fit done afresh with the current model's effects and the proposed one
        (:func:`~identification.trajectory.floor_declared.floor_fit`: the regression, a contact
        search, the valley search), then fitted on the training windows selection
        compares on, from the current model's window states; ``drop`` as in
        :meth:`fit_candidate`.

        Slack cables start from their own segmented regression (``proposal.start``) and
        the current model's contact (cables do not stand in for a dissipation the contact
        took up), and replace the current model's cables. Like every candidate's, their
        floor fit is not adopted: the data's window sets and contact range stay the
        current model's, whichever candidates were fitted before in the same process.
        """
        if not self.data.on_floor:
            return self.fit_candidate(current, proposal, drop)
        data, s, now = self.data, self.settings, current.fit.fit
        assert proposal.effect is not None
        left_out = {proposal.name, *drop}
        others = [e for e in now.effects
                  if not e.constraint and e.name not in left_out]  # fmt: skip
        contact = self.contact
        if proposal.start is not None:
            # the one constraint effect is the floor contact (GroundContact is the only one)
            found = next((e for e in now.effects if e.constraint), contact)
            contact = cast("GroundContact | None", found)
        floor = floor_fit(data, s, self.start, [*others, proposal.effect], values=proposal.start,
                          contact=contact)  # fmt: skip
        fit = fit_trajectory(data, floor.fit.vec, now.windows, floor.fit.theta, s.candidate_iter)
        fit.origin = floor.fit.theta
        return self.score_candidate(proposal.name, fit, current, floor)

    def gain(self, candidate: Candidate[EndCapFits], current: Candidate[EndCapFits]) -> float:
        """Held-out chi-square removed: ``(SSE_val(current) - SSE_val) / σ̂²``."""
        c = candidate.fit
        if not np.isfinite(c.val_sse):
            return -np.inf
        return (current.fit.val_sse - c.val_sse) / (c.val_sse / max(c.val_m, 1))

    def rank(self, candidate: Candidate[EndCapFits]) -> float:
        """The chi-square gain, larger first."""
        return -candidate.gain

    def summary(self, candidate: Candidate[EndCapFits]) -> str:
        return f"val RMS {error_text(candidate.heldout['caps_rms'], '.4f', 'mm', 1e3)}"

    def separation(
        self, chosen: Candidate[EndCapFits], runner: Candidate[EndCapFits]
    ) -> tuple[float, str]:
        """How much more the chosen candidate lowers the held-out chi-square."""
        gap = chosen.gain - runner.gain
        return gap, f"held-out chi-square {gap:.4g} higher"

    def predicted_change(
        self, current: Candidate[EndCapFits], candidate: Candidate[EndCapFits]
    ) -> np.ndarray:
        """End caps predicted by ``candidate`` minus ``current`` on the held-out windows."""
        windows = current.fit.val_windows
        assert windows is not None
        ref = predicted_caps(self.data, current.fit.scored, windows)
        return (predicted_caps(self.data, candidate.fit.fit, windows) - ref).numpy()

    def accept(self, chosen: Candidate[EndCapFits]) -> Candidate[EndCapFits]:
        """Converged, then refitted on the many windows (rolls too once an effect sees them).

        On the floor the candidate was screened with the declared model and the contact
        held: the joint refit on the floor windows is its convergence, and the training
        windows' states are refitted at that model for the next iteration's comparisons.
        """
        data, s = self.data, self.settings
        now = chosen.fit.fit
        self._before_accept = (dict(data.windows), data.contact_box, data.roll)
        if data.on_floor:
            t1 = time.perf_counter()
            final = floor_refit(self, now, chosen.fit.floor)
            sse, m, windows = heldout(data, final, "train", s.state_iter, now.windows, True)
            fit = replace(final, windows=windows, sse=sse, m=m)
        else:
            fit = fit_joint(data, now, now.effects, s.base_iter)  # converge
            t1 = time.perf_counter()
            final = refit_many(data, fit.vec, fit.theta, s, s.base_iter)
        self.log(f"  refitted on {final.windows.size} training windows: end-cap RMS "
                 f"{final.rms * 1e3:.3f} mm ({time.perf_counter() - t1:.0f} s)")  # fmt: skip
        check_stage(f"the final fit with {chosen.name}", final.rms, self.noise,
                    "--max-effects to stop before it, or --fit-window shorter")  # fmt: skip
        if not data.roll and sees_roll(fixed_engine(data, final)[0]):
            # from now on every fit and score fits the windows' rolls too, so the next
            # candidates are not judged on making up for them (without: a 1.2 N "force
            # field" passed on quadratic drag; 0.06 N once the rolls were fitted)
            # (the states first, at the refitted model: from the rolls of smoothing and no
            # spin, a joint fit converges slowly)
            data.roll = True
            engine, fixed = fixed_engine(data, final)
            windows = fit_states(engine, fixed, fit.windows, s.state_iter, spin=data.spin,
                                 roll=True).windows  # fmt: skip
            fit = fit_trajectory(data, fit.vec, windows, final.theta, s.base_iter)
        fit.origin = final.theta
        scored = self.score(chosen.name, self.with_reference(EndCapFits(fit, final)), chosen.fit,
                            fresh=True)  # fmt: skip
        return replace(chosen, fit=scored.fit, model=scored.model, heldout=scored.heldout,
                       bic=scored.bic)  # fmt: skip

    def refusal(self, added: Candidate[EndCapFits], before: Candidate[EndCapFits]) -> str:
        """On the floor, a refit that fits the floor windows worse than ``before`` did:
        with one more effect the model can fit them at least as well, so the fits with it
        stopped short (through impacts) and judge nothing; accepted, such a candidate
        raises the test error."""
        now, then = added.fit.final, before.fit.final
        if self.data.on_floor and now.m == then.m and now.sse > then.sse:
            return (f"fits the floor windows worse than the current model (end-cap RMS "
                    f"{now.rms * 1e3:.3f} mm against {then.rms * 1e3:.3f} mm): the fits with it "
                    "stopped short")  # fmt: skip
        return self.predicts_worse(added, before)

    def predicts_worse(self, added: Candidate[EndCapFits], before: Candidate[EndCapFits]) -> str:
        """Where ``added`` predicts the validation split open-loop from measured states
        worse than ``before`` at a horizon the benchmarks read (by more than the noise
        level), why; "" otherwise or without a validation split. The windows the
        candidates are judged on are short, each with a fitted initial state: an effect
        can absorb a window's misfit there and predict worse over longer horizons (on a
        dropped real robot, a cubic stiffness passed on windows of 4 samples, and the model
        written with it predicted the held-out end caps worse from 0.25 s on)."""
        if "val" not in self.dataset.splits:
            return ""
        dt = self.settings.physics_dt
        new = open_loop_check(added.model.model, self.dataset, self.noise, dt, ("val",))
        old = open_loop_check(before.model.model, self.dataset, self.noise, dt, ("val",))
        if new is None or old is None:
            return ""
        why = worse_prediction(new, old)
        return f"predicts held-out motion worse than the current model ({why})" if why else ""

    def undo_accept(self) -> None:
        """The training windows, contact range and rolls as before the last accept."""
        if self._before_accept is None:
            return
        windows, self.data.contact_box, self.data.roll = self._before_accept
        self.data.windows.clear()
        self.data.windows.update(windows)

    def sample_states(self) -> State | None:
        """Every :data:`SAMPLE_STRIDE`-th smoothed training state (defined ones only)."""
        grid = self.data.smooth["train"]
        arrays = [np.asarray(getattr(grid, k))[:, ::SAMPLE_STRIDE] for k in STATE_KEYS]
        arrays = [a.reshape(-1, *a.shape[2:]) for a in arrays]
        ok = np.logical_and.reduce([np.isfinite(a).all(axis=(1, 2)) for a in arrays])
        if not ok.any():
            return None
        return State.from_numpy(*(a[ok] for a in arrays))

    def finish(self, current: Candidate[EndCapFits]) -> Candidate[EndCapFits]:
        """:func:`~identification.discovery.refits.final_refit` of ``current``."""
        return final_refit(self, current)

    # ------------------------------------------------------------------ what is left
    def residual(self, current: Candidate[EndCapFits], k: int, plots: Path | None) -> Residual:
        """The current model's held-out (validation) end-cap residuals: numbers and PNG."""
        data, fits = self.data, current.fit
        assert fits.val_windows is not None
        radius = np.repeat([rod.radius for rod in data.topology.rods], 2)
        pred = predicted_caps(data, fits.scored, fits.val_windows)
        res = window_residuals(pred, fits.val_windows.obs, data.dt, radius,
                               fits.val_windows.seen())  # fmt: skip
        r = summarize_window_residuals(res)
        plot = None
        if plots is not None:
            label = " + ".join(["declared model", *(e.name for e in fits.fit.effects)])
            noise = float(self.dataset.attrs.get("measurement_noise_std", 0.0))
            plot = plot_window_residuals(res, plots / f"residuals_{k}.png",
                                         f"iteration {k}: held-out residuals of {label}", noise)  # fmt: skip
        text = (f"Held-out end-cap residual of the current model: RMS {r['rms'] * 1e3:.3f} mm; "
                f"near the floor {r['near_floor'] * 1e3:.3f} mm vs above "
                f"{r['above_floor'] * 1e3:.3f} mm; fastest quarter {r['fast'] * 1e3:.3f} mm vs "
                f"slowest {r['slow'] * 1e3:.3f} mm; end of the window {r['late'] * 1e3:.3f} mm "
                f"vs start {r['early'] * 1e3:.3f} mm.")  # fmt: skip
        return Residual(r, text, plot)

    def leftover(self, current: Candidate[EndCapFits]) -> tuple[str, ResidualFit | None]:
        return "", None  # noisy end caps: what is left cannot be told from the noise here

    # ------------------------------------------------------------------ report
    def describe(self) -> str:
        s = self.settings
        refit = (f"declared model and every accepted one are refitted on {s.fit_windows} training "
                 "windows: the parameters below and the test errors come from that fit.")  # fmt: skip
        if self.data.on_floor:  # (set by begin; describe reports a fitted loop)
            refit = (f"declared model and contact, and every accepted model, are fitted jointly "
                     f"on {s.floor_windows} floor windows of the training split; the final model "
                     f"is refitted on up to {s.final_floor_windows} (the parameters written and "
                     "the final test errors come from that fit).")  # fmt: skip
        return (
            "Models are compared by multi-step prediction of the measured end caps: each is "
            "fitted jointly on windows of the training split; held-out windows (validation) "
            "fit only their initial states. A candidate must lower the training BIC by "
            f"{MIN_BIC_DROP:g} and the held-out chi-square by {self.criteria.min_gain:g}. The "
            + refit
        )

    def test_labels(self) -> dict[str, tuple[str, str]]:
        return {
            "caps_rms": ("end-cap RMS (noisy, window states fitted)", "mm"),
            "one_step": ("one-step vs clean truth", "m"),
            "rollout": (f"{self.horizon_s:g}-s rollout vs clean truth", "m"),
        }

    def settings_summary(self) -> dict[str, Any]:
        s = self.settings
        chosen = self.data.floor_steps if getattr(self, "data", None) is not None else None
        return {"anchors": dict(s.anchors), "window": s.window, "fit_windows": s.fit_windows,
                "floor_windows": s.floor_windows, "floor_window_steps": chosen,
                "final_floor_windows": s.final_floor_windows, "final_iterations": s.final_iter,
                "min_bic_drop": MIN_BIC_DROP,
                "min_chi2_gain": self.criteria.min_gain}  # fmt: skip
