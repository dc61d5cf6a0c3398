"""Labelling unlabelled markers: end caps tracked through point clouds.

An unlabelled export gives, per frame, a cloud of points whose track ids change when
a marker is lost and found again, plus ghosts (reflections). The first frame is
labelled by the robot's shape (:func:`initial_caps_from_shape`, whatever the robot's
pose: unique up to the robot's symmetry, one of the equivalent labellings is taken).
Then each end cap is tracked from frame to frame, its id ignored:

* a cap seen within :data:`FRESH` is predicted at constant velocity from the last two
  frames it was seen, and matched within :data:`GATE` plus its step;
* a cap lost for longer is predicted from the robot's shape: the last frame that saw
  every cap, or the robot's built shape where that fits the caps seen now better (a
  robot whose shape changed while caps were lost: cables released in a jump), moved
  rigidly onto the caps seen now (Kabsch), and re-acquired within
  :data:`REACQUIRE_GATE` of that, whatever id the camera system gave its marker;
* a robot lost altogether (fewer than three caps tracked, as in a jump) is found again
  by placing the last frame that saw every cap on a frame showing as many points
  (:func:`initial_caps_from_shape`; of a symmetric robot's placements, the one nearest
  its last pose);
* the frame's points are assigned to end caps by a minimum-cost matching
  (:func:`scipy.optimize.linear_sum_assignment`): the distance to the prediction plus
  the misfit ``| |x - x_partner| - L_r |`` of the rod's marker distance ``L_r`` (the
  rod's length with the markers' offsets) to the partner cap's prediction; a cap may
  stay unseen at the cost of its gate;
* a rod whose two assigned points are not ``L_r`` apart within ``length_tol`` loses
  the one farther from its prediction; a rod one of whose caps is found again after
  being lost is kept within :data:`REACQUIRE_LENGTH` of ``L_r``, and its distance as
  found becomes its ``L_r`` (markers move on their caps: an impact, cables wound in
  and released). Points given to no end cap are ghosts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from tensegrity_env.rotations import np_quat_to_matrix, random_quaternions

#: an end cap is matched only within this distance of its prediction [m], plus its step
GATE = 0.03
#: rod lengths are kept within this [m] (rigid rods, ~1 mm marker noise)
LENGTH_TOL = 0.01
#: a cap last seen longer ago than this [s] is predicted from the robot's shape (a few
#: frames at 100-500 Hz: a velocity from older samples no longer predicts an impact)
FRESH = 0.05
#: a lost cap is re-acquired within this distance [m] of where the robot's shape puts it
#: (a tensegrity deforms by centimetres; its markers are tens of centimetres apart)
REACQUIRE_GATE = 0.06
#: a rod found again after being lost may show its markers this fraction of its marker
#: distance nearer or farther apart than before (the ETH 6-bar's markers, 0.51 m apart,
#: shift by up to 12 mm between its compressed rest and the landing after the jump)
REACQUIRE_LENGTH = 0.05
#: rotations tried to place the robot's shape on the first frame's cloud (one every
#: ~10 degrees of the rotation group, then refined)
SHAPE_TRIES = 3000
#: with fewer than three caps tracked, the last frame that saw every cap is placed anew
#: on a frame that shows as many points, at most this often [s]
REPLACE_EVERY = 0.1
#: shape placements refined by alternating matching and rigid alignment (enough to
#: hold each of an icosahedron's 60 rotations several times)
SHAPE_REFINED = 200
#: a take that starts near the shape's own pose keeps that pose's labelling when it
#: scores within this [m] of the best placement (of a symmetric robot's equivalent ones)
SHAPE_TIE = 0.005


@dataclass(frozen=True)
class Labelling:
    """End caps recovered from point clouds.

    Attributes:
        caps: (F, 2R, 3) end-cap positions [m], NaN where the cap was not seen.
        track_of_cap: (F, 2R) index of the file's column each cap came from, -1 if unseen.
        relabelled_frames: frames where a track id was (re)assigned to an end cap, i.e.
            the file's ids changed (a marker lost and found again) or were corrected.
        ghosts: points assigned to no end cap, over all frames.
        reacquired: (2R,) times each cap was found again after :data:`FRESH` unseen.
    """

    caps: np.ndarray
    track_of_cap: np.ndarray
    relabelled_frames: int
    ghosts: int
    reacquired: np.ndarray


def rigid_align(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``Rm`` and translation ``t`` minimising ``|Rm src + t - dst|`` (Kabsch)."""
    cs, cd = src.mean(0), dst.mean(0)
    u, _, vt = np.linalg.svd((src - cs).T @ (dst - cd))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rot, cd - rot @ cs


