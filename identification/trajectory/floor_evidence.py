"""What end caps on a floor can show about the contact and the declared model.

A structure on the floor informs its parameters through three kinds of motion, and a
recording may hold some of them only:

* **Impacts** (an end cap coming down onto the floor from :data:`LIFT` above it):
  how deep a cap sinks and how fast the bounce dies out separate the contact's
  stiffness, impedance and damping.
* **Motion along the floor** (a touching end cap whose centre moves along the floor
  faster than :data:`MOVING`; sliding or rolling, which end caps cannot tell apart):
  friction acts only here. Sliding pins the friction coefficient; rolling without
  slipping only bounds it from below.
* **Rest** (every end cap slower than :data:`RESTING` while some touch the floor, for
  :data:`REST_S` or longer): static equilibrium. The weight is carried by the springs
  and the contact's normal forces, which pins the rest lengths and the stiffnesses'
  ratios, but says nothing about friction or damping.

:func:`floor_evidence` measures each from the end caps (speeds from caps smoothed over
:data:`SMOOTHING_S`, so that 1 mm motion-capture noise stays well under the speed
thresholds; heights over the shorter :data:`HEIGHT_SMOOTHING_S`), and :meth:`FloorEvidence.unseen` names the contact parameters the data
cannot pin.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from identification.data.end_caps import smooth_nodes
from identification.trajectory.airborne import AIRBORNE, cap_radii
from identification.trajectory.touchdown import TOUCH
from tensegrity_env.effects import GroundContact
from tensegrity_env.topology import Topology

#: smoothing std of the end caps before differencing [s]: 1 mm noise at 60-1000 Hz
#: leaves under 5 mm/s of speed noise per axis
SMOOTHING_S = 0.05
#: smoothing std of the end caps' heights [s] (short: a bounce lasts a few samples)
HEIGHT_SMOOTHING_S = 0.01
#: height [m] an end cap must rise above the floor for its next touch to count as an impact
LIFT = 0.02
#: speed along the floor [m/s] above which a touching end cap slides or rolls
MOVING = 0.05
#: speed [m/s] under which every end cap counts as at rest
RESTING = 0.02
#: shortest stretch at rest [s] that counts as static equilibrium
REST_S = 0.2
#: least share of touching cap samples moving along the floor that shows friction
FRICTION_SHARE = 0.01


@dataclass(frozen=True)
class FloorEvidence:
    """What a split's end caps hold about the floor.

    Attributes:
        touching_share: share of samples in which some end cap touches the floor
            (within :data:`TOUCH` of the floor height).
        moving_share: share of touching end-cap samples that move along the floor
            faster than :data:`MOVING`.
        impacts: end caps coming down onto the floor from :data:`LIFT` above it,
            summed over caps and trajectories.
        rest_s: time at rest on the floor, summed over stretches of at least
            :data:`REST_S` [s].
        duration_s: time recorded, summed over trajectories [s].
    """

    touching_share: float
    moving_share: float
    impacts: int
    rest_s: float
    duration_s: float

    def unseen(self) -> dict[str, str]:
        """Contact parameter -> why this data cannot pin it (empty when it can pin all)."""
        out: dict[str, str] = {}
        if self.touching_share == 0:
            why = "no end cap touches the floor"
            return {k: why for k in ("stiffness", "damping", "impedance", "friction")}
        if self.moving_share < FRICTION_SHARE:
            out["friction"] = (
                f"touching end caps move along the floor in {self.moving_share:.1%} of their "
                f"samples (< {FRICTION_SHARE:.0%}): friction acts only on sliding or rolling "
                "caps, so its value is the start, not identified"
            )
        if self.impacts == 0:
            out["damping"] = (
                "no end cap comes down onto the floor: contact damping, seen in how "
                "impacts die out, rests on resting caps alone"
            )
        return out

    def lines(self) -> list[str]:
        """One line per kind of motion, for a report."""
        return [
            f"end caps touch the floor in {self.touching_share:.0%} of the samples",
            f"impacts: {self.impacts} (contact stiffness, impedance and damping)",
            f"touching caps slide or roll in {self.moving_share:.0%} of their samples (friction)",
            f"at rest on the floor for {self.rest_s:.1f} s of {self.duration_s:.1f} s "
            "(static equilibrium: rest lengths and stiffness ratios)",
        ]

    def markdown(self) -> str:
        """A report section: what the data shows and the contact parameters it cannot pin."""
        L = ["## What the floor data shows", "", *[f"- {line}" for line in self.lines()]]
        unseen = self.unseen()
        if unseen:
            L += ["", "Not identified from this data:", ""]
            L += [f"- ground_contact.{k}: {why}" for k, why in unseen.items()]
        return "\n".join(L)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready fields plus the ``unseen`` parameters."""
        return {**asdict(self), "unseen": self.unseen()}


def floor_evidence(
    nodes: np.ndarray, dt: float, topology: Topology, height: float = 0.0
) -> FloorEvidence:
    """Impacts, motion along the floor and rest in end caps ``nodes`` (N, T+1, 2R, 3) [m]
    sampled every ``dt`` [s], with the floor at ``height`` [m] (gaps as NaN)."""
    N, T1 = nodes.shape[:2]
    vel = np.gradient(smooth_nodes(nodes, dt, SMOOTHING_S), dt, axis=1)
    gap = smooth_nodes(nodes, dt, HEIGHT_SMOOTHING_S)[..., 2] - cap_radii(topology) - height
    seen = np.isfinite(gap) & np.isfinite(vel).all(-1)
    touching = seen & (gap < TOUCH)
    along = np.linalg.norm(vel[..., :2], axis=-1)
    moving = touching & (along > MOVING)
    still = np.where(seen, np.linalg.norm(vel, axis=-1) < RESTING, False).all(-1)
    resting = still & touching.any(-1)
    return FloorEvidence(
        touching_share=float(touching.any(-1).mean()),
        moving_share=float(moving.sum() / max(int(touching.sum()), 1)),
        impacts=_impacts(np.where(seen, gap, np.nan)),
        rest_s=float(sum(_long_runs(row, round(REST_S / dt)) for row in resting) * dt),
        duration_s=float(N * (T1 - 1) * dt),
    )


def contact_evidence(
    nodes: np.ndarray, dt: float, topology: Topology, contact: GroundContact
) -> FloorEvidence:
    """:func:`floor_evidence` with the floor at ``contact``'s height."""
    return floor_evidence(nodes, dt, topology, float(contact.values["height"].reshape(-1)[0]))


def _impacts(gap: np.ndarray) -> int:
    """End caps coming down onto the floor: a cap's ``gap`` (N, T+1, 2R) [m] falling under
    :data:`AIRBORNE` after having been :data:`LIFT` above the floor (NaN samples skipped)."""
    count = 0
    for trace in gap.transpose(0, 2, 1).reshape(-1, gap.shape[1]):
        up = False
        for g in trace[np.isfinite(trace)]:
            if g > LIFT:
                up = True
            elif up and g < AIRBORNE:
                count += 1
                up = False
    return count


def _long_runs(mask: np.ndarray, shortest: int) -> int:
    """Samples of ``mask`` (T,) that lie in runs of ``shortest`` or more True samples."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    lengths = edges[1::2] - edges[::2]
    return int(lengths[lengths >= shortest].sum())
