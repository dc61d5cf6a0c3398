"""A labelled take placed where the robot model puts its end caps and its floor.

Two constant offsets separate what a capture system measures from what a robot model
describes, and neither is physics:

* **markers beyond the end caps.** Markers sit on the caps' surfaces, millimetres
  beyond the points the model calls end caps (its rod nodes, where springs attach). A
  marker is fixed on its rod, so the offset is constant along the rod's axis: each rod's
  markers are moved onto the model's end caps by half the difference between their
  median distance over the take and the model's cap distance (only that sum is seen;
  it is split evenly between the two ends). A marker map's own offsets
  (``offset:``) are applied before, so a mapped take is left as it is.
* **the floor's height.** The capture system's origin is wherever it was calibrated.
  Where the robot rests on its floor (the take's resting stretches,
  :func:`~identification.data.mocap.stretches.find_stretches`), the lowest end cap lies
  one cap radius (the rod's radius in the model) above the floor: the take's heights
  are shifted so that the floor is at z = 0, where every model puts it.

Both are recorded in the dataset (``placement`` attribute) and printed at import.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from identification.data.mocap.stretches import Stretch
from identification.data.quality import placeholder_samples

#: a rod's markers are moved onto the model's end caps when their median distance
#: differs from the model's by more than this [m] (0.5 mm per end; the millimetre a
#: marker's reconstruction may wander over a take is left to the noise)
MARKER_OFFSET_MIN = 0.001
#: the take's heights are shifted when its floor lies farther than this [m] from z = 0
#: (a soft contact's resting penetration and the markers' noise stay below it; see
#: docs/decisions.md)
FLOOR_SHIFT_MIN = 0.002
#: a marker seen without its rod's other marker is moved along the rod's axis of the
#: nearest frame that sees both, within this [s] (a rod turning at 2 rad/s turns a 5 mm
#: offset by 0.5 mm in it); farther, it is read as unseen
AXIS_NEAR = 0.05


@dataclass(frozen=True)
class Placement:
    """What :func:`place_take` did to a take.

    Attributes:
        beyond: (R,) [m] how far each rod's markers sat beyond the model's end caps, per
            end (half the distance difference; negative: inside them); NaN for a rod
            never seen whole; zero where below :data:`MARKER_OFFSET_MIN` (left).
        floor: the floor's height [m] in the file's (z-up) coordinates, found from the
            resting stretches; NaN when the take never rests.
        shifted: whether the heights were shifted by ``-floor``.
        lone: samples of a marker seen without its rod's other one, away from any
            frame that shows the rod's axis: where its end cap lies is not known, and
            it is read as unseen.
    """

    beyond: np.ndarray
    floor: float
    shifted: bool
    lone: int = 0

    def to_dict(self) -> dict[str, object]:
        return {"markers_beyond_caps_m": [None if not np.isfinite(b) else round(float(b), 6) for b in self.beyond],
                "floor_height_m": None if not np.isfinite(self.floor) else round(self.floor, 6),
                "floor_shifted": self.shifted, "lone_samples_unseen": self.lone}  # fmt: skip

    def lines(self) -> list[str]:
        """What was done, one line each (nothing when nothing was)."""
        out = []
        moved = self.beyond[np.isfinite(self.beyond) & (self.beyond != 0)]
        if moved.size:
            out.append(f"markers sit {1e3 * moved.min():.1f} to {1e3 * moved.max():.1f} mm beyond the model's "
                       f"end caps along {moved.size} rods (their distance over the take against the model's): "
                       "placed onto the end caps" + (f"; {self.lone} samples read as unseen (a marker seen without its "
                       "rod's other one, far from a frame that shows the rod's axis, and what it leaves of a "
                       "frame copied from the one before)"
                       if self.lone else ""))  # fmt: skip
        if self.shifted:
            out.append(f"the floor lies at z = {1e3 * self.floor:.1f} mm (the lowest end caps at rest, less "
                       "their radius): heights measured from it")  # fmt: skip
        return out


def _axis(d: np.ndarray, time: np.ndarray, resting: np.ndarray) -> np.ndarray:
    """Unit axes (F, 3) of a rod's cap-to-cap vectors ``d`` (F, 3) [m] at ``time`` (F,)
    [s]. Where one cap is unseen (a lone marker keeps its measurement): the axis of the
    nearest frame that sees both within :data:`AXIS_NEAR`, or anywhere in the same
    resting stretch (``resting`` (F,): its index, -1 when not at rest; a robot at rest
    turns no rod); NaN elsewhere."""
    n = np.linalg.norm(d, axis=-1)
    ok = np.isfinite(n) & (n > 0)
    u = np.full_like(d, np.nan)
    u[ok] = d[ok] / n[ok, None]
    lone = np.flatnonzero(~ok)
    for group in (None, *np.unique(resting[resting >= 0])):
        both = np.flatnonzero(ok & (resting == group)) if group is not None else np.flatnonzero(ok)
        if not both.size:
            continue
        k = np.searchsorted(time[both], time[lone])  # the first such frame at or after each
        prev, nxt = both[np.clip(k - 1, 0, len(both) - 1)], both[np.clip(k, 0, len(both) - 1)]
        near = np.where(
            np.abs(time[lone] - time[prev]) <= np.abs(time[nxt] - time[lone]), prev, nxt
        )
        take = (
            (np.abs(time[lone] - time[near]) <= AXIS_NEAR)
            if group is None
            else resting[lone] == group
        )
        u[lone[take]] = u[near[take]]
    return u


def markers_onto_caps(
    caps: np.ndarray, lengths: np.ndarray, time: np.ndarray, stretches: Sequence[Stretch] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """End caps ``caps`` (F, 2R, 3) [m] (markers, NaN unseen) at ``time`` (F,) [s] moved
    along each rod's axis (:func:`_axis`, the take's resting ``stretches`` keep a lone
    marker's) onto the model's end caps ``lengths`` (R,) [m] apart, and how far beyond them each
    rod's markers sat, per end (R,) [m] (module docstring). A rod whose markers are
    within :data:`MARKER_OFFSET_MIN` of the model's distance is left (offset 0); one
    never seen whole gives NaN and is left."""
    apart = np.linalg.norm(caps[:, 0::2] - caps[:, 1::2], axis=-1)  # (F, R)
    resting = np.full(len(time), -1)
    for k, s in enumerate(stretches):
        if s.kind == "rest":
            resting[(time >= s.start) & (time < s.end)] = k
    beyond = np.full(len(lengths), np.nan)
    out = caps.copy()
    for r, length in enumerate(lengths):
        d = apart[:, r][np.isfinite(apart[:, r])]
        if not d.size:
            continue
        diff = float(np.median(d)) - float(length)
        if abs(diff) <= MARKER_OFFSET_MIN:
            beyond[r] = 0.0
            continue
        beyond[r] = diff / 2
        u = _axis(caps[:, 2 * r + 1] - caps[:, 2 * r], time, resting)
        out[:, 2 * r] = caps[:, 2 * r] + beyond[r] * u
        out[:, 2 * r + 1] = caps[:, 2 * r + 1] - beyond[r] * u
    return out, beyond


def floor_from_rest(
    caps: np.ndarray, time: np.ndarray, stretches: list[Stretch], radius: np.ndarray
) -> float:
    """The floor's height [m] from the resting stretches of ``stretches``: the median over
    their frames of the lowest seen end cap's height less its rod's ``radius`` (R,) [m]
    (``caps`` (F, 2R, 3) [m], z-up, at ``time`` (F,) [s]); NaN without a resting frame."""
    rest = np.zeros(len(time), dtype=bool)
    for s in stretches:
        if s.kind == "rest":
            rest |= (time >= s.start) & (time < s.end)
    seen = np.isfinite(caps).all(-1)
    z = np.where(seen, caps[..., 2] - np.repeat(radius, 2)[None], np.inf)[rest]
    low = z.min(-1) if z.size else np.array([])
    low = low[np.isfinite(low)]
    return float(np.median(low)) if low.size else float("nan")


def place_take(caps: np.ndarray, time: np.ndarray, stretches: list[Stretch], lengths: np.ndarray,
               radius: np.ndarray) -> tuple[np.ndarray, Placement]:  # fmt: skip
    """A take's end caps ``caps`` (F, 2R, 3) [m] (z-up, at ``time`` (F,) [s]) with its
    markers moved onto the model's end caps (:func:`markers_onto_caps`, rods' cap
    distances ``lengths`` (R,) [m]) and its heights measured from the floor its resting
    ``stretches`` show (:func:`floor_from_rest`, rods' ``radius`` (R,) [m]), where
    these differ by more than :data:`MARKER_OFFSET_MIN` and :data:`FLOOR_SHIFT_MIN`."""
    out, beyond = markers_onto_caps(caps, lengths, time, stretches)
    # a frame whose other caps repeated the frame before reads as a copy once its lone
    # marker is gone (:func:`~identification.data.quality.placeholder_samples`)
    out[placeholder_samples(out) & np.isfinite(out).all(-1)] = np.nan
    lone = int((np.isfinite(caps).all(-1) & ~np.isfinite(out).all(-1)).sum())
    floor = floor_from_rest(out, time, stretches, radius)
    shifted = bool(np.isfinite(floor) and abs(floor) > FLOOR_SHIFT_MIN)
    if shifted:
        out[..., 2] -= floor
    return out, Placement(beyond, floor, shifted, lone)