def _refine(shape: np.ndarray, cloud: np.ndarray, rot: np.ndarray, t: np.ndarray,
            iterations: int = 20) -> tuple[np.ndarray, float]:  # fmt: skip
    """Alternate matching and rigid alignment from the placement ``rot``, ``t``; returns
    each shape point's cloud index and the RMS distance of the matched pairs [m]."""
    pick = np.full(len(shape), -1)
    for _ in range(iterations):
        moved = shape @ rot.T + t
        rows, cols = linear_sum_assignment(np.linalg.norm(moved[:, None] - cloud[None], axis=-1))
        new = np.full(len(shape), -1)
        new[rows] = cols
        if (new == pick).all():
            break
        pick = new
        ok = pick >= 0
        rot, t = rigid_align(shape[ok], cloud[pick[ok]])
    moved = shape @ rot.T + t
    ok = pick >= 0
    return pick, float(np.sqrt(np.mean(np.sum((moved[ok] - cloud[pick[ok]]) ** 2, -1))))


def rod_misfit(caps: np.ndarray, lengths: np.ndarray) -> float:
    """RMS [m] of each rod's marker distance in ``caps`` (2R, 3) against its length
    ``lengths`` (R,) plus one common marker offset (markers sit on the caps' surfaces,
    beyond the end caps: the offset is >= 0); NaN caps are left out."""
    d = np.linalg.norm(caps[0::2] - caps[1::2], axis=-1) - lengths
    d = d[np.isfinite(d)]
    if not d.size:
        return float("inf")
    return float(np.sqrt(np.mean((d - max(0.0, float(np.median(d)))) ** 2)))


def initial_caps_from_shape(shape: np.ndarray, cloud: np.ndarray, seed: int = 0) -> np.ndarray:
    """End caps of the first frame: the robot's shape (2R, 3) placed on the cloud (K, 3),
    in whatever pose the robot is.

    :data:`SHAPE_TRIES` rotations about the centre of the points near the cloud's median
    (ghosts far away left out) are matched to the cloud; the best
    :data:`SHAPE_REFINED` are refined by alternating matching and rigid alignment
    (Kabsch), and so is the shape's own pose. A tensegrity's end caps can be nearly as
    symmetric as a regular polyhedron while its rods pair them less symmetrically: a
    placement scores its RMS distance plus its :func:`rod_misfit`; the least wins, the
    own pose when it scores within :data:`SHAPE_TIE` of it. The labelling is unique up
    to the robot's symmetry. Unmatched caps are NaN."""
    lengths = np.linalg.norm(shape[0::2] - shape[1::2], axis=-1)
    span = float(np.max(np.linalg.norm(shape[:, None] - shape[None], axis=-1)))
    near = cloud[np.linalg.norm(cloud - np.median(cloud, axis=0), axis=-1) <= span]
    if len(near) < min(len(shape), len(cloud)):
        near = cloud
    centre, mid = near.mean(0), shape.mean(0)
    rots = np_quat_to_matrix(random_quaternions(np.random.default_rng(seed), SHAPE_TRIES))
    moved = np.einsum("nij,kj->nki", rots, shape - mid) + centre  # (N, 2R, 3)
    scores = np.empty(len(rots))
    for n in range(len(rots)):
        d = np.linalg.norm(moved[n][:, None] - cloud[None], axis=-1)
        rows, cols = linear_sum_assignment(d)
        scores[n] = d[rows, cols].sum()
    tried = [_refine(shape, cloud, np.eye(3), np.zeros(3))]  # the robot file's own pose first
    tried += [_refine(shape, cloud, rots[n], centre - rots[n] @ mid)
              for n in np.argsort(scores)[:SHAPE_REFINED]]  # fmt: skip

    def caps_of(pick: np.ndarray) -> np.ndarray:
        out = np.full_like(shape, np.nan)
        out[pick >= 0] = cloud[pick[pick >= 0]]
        return out

    placed = [caps_of(pick) for pick, _ in tried]
    score = np.array([rms + rod_misfit(c, lengths) for c, (_, rms) in zip(placed, tried, strict=True)])
    return placed[0] if score[0] <= score.min() + SHAPE_TIE else placed[int(np.argmin(score))]


