"""Which way is up in a take, found from its end caps.

Two kinds of evidence, in order:

* **free flight**: where the robot flies (dropped, jumping), the centre of its end caps
  accelerates at g, straight down. Stretches of at least :data:`FLIGHT_MIN` whose
  centre's acceleration (second differences, averaged over :data:`FLIGHT_SMOOTH`, and
  its median over the stretch: an impact's spike smoothed is no flight) is within
  :data:`FLIGHT_TOL` of 9.81 m/s^2, measured to :data:`FLIGHT_ERROR` of it, give
  gravity's direction, unless the floor says otherwise (then the floor is taken).
* **a floor**: where it rests or rolls, its lowest end cap stays at the floor's height
  and its two lowest caps sit level. Along the floor's normal that holds for most of
  the take (also when a person lifts the robot for a while); along a wall, a resting
  robot's outermost cap keeps its place too, but its two outermost caps are level only
  by chance and not across takes' stretches.

The vertical is the file's axis (x, y or z, pointing up) nearest to what was found.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

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
#: ... measured to this fraction of g at least (the standard error of the stretch's mean
#: acceleration): noisy markers make short stretches of any acceleration (1 mm noise at
#: 120 Hz: ~4 m/s^2 over 0.05 s); a tumbling robot's fall measured to 0.1 mm, ~1 m/s^2
FLIGHT_ERROR = 0.15
#: resting on a floor: the lowest cap within this [m] of its usual height, and the two
#: lowest caps within it of each other (markers sit millimetres above a cap's contact)
FLOOR_BAND = 0.01
#: a floor holds for at least this fraction of the take's frames along its normal ...
FLOOR_SHARE = 0.5
#: ... and for at most this fraction of that along any other axis direction
FLOOR_MARGIN = 0.7
#: a robot leaves its floor (lifted, jumping) for at least this fraction of the frames
#: before the floor's side is read from it
LEFT_FLOOR = 0.02
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


def centre_acceleration(caps: np.ndarray, time: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The acceleration of the centre of the end caps ``caps`` (F, N, 3) [m] at ``time``
    (F,) [s]: per frame (second differences over the caps seen in all three frames),
    and that averaged over :data:`FLIGHT_SMOOTH` where at least half the span is
    measured; both (F, 3) [m/s^2], NaN where not measured. Frames that see fewer than
    all but two caps are skipped (second differences over uneven steps)."""
    F, N = caps.shape[:2]
    seen = np.isfinite(caps).all(-1)
    usable = np.flatnonzero(seen.sum(-1) >= max(N - 2, 1))
    dt = float(np.median(np.diff(time)))
    acc = np.full((F, 3), np.nan)
    for a, f, b in zip(usable[:-2], usable[1:-1], usable[2:], strict=True):
        both = seen[a] & seen[f] & seen[b]
        h0, h1 = time[f] - time[a], time[b] - time[f]
        if both.sum() < max(N - 2, 1) or max(h0, h1) > 3.5 * dt:
            continue
        c0, c1, c2 = (caps[k, both].mean(0) for k in (a, f, b))
        acc[f] = 2.0 * ((c2 - c1) / h1 - (c1 - c0) / h0) / (h0 + h1)
    ok = np.isfinite(acc).all(-1)
    smooth = np.full((F, 3), np.nan)
    half = FLIGHT_SMOOTH / 2
    lo = np.searchsorted(time, time - half)
    hi = np.searchsorted(time, time + half, side="right")
    for f in np.flatnonzero(ok):
        if ok[lo[f] : hi[f]].mean() >= 0.5:  # at least half the span measured
            smooth[f] = acc[lo[f] : hi[f]][ok[lo[f] : hi[f]]].mean(0)
    return acc, smooth


