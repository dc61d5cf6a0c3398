"""Does a model stay with the data when rolled out open-loop? The check before a params file is written.

A fit's end-cap RMS is measured on its own short windows, each with a fitted initial
state; a model can fit them and still leave the data when rolled out for a second from
a measured state (a floor fitted far below the caps, contact or springs that pump
energy in). ``identify`` and ``diagnose`` run :func:`open_loop_check` on the held-out
splits (``val`` and ``test``; the fitted split where there are none) before they write
anything:

* starts every :data:`EVERY_S` of each trajectory (at most :data:`MAX_STARTS` per split), each
  from the measured state there (the recorded rod states where the data has them,
  else the end caps' Gaussian smoothing :data:`SMOOTHING_S`, as the
  benchmarks start their rollouts), rolled :data:`HORIZON_S` (or as long as the
  trajectory allows) under the split's recorded controls;
* at each step of the horizon, the end-cap RMS error over the starts and the seen caps;
* the model has **diverged** when any predicted end cap is non-finite, or when that RMS
  exceeds the limit :func:`extent_limit`: the data's own extent over a start's horizon
  (the largest distance between two measured end caps in it: the robot's size and how
  far it travelled; the median over starts), and at least :data:`NOISE_LEVELS` noise
  levels. A model whose end caps are off by more than everything the measured ones span
  is no longer predicting this robot; one that is off by centimetres is a poor model,
  not a diverged one, and is written (the benchmarks measure how poor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from identification.data.dataset import Dataset
from identification.data.end_caps import measured_rod_states
from identification.trajectory.windows import rollout_caps
from tensegrity_env.engine import State
from tensegrity_env.io_utils import StageError
from tensegrity_env.model import Model

#: each start is rolled out this long [s] (the longest horizon the benchmarks read)
HORIZON_S = 1.0
#: a start every this [s] of a trajectory (the benchmarks' spacing)
EVERY_S = 0.25
#: at most this many starts per split, spread evenly over those found (the check's cost)
MAX_STARTS = 32
#: the measured starting states' Gaussian smoothing [s] (the benchmarks' filter)
SMOOTHING_S = 0.01
#: the limit is at least this many noise levels (the fit check's factor, for data that
#: barely moves and is noisy)
NOISE_LEVELS = 100.0
#: the fewest samples a start's horizon holds (shorter pieces give no start)
LEAST_STEPS = 2
#: the horizons [s] at which held-out prediction is compared between models (the ones
#: ``benchmarks/bench_real.py`` reports)
HORIZONS_S = (0.1, 0.25, 0.5, 1.0)
#: what to try when a fit predicts worse than the model it started from
WORSE_THAN_START_ADVICE = ("a fit on the free stretches only (import-mocap --segments), "
                           "--effort thorough, or the start model as it is")  # fmt: skip


@dataclass(frozen=True)
class OpenLoopCheck:
    """The result of :func:`open_loop_check`.

    Attributes:
        splits: the splits the starts were taken from.
        starts: rollouts run.
        horizon_s: the longest rollout [s].
        worst_rms_m: the largest end-cap RMS [m] over the horizon's steps, of the
            rollouts whose end caps stay finite.
        at_s: when [s] after the starts ``worst_rms_m`` was reached.
        limit_m: the divergence limit [m] (:func:`extent_limit`).
        extent_m: the data's extent over a start's horizon [m], median over starts.
        noise_m: the data's noise level [m].
        non_finite: starts whose rollout reached a non-finite end cap.
        rms_m: the end-cap RMS [m] over the starts at each step 1..n of the horizon
            (step k is k sample periods after the starts; NaN where no cap was seen),
            shape (n,).
        dt: the sample period [s].
    """

    splits: tuple[str, ...]
    starts: int
    horizon_s: float
    worst_rms_m: float
    at_s: float
    limit_m: float
    extent_m: float
    noise_m: float
    non_finite: int = 0
    rms_m: tuple[float, ...] = ()
    dt: float = 0.0

    def at(self, horizons: tuple[float, ...] = HORIZONS_S) -> list[float | None]:
        """The end-cap RMS [m] at each of ``horizons`` [s] (None beyond the rollouts; inf
        where a rollout left the finite numbers)."""
        out: list[float | None] = []
        for h in horizons:
            k = round(h / self.dt) if self.dt > 0 else 0
            if not 1 <= k <= len(self.rms_m) or np.isnan(self.rms_m[k - 1]):
                out.append(None)
            else:
                out.append(float("inf") if self.non_finite else self.rms_m[k - 1])
        return out

    @property
    def diverged(self) -> bool:
        return bool(self.non_finite) or not self.worst_rms_m <= self.limit_m

    def as_dict(self) -> dict[str, object]:
        """The check as JSON-able values."""
        return {"splits": list(self.splits), "starts": self.starts, "horizon_s": self.horizon_s,
                "worst_rms_m": self.worst_rms_m, "at_s": self.at_s, "limit_m": self.limit_m,
                "extent_m": self.extent_m, "noise_level_m": self.noise_m, "non_finite_starts": self.non_finite,
                "diverged": self.diverged}  # fmt: skip

    def line(self) -> str:
        """One line: what was rolled out, the worst error and the rule."""
        worst = f"end-cap RMS up to {self.worst_rms_m * 1e3:.4g} mm (at {self.at_s:.3g} s)"
        if self.non_finite:
            others = f" (the others: {worst})" if self.non_finite < self.starts else ""
            worst = f"non-finite end caps in {self.non_finite} of them{others}"
        return (f"open-loop check on {', '.join(repr(s) for s in self.splits)}: {self.starts} "
                f"starts from measured states, up to {self.horizon_s:.3g} s each: {worst}; limit "
                f"{self.limit_m * 1e3:.4g} mm (the measured end caps' extent over a start's "
                f"horizon, {self.extent_m * 1e3:.4g} mm, and at least {NOISE_LEVELS:g} noise "
                f"levels of {self.noise_m * 1e3:.3g} mm)")  # fmt: skip


def extent_limit(extent: float, noise: float) -> float:
    """The divergence limit [m] for data of extent ``extent`` [m] and noise std ``noise`` [m]."""
    return max(extent, NOISE_LEVELS * noise)


def check_splits(dataset: Dataset) -> tuple[str, ...]:
    """The splits :func:`open_loop_check` rolls out on: the held-out ones, else all."""
    held = tuple(s for s in ("val", "test") if s in dataset.splits)
    return held or tuple(dataset.splits)


def _starts(known: np.ndarray, every: int, steps: int) -> list[tuple[int, int]]:
    """(trajectory, sample) of the first known state in each slot of ``every`` samples
    whose horizon of ``steps`` fits, at most :data:`MAX_STARTS` spread evenly."""
    out = []
    N, T = known.shape
    for n in range(N):
        last = T - LEAST_STEPS - 1
        for a in range(0, max(last + 1, 0), every):
            hit = np.flatnonzero(known[n, a : min(a + every, last + 1)])
            if hit.size:
                out.append((n, a + int(hit[0])))
    if len(out) > MAX_STARTS:
        out = [out[int(i)] for i in np.linspace(0, len(out) - 1, MAX_STARTS).round()]
    return out


def open_loop_check(
    model: Model,
    dataset: Dataset,
    noise: float,
    physics_dt: float | None = None,
    splits: tuple[str, ...] | None = None,
) -> OpenLoopCheck | None:
    """Roll ``model`` open-loop from measured states of ``dataset``'s held-out splits
    (:func:`check_splits`) and compare its end caps with the measured ones (see the
    module docstring). ``noise``: the data's noise std [m]; ``physics_dt``: the longest
    physics step [s] (the engine substeps between samples). None where no split has a
    measured state with :data:`LEAST_STEPS` samples after it (rod states as recorded, else
    from the end caps, which need no twist: no spring attached off a rod's axis), or where a split carries
    winch commands (their rollout needs the winding, not modelled here). ``splits``: the
    splits to start from (default :func:`check_splits`)."""
    splits = check_splits(dataset) if splits is None else splits
    if any(dataset.split(s).has_winch_commands for s in splits):
        return None
    dt = dataset.dt
    every, horizon = max(1, round(EVERY_S / dt)), max(1, round(HORIZON_S / dt))
    starts, extents = [], []
    rows: list[tuple[State, np.ndarray, np.ndarray, np.ndarray | None]] = []
    for name in splits:
        split = dataset.split(name)
        nodes = split.nodes
        if split.has_states:  # recorded rod states: the measured state itself
            st = {k: np.asarray(getattr(split, k)) for k in ("p", "v", "q", "omega")}
        elif dataset.topology.off_axis_points():  # states from end caps need the twist
            continue
        else:
            _, st = measured_rod_states(nodes, dataset.topology, dt, "gaussian", SMOOTHING_S)
        known = np.isfinite(st["p"]).all((-1, -2)) & np.isfinite(st["omega"]).all((-1, -2))
        for n, t in _starts(known, every, horizon):
            L = min(horizon, nodes.shape[1] - 1 - t)
            init = State(*(torch.as_tensor(st[k][n, t][None]) for k in ("p", "v", "q", "omega")))
            cables = None if split.cable_control is None else split.cable_control[n, t : t + L]
            rows.append((init, nodes[n, t : t + L + 1], split.control[n, t : t + L], cables))
            seen = nodes[n, t : t + L + 1][np.isfinite(nodes[n, t : t + L + 1]).all(-1)]
            extents.append(_diameter(seen))
            starts.append(name)
    if not rows:
        return None
    L = max(r[1].shape[0] - 1 for r in rows)
    engine = model.replace(dt=dt).engine(physics_dt=physics_dt)
    err2 = np.zeros(L + 1)
    count = np.zeros(L + 1)
    lost = 0  # rollouts with a non-finite end cap
    groups: dict[int, list[int]] = {}  # starts of one length run as one batch
    for i, r in enumerate(rows):
        groups.setdefault(r[2].shape[0], []).append(i)
    with torch.no_grad(), np.errstate(invalid="ignore", over="ignore"):
        for n, idx in groups.items():
            init = State(
                *(
                    torch.cat([getattr(rows[i][0], k) for i in idx])
                    for k in ("p", "v", "q", "omega")
                )
            )
            control = torch.as_tensor(np.stack([rows[i][2] for i in idx]), dtype=torch.float64)
            cab = [c for i in idx if (c := rows[i][3]) is not None]
            commands = torch.as_tensor(np.stack(cab), dtype=torch.float64) if cab else None
            pred = rollout_caps(engine, model.params, init, control, commands).numpy()
            blown = ~np.isfinite(pred).all((1, 2, 3))  # (B,)
            lost += int(blown.sum())
            d2 = np.sum((pred - np.stack([rows[i][1] for i in idx])) ** 2, -1)  # (B, n+1, 2R)
            ok = np.isfinite(d2) & ~blown[:, None, None]
            err2[: n + 1] += np.where(ok, d2, 0.0).sum((0, 2))
            count[: n + 1] += ok.sum((0, 2))
    rms = np.sqrt(err2[1:] / np.maximum(count[1:], 1))
    rms[count[1:] == 0] = 0.0
    worst = float(rms.max())
    at = float((int(rms.argmax()) + 1) * dt)
    extent = float(np.median(extents))
    return OpenLoopCheck(tuple(dict.fromkeys(starts)), len(rows), L * dt, worst, at,
                         extent_limit(extent, noise), extent, noise, lost,
                         tuple(float(x) if c else float("nan") for x, c in zip(rms, count[1:], strict=True)), dt)  # fmt: skip


def worse_prediction(
    new: OpenLoopCheck, old: OpenLoopCheck, horizons: tuple[float, ...] = HORIZONS_S
) -> str:
    """Why ``new`` predicts worse than ``old`` (both rolled out from the same starts): the
    horizons at which its end-cap RMS exceeds ``old``'s by more than the noise level (a
    difference below it is not one the markers can show); "" where it does not."""
    a, b = new.at(horizons), old.at(horizons)
    worse = [i for i, (x, y) in enumerate(zip(a, b, strict=True))
             if x is not None and y is not None and not x <= y + old.noise_m]  # fmt: skip
    if not worse:
        return ""
    mm = lambda v: "inf" if v is None or not np.isfinite(v) else f"{v * 1e3:.3g}"  # noqa: E731
    return ("end-cap RMS at " + ", ".join(f"{horizons[i]:g} s {mm(a[i])} mm against {mm(b[i])} mm"
                                          for i in worse)
            + f" open-loop from measured states on {', '.join(repr(s) for s in new.splits)}")  # fmt: skip


def _diameter(points: np.ndarray) -> float:
    """The largest distance [m] between two of ``points`` (P, 3) (0 for fewer than two)."""
    if len(points) < 2:
        return 0.0
    pts = np.unique(points.round(6), axis=0)
    # the farthest pair lies among the extremes along many directions: exact enough for a
    # limit, and linear in the points (a take's horizon holds thousands of samples)
    dirs = np.random.default_rng(0).normal(size=(64, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    proj = pts @ dirs.T
    ext = pts[np.unique(np.concatenate([proj.argmin(0), proj.argmax(0)]))]
    return float(np.max(np.linalg.norm(ext[:, None] - ext[None], axis=-1)))


def check_open_loop(stage: str, check: OpenLoopCheck | None, advice: str) -> None:
    """Raise :class:`StageError` naming ``stage`` when ``check`` says the model diverged."""
    if check is not None and check.diverged:
        raise StageError(
            stage, f"the model diverges open-loop ({check.line()}); nothing written", advice
        )


def check_not_worse_than_start(
    stage: str,
    model: Model,
    start: Model | None,
    dataset: Dataset,
    noise: float,
    physics_dt: float | None,
) -> OpenLoopCheck | None:
    """Raise :class:`StageError` naming ``stage`` where ``model`` predicts the validation
    split (the held-out splits where there is none) open-loop from measured states worse than the ``start`` model (the one the
    user gave, e.g. a robot's nominal model) at every horizon of :data:`HORIZONS_S` by
    more than the ``noise`` level [m] (:func:`worse_prediction`): such a fit has learnt
    nothing the start did not know better, and writing it would pass a worse model off
    as an identified one. Worse at some horizons only is a trade a fit may make, and is
    written. Returns the start's check (None where there is no start or nothing could be
    rolled out)."""
    if start is None:
        return None
    splits = ("val",) if "val" in dataset.splits else None  # the test split stays unseen
    new = open_loop_check(model, dataset, noise, physics_dt, splits)
    old = open_loop_check(start, dataset, noise, physics_dt, splits)
    if new is None or old is None:
        return old
    a, b = new.at(), old.at()
    pairs = [(x, y) for x, y in zip(a, b, strict=True) if x is not None and y is not None]
    if pairs and all(not x <= y + noise for x, y in pairs):
        raise StageError(stage, f"the fitted model predicts worse than the start model at every "
                         f"horizon ({worse_prediction(new, old)}); not written", WORSE_THAN_START_ADVICE)  # fmt: skip
    return old
