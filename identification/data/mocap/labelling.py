"""Labelling unlabelled markers: end caps tracked through point clouds.

An unlabelled export gives, per frame, a cloud of points whose track ids change when
a marker is lost and found again, plus ghosts (reflections). Each end cap is tracked
from frame to frame: its position is predicted at constant velocity from the last two
frames it was seen, and the frame's points are assigned to end caps by a minimum-cost
matching (:func:`scipy.optimize.linear_sum_assignment`). The cost of giving point
``x`` to end cap ``i`` of rod ``r`` is its distance to ``i``'s prediction plus the
rod-length misfit ``| |x - x_partner| - L_r |`` to the partner cap's prediction (when
the partner was seen in the previous frame);
a cap may stay unseen at the cost of its gate. After matching, a rod whose two
assigned points are not ``L_r`` apart (within ``length_tol``) loses the worse one.
Points given to no end cap are ghosts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

#: an end cap is matched only within this distance of its prediction [m], plus its step
GATE = 0.03
#: rod lengths are kept within this [m] (rigid rods, ~1 mm marker noise)
LENGTH_TOL = 0.01


@dataclass(frozen=True)
class Labelling:
    """End caps recovered from point clouds.

    Attributes:
        caps: (F, 2R, 3) end-cap positions [m], NaN where the cap was not seen.
        track_of_cap: (F, 2R) index of the file's track each cap came from, -1 if unseen.
        relabelled_frames: frames where a track id was (re)assigned to an end cap, i.e.
            the file's ids changed (a marker lost and found again) or were corrected.
        ghosts: points assigned to no end cap, over all frames.
    """

    caps: np.ndarray
    track_of_cap: np.ndarray
    relabelled_frames: int
    ghosts: int


def rigid_align(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``Rm`` and translation ``t`` minimising ``|Rm src + t - dst|`` (Kabsch)."""
    cs, cd = src.mean(0), dst.mean(0)
    u, _, vt = np.linalg.svd((src - cs).T @ (dst - cd))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rot, cd - rot @ cs


def initial_caps_from_shape(shape: np.ndarray, cloud: np.ndarray, iterations: int = 20) -> np.ndarray:
    """End caps of the first frame: the robot's shape (2R, 3) matched to the cloud (K, 3)
    by alternating assignment and rigid alignment, starting from the shape's own pose
    (the take must start near the robot file's pose). Unmatched caps are NaN."""
    moved = shape.copy()
    pick = np.full(len(shape), -1)
    for _ in range(iterations):
        cost = np.linalg.norm(moved[:, None] - cloud[None], axis=-1)
        rows, cols = linear_sum_assignment(cost)
        new = np.full(len(shape), -1)
        new[rows] = cols
        if (new == pick).all():
            break
        pick = new
        ok = pick >= 0
        rot, t = rigid_align(shape[ok], cloud[pick[ok]])
        moved = shape @ rot.T + t
    out = np.full_like(shape, np.nan)
    ok = pick >= 0
    out[ok] = cloud[pick[ok]]
    return out


def label_clouds(
    points: np.ndarray,
    time: np.ndarray,
    first: np.ndarray,
    rod_lengths: np.ndarray,
    gate: float = GATE,
    length_tol: float = LENGTH_TOL,
) -> Labelling:
    """Track ``2R`` end caps through ``points`` (F, M, 3) [m] (NaN: track absent).

    ``first`` (2R, 3): the end caps in frame 0 (NaN for caps not identified there);
    ``rod_lengths`` (R,) [m]; ``time`` (F,) [s].
    """
    F = points.shape[0]
    n_caps = first.shape[0]
    partner = np.arange(n_caps) ^ 1
    lengths = np.repeat(rod_lengths, 2)
    caps = np.full((F, n_caps, 3), np.nan)
    track = np.full((F, n_caps), -1)
    seen_at = np.full((n_caps, 2), -1)  # last two frames each cap was seen
    relabelled, ghosts = 0, 0
    present0 = np.isfinite(points[0]).all(-1)
    for i in range(n_caps):
        if np.isfinite(first[i]).all():
            d = np.linalg.norm(np.where(present0[:, None], points[0], np.inf) - first[i], axis=-1)
            j = int(np.argmin(d))
            caps[0, i], track[0, i], seen_at[i] = points[0, j], j, (0, -1)
    ghosts += int(present0.sum() - (track[0] >= 0).sum())
    previous = {int(j): i for i, j in enumerate(track[0]) if j >= 0}
    for f in range(1, F):
        present = np.flatnonzero(np.isfinite(points[f]).all(-1))
        cloud = points[f, present]
        pred = np.full((n_caps, 3), np.nan)
        reach = np.full(n_caps, gate)
        for i in range(n_caps):
            a, b = seen_at[i]
            if a < 0:
                continue
            if b >= 0:
                vel = (caps[a, i] - caps[b, i]) / (time[a] - time[b])
                pred[i] = caps[a, i] + vel * (time[f] - time[a])
                reach[i] += 2.0 * np.linalg.norm(vel) * (time[f] - time[a])
            else:
                pred[i] = caps[a, i]
                reach[i] += 1.0 * (time[f] - time[a])  # up to 1 m/s unseen motion
        known = np.isfinite(pred).all(-1)
        if len(cloud) == 0 or not known.any():
            continue
        dist = np.linalg.norm(pred[:, None] - cloud[None], axis=-1)
        fresh = seen_at[:, 0] == f - 1  # predictions one frame old are trusted for lengths
        mate = np.where(fresh[partner, None], pred[partner], np.nan)
        misfit = np.abs(np.linalg.norm(cloud[None] - mate[:, None], axis=-1) - lengths[:, None])
        cost = dist + np.where(np.isfinite(misfit), misfit, 0.0)
        cost = np.where(known[:, None] & (dist <= reach[:, None]), cost, 1e6)
        unseen = np.full((n_caps, n_caps), 1e6)
        np.fill_diagonal(unseen, reach)
        rows, cols = linear_sum_assignment(np.hstack([cost, unseen]))
        pick = np.full(n_caps, -1)
        real = cols < len(cloud)
        pick[rows[real]] = cols[real]
        pick[cost[np.arange(n_caps), np.clip(pick, 0, None)] >= 1e6] = -1
        for r in range(n_caps // 2):
            i, k = 2 * r, 2 * r + 1
            if pick[i] >= 0 and pick[k] >= 0:
                gap = abs(np.linalg.norm(cloud[pick[i]] - cloud[pick[k]]) - lengths[i])
                if gap > length_tol:
                    worse = i if dist[i, pick[i]] > dist[k, pick[k]] else k
                    pick[worse] = -1
        assigned = {}
        for i in np.flatnonzero(pick >= 0):
            j = int(present[pick[i]])
            caps[f, i], track[f, i] = points[f, j], j
            seen_at[i] = (f, seen_at[i, 0])
            assigned[j] = int(i)
        ghosts += len(cloud) - len(assigned)
        if any(previous.get(j) != i for j, i in assigned.items()):
            relabelled += 1
        previous = assigned
    return Labelling(caps, track, relabelled, ghosts)
