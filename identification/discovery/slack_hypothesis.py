"""The slack-cable hypothesis of the multi-step scorer: which springs act as cables,
and its fit.

Slack cables are named by a segmented regression on the smoothed end caps
(:mod:`identification.trajectory.slack_regression`: a stiffness change below each
spring's rest length); the candidate, those springs as cables, is then fitted like
the declared model, from that regression, and compared with the current model as any
other (:class:`~identification.discovery.multi_step.MultiStepScorer`).

Once the model has cables, a spring the regression sees losing its stiffness in
compression less clearly (:data:`FURTHER_SIGNIFICANCE` standard errors) is asked of
the trajectories instead: switched to a cable in the current model, does the
training windows' chi-square drop, their states refitted? Smoothing hides a cable
that goes slack only in short dips at a motion-capture rate: its loss of stiffness can
come out less significant than a spring's.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from identification.discovery.judge import MIN_CHI2_GAIN
from identification.discovery.library import Proposal
from identification.trajectory.end_cap_data import (
    EndCapData,
    TrajectorySettings,
    TrajFit,
    airborne_keep,
    contact_searched,
)
from identification.trajectory.floor_declared import leaning_rows
from identification.trajectory.presets import fit_declared, fit_joint
from identification.trajectory.slack_regression import (
    CABLE_LOSS,
    CABLE_SIGNIFICANCE,
    SlackRegression,
    slack_regression,
)
from identification.trajectory.window_states import fit_states
from tensegrity_env.effects import SlackSprings
from tensegrity_env.effects.base import PhysicalEffect


def slack_hypothesis(data: EndCapData, current: TrajFit, anchors: dict[str, float]) -> Proposal:
    """Cables from the segmented regression on ``data``'s training end caps.

    The candidate holds every cable of ``current``, old and new (its effect None when
    no new one shows), and starts from the regression's parameter values. On the floor
    the regression uses the rods away from it and the moments of those leaning on it
    about their contact points (:func:`~identification.trajectory.floor_declared.leaning_rows`),
    else the airborne samples.
    """
    old = [e for e in current.effects if e.name == SlackSprings.name]
    known = {int(i) for e in old for i in e.values["springs"].tolist()}
    if len(known) == data.topology.n_springs:
        return Proposal("slack_springs", None, f"all {len(known)} springs are cables already")
    rows = leaning_rows(data) if data.on_floor else {"keep": airborne_keep(data)}
    reg = slack_regression(data.topology, data.smooth["train"], data.train.control, anchors,
                           **rows)  # fmt: skip
    new = sorted(set(reg.cables()) - known)
    how = "segmented regression"
    if known and not new:
        new = switched_cables(data, current, reg, known)
        how = "switched in the current model, the training chi-square drops"
    if not new:
        free = [i for i in range(data.topology.n_springs) if i not in known]
        z = reg.significance[free]
        return Proposal("slack_springs", None,
                        f"no (further) spring loses at least {CABLE_LOSS:.0%} of K when compressed "
                        f"by {CABLE_SIGNIFICANCE:g} standard errors (largest significance "
                        f"{z.max():.3g})")  # fmt: skip
    cables = sorted(known | set(new))
    loss = reg.loss[new]
    gate = (f"{len(new)} {'more ' if known else ''}springs lose {np.median(loss):.0%} of K "
            f"when compressed ({how}, ≥{reg.significance[new].min():.0f} "
            f"standard errors)")  # fmt: skip
    return Proposal("slack_springs", SlackSprings(data.topology, springs=cables), gate,
                    start=reg.values)  # fmt: skip


#: the regression's bar for a further cable once the model has cables: the trajectories
#: decide (:func:`switched_cables`)
FURTHER_SIGNIFICANCE = 3.0
#: Levenberg-Marquardt iterations of the switched model's window states
SWITCH_ITER = 5


def switched_cables(
    data: EndCapData, current: TrajFit, reg: SlackRegression, known: set[int]
) -> list[int]:
    """Further cables chosen by switching springs to cables in ``current``.

    The springs offered are those the regression marks as losing :data:`CABLE_LOSS` of
    K in compression by :data:`FURTHER_SIGNIFICANCE` standard errors. Forward
    selection: the spring whose switch lowers the training chi-square
    ``(SSE_before - SSE_switched) / σ̂²`` most is taken while that drop is at least
    :data:`~identification.discovery.judge.MIN_CHI2_GAIN`, then the rest are tried
    again with it (a spring switched in place of a missing cable makes up for part of
    it). Only the training windows' states are refitted, from ``current``'s.
    """
    z, loss = reg.significance, np.nan_to_num(reg.loss)
    offered = [i for i in range(data.topology.n_springs)
               if i not in known and loss[i] >= CABLE_LOSS and z[i] >= FURTHER_SIGNIFICANCE]  # fmt: skip
    if not offered:
        return []
    vec = current.vec.held_at(current.theta)
    others = [e for e in current.effects if e.name != SlackSprings.name]

    def sse(cables: set[int]) -> float:
        engine = data.engine.with_effects([*others,
                                           SlackSprings(data.topology, springs=sorted(cables))])  # fmt: skip
        w = fit_states(engine, vec, current.windows, SWITCH_ITER, spin=data.spin, roll=data.roll,
                       grow=False)  # fmt: skip
        return float(w.history[-1]) * w.windows.residuals

    chosen: set[int] = set()
    base = sse(known)
    sigma2 = base / current.m
    while offered:
        gains = {i: (base - sse(known | chosen | {i})) / sigma2 for i in offered}
        best = max(gains, key=lambda i: gains[i])
        data.log("    switched to a cable: " + ", ".join(
            f"spring {i} {g:+.4g}" for i, g in gains.items()) + " (training chi-square)")  # fmt: skip
        if gains[best] < MIN_CHI2_GAIN:
            break
        chosen.add(best)
        offered.remove(best)
        base -= gains[best] * sigma2
    return sorted(chosen)


def fit_slack(
    data: EndCapData,
    s: TrajectorySettings,
    current: TrajFit,
    proposal: Proposal,
    keep: Sequence[PhysicalEffect],
) -> TrajFit:
    """The cable hypothesis (``proposal``, with ``keep`` but its cables) fitted like the
    declared model, from its own regression; returns the fit on the training windows.

    Started from the current model instead, a fit stays near the compromise the
    springs made for the missing cables (lower stiffness, shorter rest length).
    With a searched contact in the model (its parameters held) the usual joint fit
    runs instead.
    """
    assert proposal.effect is not None
    # the proposal holds every cable, old and new: the current cables' effect is replaced
    # (kept beside it, the push of a cable in both would be removed twice: a pull)
    effects = [*(e for e in keep if e.name != proposal.name), proposal.effect]
    if contact_searched(current.vec):
        return fit_joint(data, current, effects, s.candidate_iter)
    many, fit = fit_declared(data, s, effects=effects, values=proposal.start)
    data.log(f"    {proposal.name}: fitted from the segmented regression, end-cap RMS "
             f"{many.rms * 1e3:.3f} mm on {many.windows.size} windows")  # fmt: skip
    return fit
