"""A take as a sequence of stretches: at rest, free, or acted on from outside the model.

A robot that no declared force can move the way it moves is touched by something outside
the model (a person lifting it). Off its floor, only gravity acts on the centre of its
end caps (springs are internal): a centre that does not fall at g there, for a sustained
time, is held. Such a stretch is widened back to the last rest or free flight before
it (a robot at rest does not start to move by itself before it is lifted) and on to the
next rest or the first frame that falls freely after it (the release). Resting stretches
are those where the end caps stay still on the floor. Whatever is neither is free: the model's
forces (gravity, springs, floor) explain it, and fits use it.

Times are the take's [s]; end caps are z-up (after the import turned the take upright).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from identification.data.mocap.vertical import (
    FLIGHT_MIN,
    FLIGHT_TOL,
    FLOOR_BAND,
    G,
    centre_acceleration,
)
from tensegrity_env.io_utils import InputError

#: off the floor: the lowest end cap this far [m] above the floor's height (twice the
#: band a resting robot's lowest caps keep)
OFF_FLOOR = 2 * FLOOR_BAND
#: a centre off the floor accelerating this fraction of g away from free fall is held
#: (free fall measured to 0.1 mm markers is within ~0.1 g over 0.05 s)
HELD_TOL = 0.5
#: held for at least this [s] (an impact's smoothed spike lasts a few frames) ...
HELD_MIN = 0.2
#: ... or for at least free flight's shortest stretch within this [s] of such a hold (a
#: hand that tosses the robot up and touches it again on its way down)
HELD_NEAR = 0.3
#: at rest: the seen end caps move slower than this [m/s] (their median: a marker's
#: reconstruction jumping by millimetres moves no robot) ...
REST_SPEED = 0.005
#: ... measured over this span [s] (0.1 mm noise gives ~1 mm/s over it) ...
REST_SPAN = 0.2
#: ... for at least this long [s]
REST_MIN = 0.5
#: unmeasured frames within a run shorter than this [s] do not break it (more than half
#: the rest span, which leaves the take's ends unmeasured)
BRIDGE = 0.15
#: kinds of stretch, in the order they take precedence
KINDS = ("external", "rest", "free", "named")
#: the kinds a fit uses
USED = ("rest", "free", "named")


@dataclass(frozen=True)
class Stretch:
    """Part of a take: ``start`` to ``end`` [s] (``end`` exclusive, one frame after the
    last), of ``kind``: ``external`` (acted on from outside the model), ``rest``,
    ``free``, or ``named`` (given by the user, ``--segments``)."""

    start: float
    end: float
    kind: str
    held: tuple[float, float] | None = None  # external: from leaving the floor held to release [s]

    def to_dict(self) -> dict[str, object]:
        d: dict[str, object] = {
            "start_s": round(self.start, 4),
            "end_s": round(self.end, 4),
            "kind": self.kind,
        }
        if self.held is not None:
            d["held_s"] = [round(t, 4) for t in self.held]
        return d

    def __str__(self) -> str:
        extra = (
            f" (off the floor and not falling freely {self.held[0]:.2f}-{self.held[1]:.2f} s)"
            if self.held
            else ""
        )
        return f"{self.kind} {self.start:.2f}-{self.end:.2f} s{extra}"


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[a, b) frame ranges where ``mask`` (F,) holds."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def _bridged(mask: np.ndarray, known: np.ndarray, time: np.ndarray) -> np.ndarray:
    """``mask`` with runs of unknown frames shorter than :data:`BRIDGE` between two of
    its frames filled in."""
    out = mask & known
    F = len(mask)
    for a, b in _runs(~known):  # within the take between two of its frames, or at its ends
        left = out[a - 1] if a > 0 else b < F and out[b]
        right = out[b] if b < F else a > 0 and out[a - 1]
        if left and right and time[min(b, F - 1)] - time[max(a - 1, 0)] <= BRIDGE:
            out[a:b] = True
    return out


def _long(mask: np.ndarray, time: np.ndarray, least: float) -> np.ndarray:
    """``mask`` keeping only its runs that last ``least`` [s] or more."""
    dt = float(np.median(np.diff(time)))
    out = np.zeros_like(mask)
    for a, b in _runs(mask):
        if time[b - 1] - time[a] + dt >= least:
            out[a:b] = True
    return out


def _closed(mask: np.ndarray, time: np.ndarray, gap: float) -> np.ndarray:
    """``mask`` with the frames between two of its runs less than ``gap`` [s] apart
    filled in (a hold whose acceleration dips near free fall for a frame or two)."""
    out = mask.copy()
    runs = _runs(mask)
    for (_, b), (c, _) in itertools.pairwise(runs):
        if time[c] - time[b - 1] < gap:
            out[b:c] = True
    return out


def floor_height(caps: np.ndarray) -> float:
    """The floor's height [m]: the median over frames of the lowest seen end cap's
    height (``caps`` (F, N, 3) [m], z-up); NaN when no cap is ever seen."""
    low = np.nanmin(np.where(np.isfinite(caps).all(-1), caps[..., 2], np.inf), axis=1)
    low = low[np.isfinite(low)]
    return float(np.median(low)) if low.size else float("nan")


def find_stretches(caps: np.ndarray, time: np.ndarray) -> list[Stretch]:
    """The stretches of a take, end caps ``caps`` (F, N, 3) [m] (z-up, NaN unseen) at
    ``time`` (F,) [s]: consecutive, covering the take, each ``external``, ``rest`` or
    ``free`` (module docstring)."""
    F, N = caps.shape[:2]
    dt = float(np.median(np.diff(time)))
    seen = np.isfinite(caps).all(-1)
    enough = seen.sum(-1) >= max(N - 2, 1)  # the lowest cap is not one hidden
    low = np.nanmin(np.where(seen, caps[..., 2], np.inf), axis=1)
    off = enough & (low > floor_height(caps) + OFF_FLOOR)
    _, acc = centre_acceleration(caps, time)
    measured = np.isfinite(acc).all(-1) & enough
    away = np.linalg.norm(acc - np.array([0.0, 0.0, -G]), axis=-1)
    touched = _bridged(off & (away > HELD_TOL * G), measured, time)
    touched = _long(touched | _closed(touched, time, FLIGHT_MIN), time, FLIGHT_MIN)
    held = _long(touched, time, HELD_MIN)
    for a, b in _runs(touched & ~held):  # a short touch near a hold belongs to it
        near = np.flatnonzero(held & (np.abs(time - time[a]) <= HELD_NEAR + time[b - 1] - time[a]))
        if near.size:
            held[min(a, near[0]) : max(b, near[-1] + 1)] = True
    flying = _long(_bridged(off & (away <= FLIGHT_TOL * G), measured, time), time, FLIGHT_MIN)
    # at rest: the seen caps still over REST_SPAN (their median), on the floor
    h = max(1, round(REST_SPAN / dt / 2))
    moved = np.full(F, np.nan)
    if F > 2 * h:
        step = np.linalg.norm(caps[2 * h :] - caps[: -2 * h], axis=-1)  # (F - 2h, N)
        has = np.isfinite(step).any(-1)
        speed = np.full(len(step), np.nan)
        speed[has] = np.nanmedian(step[has], axis=-1) / (time[2 * h :] - time[: -2 * h])[has]
        moved[h:-h] = speed
    still = np.isfinite(moved) & (moved < REST_SPEED) & ~off
    rest = _long(_bridged(still, np.isfinite(moved), time), time, REST_MIN) & ~held
    # widened back to the last rest or free flight, and on to the next rest or frame
    # that falls freely (what follows a release)
    falling = off & measured & (away <= HELD_TOL * G)
    external = held.copy()
    for a, b in _runs(held):
        before = np.flatnonzero((rest | flying)[:a])
        after = np.flatnonzero((rest | falling)[b:])
        external[(before[-1] + 1 if before.size else 0) : (b + after[0] if after.size else F)] = (
            True
        )
    kind = np.where(external, 0, np.where(rest & ~external, 1, 2))
    out: list[Stretch] = []
    for k in range(3):
        for a, b in _runs(kind == k):
            core = np.flatnonzero(held[a:b]) + a
            span = (
                (float(time[core[0]]), float(time[core[-1]] + dt)) if k == 0 and core.size else None
            )
            out.append(Stretch(float(time[a]), float(time[b - 1] + dt), KINDS[k], span))
    return sorted(out, key=lambda s: s.start)


def parse_segments(text: str) -> list[tuple[float, float]]:
    """``"0-7,11.5-20"`` -> [(0, 7), (11.5, 20)] [s]; one-line errors."""
    out: list[tuple[float, float]] = []
    for part in text.split(","):
        a, sep, b = part.strip().partition("-")
        try:
            lo, hi = float(a), float(b)
        except ValueError:
            raise InputError(
                f"--segments: {part.strip()!r} is not START-END in seconds (e.g. 0-7,11.5-20)"
            ) from None
        if not sep or not hi > lo >= 0:
            raise InputError(
                f"--segments: {part.strip()!r} must be START-END with 0 <= START < END [s]"
            )
        out.append((lo, hi))
    out.sort()
    for (_, end), (start, _) in itertools.pairwise(out):
        if start < end:
            raise InputError(f"--segments: {text!r}: segments overlap near {start:g} s")
    return out


def named_stretches(
    segments: list[tuple[float, float]], time: np.ndarray, source: str
) -> list[Stretch]:
    """The user's ``segments`` [s] as ``named`` stretches of a take at ``time`` (F,)
    [s]; a segment that holds fewer than two of its frames is refused in one line."""
    dt = float(np.median(np.diff(time)))
    out = []
    for a, b in segments:
        inside = np.flatnonzero((time >= a) & (time < b))
        if inside.size < 2:
            raise InputError(f"{source}: --segments {a:g}-{b:g} s holds {inside.size} frames of the take "
                             f"({time[0]:.3g}-{time[-1]:.3g} s)")  # fmt: skip
        out.append(Stretch(float(time[inside[0]]), float(time[inside[-1]] + dt), "named"))
    return out


def pieces(stretches: list[Stretch], time: np.ndarray, piece: float) -> list[tuple[int, int]]:
    """Frame ranges [a, b) of ``piece`` [s] each (whole frames), cut from the stretches a
    fit uses (:data:`USED`) in time order; what is left of a stretch, shorter than one
    piece, is left out. A piece never crosses a stretch's end. ``piece`` 0: each such
    stretch whole."""
    dt = float(np.median(np.diff(time)))
    n = max(2, round(piece / dt))
    out = []
    for s in stretches:
        if s.kind not in USED:
            continue
        a = int(np.searchsorted(time, s.start - dt / 2))
        b = int(np.searchsorted(time, s.end - dt / 2))
        if piece <= 0:
            out += [(a, b)] if b - a >= 2 else []
            continue
        out += [(k, k + n) for k in range(a, b - n + 1, n)]
    return out


def assign_splits(n: int, fractions: tuple[float, float, float]) -> list[str]:
    """Split names for ``n`` pieces in time order: each goes to the split furthest below
    its share ``fractions`` (train, val, test) of the pieces so far (train on ties), so
    that every split draws from the whole take."""
    names = ("train", "val", "test")
    count = np.zeros(3)
    out = []
    for i in range(n):
        k = int(np.argmax(np.asarray(fractions) * (i + 1) - count))
        count[k] += 1
        out.append(names[k])
    return out
