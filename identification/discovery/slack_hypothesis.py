"""The slack-cable hypothesis of the multi-step scorer: which springs act as cables,
and its fit.

Slack cables are named by a segmented regression on the smoothed end caps
(:mod:`identification.trajectory.slack_regression`: a stiffness change below each
spring's rest length); the candidate, those springs as cables, is then fitted like
the declared model, from that regression, and compared with the current model as any
other (:class:`~identification.discovery.multi_step.MultiStepScorer`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from identification.discovery.end_cap_data import (
    EndCapData,
    TrajectorySettings,
    TrajFit,
    airborne_keep,
    contact_searched,
)
from identification.discovery.end_cap_fits import fit_declared, fit_with
from identification.discovery.floor_fits import floor_rows
from identification.discovery.library import Proposal
from identification.trajectory.slack_regression import (
    CABLE_LOSS,
    CABLE_SIGNIFICANCE,
    slack_regression,
)
from tensegrity_env.effects import SlackSprings
from tensegrity_env.effects.base import PhysicalEffect


def slack_hypothesis(data: EndCapData, current: TrajFit, anchors: dict[str, float]) -> Proposal:
    """Cables from the segmented regression on ``data``'s training end caps.

    The candidate holds every cable of ``current``, old and new (its effect None when
    no new one shows), and starts from the regression's parameter values. On the floor
    the regression uses the rods away from it, else the airborne samples.
    """
    old = [e for e in current.effects if isinstance(e, SlackSprings)]
    known = {int(i) for e in old for i in e.values["springs"].tolist()}
    rows = {"rod_keep": floor_rows(data)} if data.on_floor else {"keep": airborne_keep(data)}
    reg = slack_regression(data.topology, data.smooth["train"], data.train.control, anchors,
                           **rows)  # fmt: skip
    new = sorted(set(reg.cables()) - known)
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
            f"when compressed (segmented regression, ≥{reg.significance[new].min():.0f} "
            f"standard errors)")  # fmt: skip
    return Proposal("slack_springs", SlackSprings(data.topology, springs=cables), gate,
                    start=reg.values)  # fmt: skip


def fit_slack(
    data: EndCapData,
    s: TrajectorySettings,
    current: TrajFit,
    proposal: Proposal,
    keep: Sequence[PhysicalEffect],
) -> TrajFit:
    """The cable hypothesis (``proposal``, with ``keep``) fitted like the declared model,
    from its own regression; returns the fit on the training windows.

    Started from the current model instead, a fit stays near the compromise the
    springs made for the missing cables (lower stiffness, shorter rest length).
    With a searched contact in the model (its parameters held) the usual joint fit
    runs instead.
    """
    assert proposal.effect is not None
    effects = [*keep, proposal.effect]
    if contact_searched(current.vec):
        return fit_with(data, current, effects, s.candidate_iter)
    many, fit = fit_declared(data, s, effects=effects, values=proposal.start)
    data.log(f"    {proposal.name}: fitted from the segmented regression, end-cap RMS "
             f"{many.rms * 1e3:.3f} mm on {many.windows.size} windows")  # fmt: skip
    return fit
