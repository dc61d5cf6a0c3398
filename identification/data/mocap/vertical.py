"""Which way is up in a take, found from its end caps.

Two kinds of evidence, in order:

* **free flight**: where the robot flies (dropped, jumping), the centre of its end caps
  accelerates at g, straight down. Stretches of at least :data:`FLIGHT_MIN` whose
  centre's acceleration (second differences, averaged over :data:`FLIGHT_SMOOTH`) is
  within :data:`FLIGHT_TOL` of 9.81 m/s^2 give gravity's direction.
* **a floor**: where it rests or rolls, its lowest end cap stays at the floor's height
  and its two lowest caps sit level. Along the floor's normal that holds for most of
  the take (also when a person lifts the robot for a while); along a wall, a resting
  robot's outermost cap keeps its place too, but its two outermost caps are level only
  by chance and not across takes' stretches.

The vertical is the file's axis (x, y or z, pointing up) nearest to what was found.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: standard gravity [m/s^2]
G = 9.81
#: a stretch of free flight lasts at least this [s] (a drop from 5 cm takes 0.1 s)
FLIGHT_MIN = 0.05
#: accelerations are averaged over this span [s] (marker noise of 0.1 mm gives ~2 m/s^2
#: per frame at 120 Hz; averaged over 6 frames and a dozen caps, ~0.3)
FLIGHT_SMOOTH = 0.05
#: a flying robot's centre accelerates at g within this fraction
FLIGHT_TOL = 0.15
#: resting on a floor: the lowest cap within this [m] of its usual height, and the two
#: lowest caps within it of each other (markers sit millimetres above a cap's contact)
FLOOR_BAND = 0.01
#: a floor holds for at least this fraction of the take's frames along its normal ...
FLOOR_SHARE = 0.5
#: ... and for at most this fraction of that along any other axis direction
FLOOR_MARGIN = 0.7
#: the file's axis nearest to the evidence must be within this angle [deg] of it
AXIS_ANGLE = 30.0
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class Vertical:
    """What a take says of its vertical.

    Attributes:
        up: the file's up direction as a unit vector (3,) in file coordinates.
        axis: the file's axis nearest to it, ``"x"``, ``"y"`` or ``"z"``, with a ``-``
            when up points along the axis's negative direction.
        angle: the angle between ``up`` and that axis [deg].
        evidence: how it was found, for messages.
    """

    up: np.ndarray
    axis: str
    angle: float
    evidence: str


def _nearest_axis(up: np.ndarray) -> tuple[str, float]:
    k = int(np.argmax(np.abs(up)))
    angle = float(np.degrees(np.arccos(min(1.0, abs(up[k])))))
    return ("-" if up[k] < 0 else "") + AXES[k], angle


def free_flight(caps: np.ndarray, time: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Gravity's direction (3,) (unit, pointing down) from the stretches where the
    centre of the end caps ``caps`` (F, N, 3) [m] at ``time`` (F,) [s] accelerates at
    g, and their total duration [s]; None without such stretches."""
    F, N = caps.shape[:2]
    seen = np.isfinite(caps).all(-1)
    acc = np.full((F, 3), np.nan)
    for f in range(1, F - 1):
        both = seen[f - 1] & seen[f] & seen[f + 1]
        if both.sum() < max(N - 2, 1):
            continue
        c = caps[f - 1 : f + 2, both].mean(1)  # (3, 3)
        h0, h1 = time[f] - time[f - 1], time[f + 1] - time[f]
        acc[f] = 2.0 * ((c[2] - c[1]) / h1 - (c[1] - c[0]) / h0) / (h0 + h1)
    dt = float(np.median(np.diff(time)))
    w = max(1, round(FLIGHT_SMOOTH / dt))
    ok = np.isfinite(acc).all(-1)
    smooth = np.full((F, 3), np.nan)
    for f in range(F - w + 1):
        if ok[f : f + w].all():
            smooth[f + w // 2] = acc[f : f + w].mean(0)
    norm = np.linalg.norm(smooth, axis=-1)
    fly = np.isfinite(norm) & (np.abs(norm - G) < FLIGHT_TOL * G)
    keep = np.zeros(F, dtype=bool)  # runs of at least FLIGHT_MIN
    start = None
    for f in range(F + 1):
        if f < F and fly[f]:
            start = f if start is None else start
        elif start is not None:
            if time[f - 1] - time[start] + dt >= FLIGHT_MIN:
                keep[start:f] = True
            start = None
    if not keep.any():
        return None
    down = smooth[keep].mean(0)
    return down / np.linalg.norm(down), float(keep.sum() * dt)


def floor_shares(caps: np.ndarray) -> np.ndarray:
    """(6,): for each direction +x, -x, +y, -y, +z, -z taken as up, the fraction of the
    frames of ``caps`` (F, N, 3) [m] in which the lowest cap lies within
    :data:`FLOOR_BAND` of its median height and the two lowest lie level within it."""
    out = np.zeros(6)
    seen = np.isfinite(caps).all(-1)
    frames = seen.sum(-1) >= 2
    if not frames.any():
        return out
    for k in range(6):
        up = np.zeros(3)
        up[k // 2] = 1.0 if k % 2 == 0 else -1.0
        h = np.where(seen, caps @ up, np.inf)[frames]
        two = np.sort(h, axis=-1)[:, :2]
        low = two[:, 0]
        share = (np.abs(low - np.median(low)) < FLOOR_BAND) & (two[:, 1] - two[:, 0] < FLOOR_BAND)
        out[k] = share.mean()
    return out


def find_vertical(caps: np.ndarray, time: np.ndarray) -> Vertical | None:
    """The vertical of a take from its end caps ``caps`` (F, N, 3) [m] (NaN unseen) at
    ``time`` (F,) [s], in file coordinates: from free flight where there is any, else
    from a floor; None when neither is found."""
    flight = free_flight(caps, time)
    if flight is not None:
        down, seconds = flight
        axis, angle = _nearest_axis(-down)
        return Vertical(-down, axis, angle, f"free flight over {seconds:.2g} s accelerates along "
                        f"{_signed(down)} at g")  # fmt: skip
    shares = floor_shares(caps)
    per_axis = shares.reshape(3, 2).max(-1)
    k = int(np.argmax(per_axis))
    others = np.delete(per_axis, k)
    if per_axis[k] < FLOOR_SHARE or others.max() > FLOOR_MARGIN * per_axis[k]:
        return None
    plus, minus = shares[2 * k], shares[2 * k + 1]
    up = np.zeros(3)
    up[k] = 1.0 if plus >= minus else -1.0
    axis, _ = _nearest_axis(up)
    text = (f"the lowest end caps rest on a plane normal to {AXES[k]} in {100 * per_axis[k]:.0f} % "
            f"of the frames (at most {100 * others.max():.0f} % along another axis)")  # fmt: skip
    if min(plus, minus) > FLOOR_MARGIN * max(plus, minus):
        return Vertical(np.eye(3)[k], AXES[k], 0.0, text + f"; which way is up along {AXES[k]} is not "
                        f"seen (nothing leaves the floor): taken as +{AXES[k]}")  # fmt: skip
    return Vertical(up, axis, 0.0, text + f", nothing below it along {axis}")


def _signed(v: np.ndarray) -> str:
    axis, angle = _nearest_axis(v)
    return f"{axis} ({angle:.0f} deg off)" if angle >= 1 else axis