def free_flight(caps: np.ndarray, time: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Gravity's direction (3,) (unit, pointing down) from the stretches where the
    centre of the end caps ``caps`` (F, N, 3) [m] at ``time`` (F,) [s] accelerates at
    g, and their total duration [s]; None without such stretches
    (:func:`centre_acceleration`)."""
    F = caps.shape[0]
    dt = float(np.median(np.diff(time)))
    acc, smooth = centre_acceleration(caps, time)
    ok = np.isfinite(acc).all(-1)
    norm = np.linalg.norm(smooth, axis=-1)
    fly = np.isfinite(norm) & (np.abs(norm - G) < FLIGHT_TOL * G)
    keep = np.zeros(F, dtype=bool)  # runs of at least FLIGHT_MIN, unmeasured frames bridged
    start = last = None
    for f in [*np.flatnonzero(fly), None]:
        if f is not None and last is not None and time[f] - time[last] <= 3.5 * dt:
            last = f
            continue
        if start is not None and last is not None and time[last] - time[start] + dt >= FLIGHT_MIN:
            raw = acc[start : last + 1][ok[start : last + 1]]
            typical = np.median(raw, axis=0)  # an impact's spike is not typical
            spread = float(np.linalg.norm(raw.std(0))) / np.sqrt(len(raw))  # noise: the mean's error
            if abs(np.linalg.norm(typical) - G) < FLIGHT_TOL * G and spread < FLIGHT_ERROR * G:
                keep[start : last + 1] = fly[start : last + 1]
        start = last = f
    if not keep.any():
        return None
    down = smooth[keep].mean(0)
    return down / np.linalg.norm(down), float(time[keep][-1] - time[keep][0] + dt) if keep.sum() > 1 else dt


def floor_shares(caps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each direction +x, -x, +y, -y, +z, -z taken as up, (6,) each: the fraction of
    the frames of ``caps`` (F, N, 3) [m] in which the lowest cap lies within
    :data:`FLOOR_BAND` of its median height and the two lowest lie level within it;
    and the fraction in which the lowest cap lies more than that below its median
    height (nothing goes through a floor: along the wrong sign of its normal, a robot
    lifted or jumping sinks below its 'floor')."""
    shares, below = np.zeros(6), np.zeros(6)
    seen = np.isfinite(caps).all(-1)
    frames = seen.sum(-1) >= 2
    if not frames.any():
        return shares, below
    for k in range(6):
        up = np.zeros(3)
        up[k // 2] = 1.0 if k % 2 == 0 else -1.0
        h = np.where(seen, np.nan_to_num(caps) @ up, np.inf)[frames]
        two = np.sort(h, axis=-1)[:, :2]
        low = two[:, 0]
        usual = np.median(low)
        shares[k] = ((np.abs(low - usual) < FLOOR_BAND) & (two[:, 1] - two[:, 0] < FLOOR_BAND)).mean()
        below[k] = (low < usual - FLOOR_BAND).mean()
    return shares, below


def find_vertical(caps: np.ndarray, time: np.ndarray) -> Vertical | None:
    """The vertical of a take from its end caps ``caps`` (F, N, 3) [m] (NaN unseen) at
    ``time`` (F,) [s], in file coordinates: from free flight where there is any, else
    from a floor; None when neither is found."""
    floor = _floor(caps)
    flight = free_flight(caps, time)
    if flight is None:
        return floor
    down, seconds = flight
    axis, angle = _nearest_axis(-down)
    text = f"free flight over {seconds:.2g} s accelerates along {_signed(down)} at g"
    sign_seen = floor is not None and "not seen" not in floor.evidence
    if floor is not None and (floor.axis[-1] != axis[-1] or (sign_seen and floor.axis != axis)):
        return replace(floor, evidence=f"{floor.evidence} (a {text} is not taken)")
    return Vertical(-down, axis, angle, text)


def _floor(caps: np.ndarray) -> Vertical | None:
    """The vertical from a floor (:func:`floor_shares`), None without one."""
    shares, below = floor_shares(caps)
    per_axis = shares.reshape(3, 2).max(-1)
    k = int(np.argmax(per_axis))
    others = np.delete(per_axis, k)
    if per_axis[k] < FLOOR_SHARE or others.max() > FLOOR_MARGIN * per_axis[k]:
        return None
    text = (f"the lowest end caps rest on a plane normal to {AXES[k]} in {100 * per_axis[k]:.0f} % "
            f"of the frames (at most {100 * others.max():.0f} % along another axis)")  # fmt: skip
    plus, minus = below[2 * k], below[2 * k + 1]
    if abs(plus - minus) < LEFT_FLOOR:
        return Vertical(np.eye(3)[k], AXES[k], 0.0, text + f"; which way is up along {AXES[k]} is not "
                        f"seen (nothing leaves the floor): taken as +{AXES[k]}")  # fmt: skip
    up = np.zeros(3)
    up[k] = 1.0 if plus < minus else -1.0
    axis, _ = _nearest_axis(up)
    return Vertical(up, axis, 0.0, text + f", and what leaves it goes towards {axis}")


def _signed(v: np.ndarray) -> str:
    axis, angle = _nearest_axis(v)
    return f"{axis} ({angle:.0f} deg off)" if angle >= 1 else axis
