"""The refits of :class:`~identification.discovery.multi_step.MultiStepScorer`: an
accepted candidate on the floor (:func:`floor_refit`, fitted on by :func:`fitted_on`
where it stopped short), and the final model on more of the training split
(:func:`final_refit`).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from identification.data.dataset import Dataset
from identification.discovery.candidate_fits import EndCapFits
from identification.discovery.judge import Candidate, unphysical
from identification.trajectory.airborne import contact_gate
from identification.trajectory.end_cap_data import (
    STUCK_WINDOW,
    EndCapData,
    TrajectorySettings,
    TrajFit,
    fit_trajectory,
)
from identification.trajectory.floor_declared import (
    FloorFit,
    adopt_floor_fit,
    floor_fit,
    floor_steps,
    longer_windows,
)
from identification.trajectory.forked import side_by_side
from identification.trajectory.presets import refit_many
from identification.trajectory.stage_check import fit_diverged
from identification.trajectory.windows import Windows
from tensegrity_env.effects import GroundContact
from tensegrity_env.params import Params


class MultiStepScorer(Protocol):
    """What the refits read of :class:`~identification.discovery.multi_step.MultiStepScorer`."""

    data: EndCapData
    settings: TrajectorySettings
    dataset: Dataset
    start: Params | None
    contact: GroundContact | None
    jobs: int
    noise: float
    log: Callable[[str], None]


#: a final refit whose fitted coordinates (log-parameters, effect coordinates) all moved
#: less than this is reported as having stayed at the last fit: on the floor its
#: Levenberg-Marquardt steps can all be rejected where impacts make the error jump
STILL = 1e-6
#: the final refit stops once three iterations together lower the chi-square by less than
#: this: on the floor benchmark's 94 windows every coordinate was then within 1e-4 of its
#: standard error of where 60 iterations end (docs/decisions.md)
FINAL_STALL = 1.0
#: longest window of the final refit [s] (whole trajectories up to this long)
FINAL_WINDOW_S = 1.0
#: on the floor, an accepted model's joint refit that stopped at its iteration count
#: above this many times the noise level goes on (:func:`fitted_on`)
FIT_WELL = 1.1
#: at most this many more joint fits of :attr:`~TrajectorySettings.base_iter` iterations
MORE_ROUNDS = 2
#: ... each of which must lower the sum of squared errors by this fraction
MORE_GAIN = 0.01


def floor_refit(
    scorer: MultiStepScorer, screened: TrajFit, afresh: FloorFit | None = None
) -> TrajFit:
    """The accepted candidate on the floor, refitted jointly on the floor windows: the
    better (lower end-cap error on those windows) of two fits.

    One starts from the candidate as screened (the declared parameters and the
    contact at the current model's fit). The other is the floor fit of the declared
    model done afresh with the candidate's effects in it, from the same start as the
    first one (:func:`~identification.trajectory.floor_declared.floor_fit`:
    the regression, a contact search, the valley search). Where the current model's
    contact has taken up what the candidate explains (a dissipation it lacked, on an
    overdamped floor), the first stays there, with the candidate's force far below
    its value and the fit worse than the declared model's.
    With the scorer's ``jobs`` above 1 the two fits run side by side. The better goes on
    (:func:`fitted_on`) where it stopped short of fitting the data.
    """
    data, s = scorer.data, scorer.settings
    effects = [e for e in screened.effects if not e.constraint]
    tasks: list[Callable[[], Any]] = [
        lambda: refit_many(data, screened.vec, screened.theta, s, s.base_iter)
    ]
    if afresh is None:  # (a candidate fitted jointly comes with it)
        # one start: this fit afresh is itself the second start against the screened candidate
        one = replace(s, second_start=False)
        tasks.append(lambda: floor_fit(data, one, scorer.start, effects, contact=scorer.contact))
    near, *fresh = side_by_side(tasks, scorer.jobs, scorer.log)
    afresh = afresh or fresh[0]
    scorer.log(f"    floor refit from the screened candidate {near.rms * 1e3:.3f} mm, afresh "
             f"{afresh.fit.rms * 1e3:.3f} mm")  # fmt: skip
    if afresh.fit.sse < near.sse:
        fit = fitted_on(scorer, afresh.fit)
        adopt_floor_fit(data, FloorFit(fit))
        return fit
    return fitted_on(scorer, near)


def fitted_on(scorer: MultiStepScorer, fit: TrajFit) -> TrajFit:
    """``fit`` fitted on (joint fits of :attr:`~TrajectorySettings.base_iter`
    iterations from where it stopped) while its last fit ran out of iterations with the
    end-cap RMS above :data:`FIT_WELL` times the noise level, at most
    :data:`MORE_ROUNDS` times, and only while each lowers the error by
    :data:`MORE_GAIN`. Through impacts the Levenberg-Marquardt steps stay short, so an
    accepted model's refit can run out of iterations while still lowering its error,
    above the declared model's.
    """
    s = scorer.settings
    for _ in range(MORE_ROUNDS):
        if fit.converged or not fit.rms > FIT_WELL * scorer.noise:
            break
        t0 = time.perf_counter()
        more = fit_trajectory(scorer.data, fit.vec, fit.windows, fit.theta, s.base_iter)
        more.origin = more.theta
        scorer.log(f"    fitted on: end-cap RMS {fit.rms * 1e3:.3f} -> {more.rms * 1e3:.3f} mm "
                 f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip
        if not more.sse < (1 - MORE_GAIN) * fit.sse:
            return more if more.sse < fit.sse else fit
        fit = more
    return fit


def final_refit(scorer: MultiStepScorer, current: Candidate[EndCapFits]) -> Candidate[EndCapFits]:
    """The final model refitted on more of the training split.

    Selection fits on short windows (a model missing an effect drifts on long ones),
    and the accepted models on :attr:`~TrajectorySettings.fit_windows` random ones;
    the model written out is refitted from there on every training trajectory, cut
    into windows of up to :data:`FINAL_WINDOW_S`: the spring damping, the weakest
    group, is pinned by long windows (see :mod:`identification.trajectory.identifier`).
    On data that never leaves the floor it is refitted on
    :attr:`~TrajectorySettings.final_floor_windows` floor windows (selection used
    :attr:`~TrajectorySettings.floor_windows`), less those whose states stay above
    :data:`STUCK_WINDOW` times the noise level at the selected model; on drops the
    fits stay on the airborne stretches and touchdowns. It stops at
    :attr:`~TrajectorySettings.final_iter` iterations, or earlier once the error stops
    falling (:data:`FINAL_STALL`). A refit that diverges, leaves
    the physical domain or loses a standard error is not used.
    """
    data, s = scorer.data, scorer.settings
    if data.on_floor:
        count = s.final_floor_windows
        if count <= s.floor_windows:
            return current
        steps = s.final_floor_window or final_floor_steps(scorer, current)
        windows = data.cut("train", steps, count, 5, lift_off=count // 2)
        return refit(scorer, current, windows, within=STUCK_WINDOW * scorer.noise)
    if contact_gate(data.train, data.topology)[0]:
        return current
    steps = max(2, min(round(FINAL_WINDOW_S / data.dt), data.train.n_transitions))
    return refit(scorer, current, data.cut("train", steps, sys.maxsize, 4))


def final_floor_steps(scorer: MultiStepScorer, current: Candidate[EndCapFits]) -> int:
    """Steps of the final refit's floor windows: those the floor fit ended on, or longer
    ones where the final model carries their states
    (:func:`~identification.trajectory.floor_declared.longer_windows`): the model with
    its effects often fits windows the declared model could not, and longer windows pin
    the parameters better."""
    data, s = scorer.data, scorer.settings
    longest = floor_steps(data.dt, s)
    now = data.floor_steps or longest
    if now >= longest:
        return now
    last = current.fit.final
    longer = longer_windows(data, last.vec, last.theta, longest, now, s.floor_windows,
                            scorer.noise)  # fmt: skip
    if longer is None:
        return now
    scorer.log(f"    final refit windows from the model: {longer[0]} steps; {longer[2]}")
    return longer[0]


def refit(
    scorer: MultiStepScorer, current: Candidate[EndCapFits], windows: Windows,
    within: float | None = None,
) -> Candidate[EndCapFits]:  # fmt: skip
    """``current`` refitted on the training ``windows`` (those whose states fit to
    ``within`` [m] end-cap RMS, if given:
    :func:`~identification.trajectory.presets.refit_many`), kept unless it diverges,
    leaves the physical domain or loses a direction the last fit saw (a standard
    error that was finite turns infinite: its curvature matrix is singular there)."""
    t0 = time.perf_counter()
    last = current.fit.final
    s = scorer.settings
    final = refit_many(scorer.data, last.vec, last.theta, s, s.final_iter, windows=windows,
                     within=within, bar="final refit", stall=FINAL_STALL)  # fmt: skip
    ds = scorer.dataset
    model = final.fitted_model(ds.topology, ds.dt)
    why = "diverged" if fit_diverged(final.rms, scorer.noise) else unphysical(model)
    lost = int((np.isinf(final.stderr) & np.isfinite(last.stderr)).sum())
    if not why and lost:
        why = f"{lost} standard errors the last fit pinned are infinite"
    moved = float((final.theta - last.theta).abs().max()) if len(last.theta) else 0.0
    still = "" if moved > STILL else (
        f"; its parameters stayed at the last fit's (largest change {moved:.2g}: no step "
        "lowered the error on these windows)")  # fmt: skip
    stop = "converged" if final.converged else "ran out"
    scorer.log(f"final refit on {final.windows.size} training windows of {windows.steps} "
             f"steps: end-cap RMS {final.rms * 1e3:.3f} mm ({final.iterations} iterations, "
             f"{stop}; {time.perf_counter() - t0:.0f} s)"
             + (f"; not used ({why})" if why else still))  # fmt: skip
    if why:
        return current
    fits = replace(current.fit, final=final)
    return replace(current, fit=fits, model=model)