def label_clouds(
    points: np.ndarray,
    time: np.ndarray,
    first: np.ndarray,
    rod_lengths: np.ndarray,
    gate: float = GATE,
    length_tol: float = LENGTH_TOL,
    ids: np.ndarray | None = None,
    built: np.ndarray | None = None,
) -> Labelling:
    """Track ``2R`` end caps through ``points`` (F, M, 3) [m] (NaN: track absent).

    ``first`` (2R, 3): the end caps in frame 0 (NaN for caps not identified there);
    ``rod_lengths`` (R,) [m]: the distance of each rod's two markers; ``time`` (F,)
    [s]; ``ids`` (F, M): the capture system's id of each sample where a column holds
    several ids in turn (for counting relabelled frames), else None; ``built`` (2R, 3)
    [m]: the robot's built shape, labelled as ``first`` (None: the last full frame's
    only).
    """
    F = points.shape[0]
    n_caps = first.shape[0]
    partner = np.arange(n_caps) ^ 1
    lengths = np.repeat(rod_lengths, 2).astype(float)
    caps = np.full((F, n_caps, 3), np.nan)
    track = np.full((F, n_caps), -1)
    seen_at = np.full((n_caps, 2), -1)  # last two frames each cap was seen
    reacquired = np.zeros(n_caps, dtype=int)
    relabelled, ghosts = 0, 0
    present0 = np.isfinite(points[0]).all(-1)
    for i in range(n_caps):
        if np.isfinite(first[i]).all():
            d = np.linalg.norm(np.where(present0[:, None], points[0], np.inf) - first[i], axis=-1)
            j = int(np.argmin(d))
            caps[0, i], track[0, i], seen_at[i] = points[0, j], j, (0, -1)
    shape = caps[0].copy() if (track[0] >= 0).all() else None  # the last frame seeing every cap
    ghosts += int(present0.sum() - (track[0] >= 0).sum())

    def ident(f: int, j: int) -> int:
        return int(ids[f, j]) if ids is not None else j

    previous = {ident(0, int(j)): i for i, j in enumerate(track[0]) if j >= 0}
    tried_at = -np.inf  # when the shape was last placed anew on a frame
    for f in range(1, F):
        present = np.flatnonzero(np.isfinite(points[f]).all(-1))
        cloud = points[f, present]
        pred, reach, fresh = _predict(caps, time, seen_at, f, gate, shape, built)
        known = np.isfinite(pred).all(-1)
        lost = fresh.sum() < 3 and shape is not None and len(cloud) >= n_caps
        if lost and shape is not None and time[f] - tried_at >= REPLACE_EVERY:
            tried_at = time[f]
            placed = initial_caps_from_shape(shape, cloud)
            pick = np.array([int(np.argmin(np.linalg.norm(cloud - c, axis=-1))) if np.isfinite(c).all()
                             else -1 for c in placed])  # fmt: skip
            pred, reach = np.where(pick[:, None] >= 0, cloud[np.clip(pick, 0, None)], np.nan), np.full(n_caps, gate)
            known = np.isfinite(pred).all(-1)
        if len(cloud) == 0 or not known.any():
            continue
        dist = np.linalg.norm(pred[:, None] - cloud[None], axis=-1)
        mate = np.where(fresh[partner, None], pred[partner], np.nan)
        misfit = np.abs(np.linalg.norm(cloud[None] - mate[:, None], axis=-1) - lengths[:, None])
        cost = dist + np.where(np.isfinite(misfit), misfit, 0.0)
        cost = np.where(known[:, None] & (dist <= reach[:, None]), cost, 1e6)
        unseen = np.full((n_caps, n_caps), 1e6)
        np.fill_diagonal(unseen, np.where(known, reach, 1.0))
        rows, cols = linear_sum_assignment(np.hstack([cost, unseen]))
        pick = np.full(n_caps, -1)
        real = cols < len(cloud)
        pick[rows[real]] = cols[real]
        pick[cost[np.arange(n_caps), np.clip(pick, 0, None)] >= 1e6] = -1
        for r in range(n_caps // 2):
            i, k = 2 * r, 2 * r + 1
            if pick[i] >= 0 and pick[k] >= 0:
                apart = float(np.linalg.norm(cloud[pick[i]] - cloud[pick[k]]))
                found = not (fresh[i] and fresh[k])  # one found again: a new distance is taken
                tol = max(length_tol, REACQUIRE_LENGTH * lengths[i]) if found else length_tol
                if abs(apart - lengths[i]) > tol:
                    worse = i if dist[i, pick[i]] > dist[k, pick[k]] else k
                    pick[worse] = -1
                elif found:
                    lengths[i] = lengths[k] = apart
        assigned = {}
        for i in np.flatnonzero(pick >= 0).tolist():
            j = int(present[pick[i]])
            if seen_at[i, 0] >= 0 and not fresh[i]:
                reacquired[i] += 1
            caps[f, i], track[f, i] = points[f, j], j
            seen_at[i] = (f, seen_at[i, 0])
            assigned[ident(f, j)] = int(i)
        if (pick >= 0).all():
            shape = caps[f].copy()
        ghosts += len(cloud) - len(assigned)
        if any(previous.get(j) != i for j, i in assigned.items()):
            relabelled += 1
        previous = assigned
    return Labelling(caps, track, relabelled, ghosts, reacquired)


def _predict(
    caps: np.ndarray, time: np.ndarray, seen_at: np.ndarray, f: int, gate: float,
    shape: np.ndarray | None, built: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Each cap's predicted position in frame ``f`` (2R, 3) [m] (NaN: none), its gate
    (2R,) [m] and whether it was seen within :data:`FRESH` (2R,). Lost caps: from
    ``shape`` or ``built`` (2R, 3), whichever lies closer to the fresh caps once moved
    onto them."""
    n_caps = caps.shape[1]
    pred = np.full((n_caps, 3), np.nan)
    reach = np.full(n_caps, gate)
    fresh = np.zeros(n_caps, dtype=bool)
    for i in range(n_caps):
        a, b = seen_at[i]
        if a < 0:
            continue
        fresh[i] = time[f] - time[a] <= FRESH
        if b >= 0 and time[a] - time[b] <= FRESH:
            vel = (caps[a, i] - caps[b, i]) / (time[a] - time[b])
            pred[i] = caps[a, i] + vel * (time[f] - time[a])
            reach[i] += 2.0 * np.linalg.norm(vel) * (time[f] - time[a])
        else:
            pred[i] = caps[a, i]
            reach[i] += 1.0 * (time[f] - time[a])  # up to 1 m/s unseen motion
    lost = ~fresh
    if shape is not None and lost.any() and fresh.sum() >= 3:
        best = np.inf
        for s in (shape, built):
            if s is None:
                continue
            rot, t = rigid_align(s[fresh], pred[fresh])
            misfit = float(np.linalg.norm(s[fresh] @ rot.T + t - pred[fresh], axis=-1).mean())
            if misfit < best:
                best, pred[lost] = misfit, s[lost] @ rot.T + t
        reach[lost] = REACQUIRE_GATE
    return pred, reach, fresh
