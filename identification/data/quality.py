"""What a measured dataset's samples are like: rate, jitter, gaps and marker noise.

A sample interval is a whole number of nominal steps plus jitter: an interval of ``k``
steps (``k = round(interval / dt)``) with ``k > 1`` is a pause in which ``k - 1``
frames were dropped (a paused recording, a frame the system lost), and its offset from
``k dt`` is jitter. Reported apart, a recording paused for seconds does not read as
seconds of jitter.

The noise of each end cap is estimated from the high-frequency residual of a smooth
fit: the third difference of three consecutive sample steps,
``x[t+3] - 3 x[t+2] + 3 x[t+1] - x[t]``, is the residual of a local quadratic; for
white noise of std ``σ`` it has std ``σ √20``, and smooth motion contributes only its
jerk times ``dt³``. A median absolute deviation keeps impacts from inflating it.

Time stamps that cannot be capture times are flagged with their times: a step far
shorter than the median step (two log messages of one frame, a clock that stamps on
arrival, not at capture) and gaps, steps far longer than it (frames lost, a pause).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identification.data.dataset import Dataset
from tensegrity_env.io_utils import atomic_path

#: consistency constant of the median absolute deviation for a normal distribution
MAD_TO_STD = 1.4826
#: a marker repeating exactly the same position over this many frames in a row (the rule
#: :func:`placeholder_samples` applies) holds a
#: value its tracker no longer sees (noise makes measured positions never repeat exactly)
HELD_RUN = 3
#: a frame whose every seen marker lies within this [m] of the frame before (per
#: coordinate) repeats it: 30 times below the finest marker noise of optical systems
#: (~0.03 mm), 100 times above the round-off of positions exported with 8 decimals
REPEAT_TOL = 1e-6
#: a step shorter than this fraction of the median step cannot separate two captures: a
#: capture system's frames are its period apart, give or take jitter of a small fraction
SHORT_STEP = 0.25
#: a step longer than this many median steps is a gap: at least one frame is missing
#: (jitter of up to half a period cannot stretch one step this far)
GAP_STEP = 1.5
#: how many flagged times the report lists
LISTED_TIMES = 5
#: what :func:`placeholder_samples` finds, for messages
PLACEHOLDER_KINDS = (f"exactly the origin, one position held over {HELD_RUN}+ frames, or a frame "
                     f"repeating the one before within {REPEAT_TOL * 1e6:g} µm")  # fmt: skip


@dataclass(frozen=True)
class SampleQuality:
    """Sampling and marker quality over all splits.

    Attributes:
        rate: nominal sample rate [Hz] (1 / dt).
        jitter: std of the sample intervals about the nearest whole number of steps
            ``k dt`` [s] (0 without stored times).
        max_jitter: largest deviation of one interval from its ``k dt`` [s].
        dropped_frames: frames missing from the sample times (``k - 1`` per interval of
            ``k`` steps).
        longest_pause: longest sample interval [s].
        duration: total recorded time [s].
        dropout: (2R,) fraction of samples each end cap was not seen.
        longest_gap: (2R,) longest run of unseen samples of each end cap [s].
        noise: (2R,) marker noise std per end cap [m] (NaN: too few samples).
        placeholders: samples that stand for an unseen end cap rather than a
            measurement (:func:`placeholder_samples`).
        median_step: median interval between consecutive samples [s].
        short_steps: times [s] (from each trajectory's start) of the samples that follow
            the one before by less than :data:`SHORT_STEP` median steps.
        gaps: times [s] of the samples that follow the one before by more than
            :data:`GAP_STEP` median steps.
    """

    rate: float
    jitter: float
    max_jitter: float
    dropped_frames: int
    longest_pause: float
    duration: float
    dropout: np.ndarray
    longest_gap: np.ndarray
    noise: np.ndarray
    placeholders: int
    median_step: float = 0.0
    short_steps: tuple[float, ...] = ()
    gaps: tuple[float, ...] = ()


def placeholder_samples(points: np.ndarray) -> np.ndarray:
    """(..., F, M) bool: the samples of marker positions ``points`` (..., F, M, 3) [m]
    that stand for an unseen marker rather than a measurement: exactly the origin (an
    exporter's zero fill), the repeats of one position held exactly over
    :data:`HELD_RUN` or more consecutive frames (a tracker holding its last value; the
    first sample of the run stays), and the samples of a repeated frame
    (:func:`repeated_frames`). Measurement noise makes all three impossible; noise-free
    data resting exactly in place would read as held."""
    x = np.asarray(points, dtype=float)
    mask = (x == 0.0).all(-1)
    same = np.isfinite(x[..., 1:, :, :]).all(-1) & (x[..., 1:, :, :] == x[..., :-1, :, :]).all(-1)
    # same[f]: sample f+1 repeats sample f; a repeat is held when the repeat before or
    # after it is one too (HELD_RUN = 3 identical samples in a row)
    before = np.zeros_like(same)
    before[..., 1:, :] = same[..., :-1, :]
    after = np.zeros_like(same)
    after[..., :-1, :] = same[..., 1:, :]
    mask[..., 1:, :] |= same & (before | after)
    mask |= repeated_frames(x)[..., None] & np.isfinite(x).all(-1)
    return mask


def repeated_frames(points: np.ndarray) -> np.ndarray:
    """(..., F) bool: the frames of marker positions ``points`` (..., F, M, 3) [m] in
    which every seen marker (two or more) repeats its position of the frame before
    within :data:`REPEAT_TOL`: an exporter's copy of the frame before (a capture system
    writing frames faster than it measures), not a measurement."""
    x = np.asarray(points, dtype=float)
    seen = np.isfinite(x[..., 1:, :, :]).all(-1)
    with np.errstate(invalid="ignore"):
        close = (np.abs(x[..., 1:, :, :] - x[..., :-1, :, :]) <= REPEAT_TOL).all(-1)  # NaN: False
    out = np.zeros(x.shape[:-2], dtype=bool)
    out[..., 1:] = (close | ~seen).all(-1) & (close.sum(-1) >= 2)
    return out


def third_difference_noise(d3: np.ndarray, least: int = 1) -> float:
    """Noise std [m] from third differences ``d3`` (any shape; non-finite ones left out):
    ``1.4826 MAD / √20``; NaN with fewer than ``least`` finite values."""
    v = np.asarray(d3, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if v.size < max(least, 1):
        return float("nan")
    return MAD_TO_STD * float(np.median(np.abs(v - np.median(v)))) / np.sqrt(20.0)


def longest_run(mask: np.ndarray) -> int:
    """Longest run of True along the last axis of a 1-D bool array."""
    best = run = 0
    for m in mask:
        run = run + 1 if m else 0
        best = max(best, run)
    return best


def sample_quality(ds: Dataset) -> SampleQuality:
    """Measure ``ds`` (every split, every trajectory)."""
    n_caps = 2 * ds.topology.n_rods
    steps, seen, missing = [], np.zeros(n_caps), np.zeros(n_caps)
    d3: list[list[np.ndarray]] = [[] for _ in range(n_caps)]  # per end cap
    ends: list[np.ndarray] = []  # the time of the sample ending each step
    longest = np.zeros(n_caps, dtype=int)
    duration, placeholders = 0.0, 0
    for s in ds.splits.values():
        t = s.times(ds.dt)
        for i in range(s.n_trajectories):
            ok_t = np.isfinite(t[i])
            ti = t[i, ok_t]
            duration += float(ti[-1] - ti[0]) + ds.dt
            steps.append(np.diff(ti))
            ends.append(ti[1:])
            nodes = s.nodes[i, ok_t]
            placeholders += int(placeholder_samples(nodes).sum())
            valid = np.isfinite(nodes).all(-1)
            seen += valid.sum(0)
            missing += (~valid).sum(0)
            for c in range(n_caps):
                longest[c] = max(longest[c], longest_run(~valid[:, c]))
                x = nodes[:, c]
                diff3 = x[3:] - 3 * x[2:-1] + 3 * x[1:-2] - x[:-3]
                d3[c].append(diff3[np.isfinite(diff3).all(-1)].ravel())
    intervals, stamped = np.concatenate(steps), np.concatenate(ends)
    median = float(np.median(intervals)) if intervals.size else ds.dt
    whole = np.maximum(np.rint(intervals / ds.dt), 1.0)
    dt_dev = intervals - whole * ds.dt
    noise = np.array([third_difference_noise(np.concatenate(d3[c]), least=10)
                      for c in range(n_caps)])  # fmt: skip
    return SampleQuality(
        rate=1.0 / ds.dt,
        jitter=float(np.sqrt(np.mean(dt_dev**2))) if dt_dev.size else 0.0,
        max_jitter=float(np.abs(dt_dev).max(initial=0.0)),
        dropped_frames=int((whole - 1).sum()),
        longest_pause=float(intervals.max(initial=ds.dt)),
        duration=duration,
        dropout=missing / np.maximum(seen + missing, 1),
        longest_gap=longest * ds.dt,
        noise=noise,
        placeholders=placeholders,
        median_step=median,
        short_steps=tuple(float(x) for x in stamped[intervals < SHORT_STEP * median]),
        gaps=tuple(float(x) for x in stamped[intervals > GAP_STEP * median]),
    )


def _us(seconds: float) -> str:
    """Microseconds, with round-off of float sample times (< 1 ns) shown as 0."""
    return "0" if seconds < 1e-9 else f"{seconds * 1e6:.3g}"


def quality_text(q: SampleQuality, cap_names: list[str]) -> str:
    """The lines ``inspect`` prints."""
    dropped = (f", {q.dropped_frames} dropped frames (longest pause {q.longest_pause:.3g} s)"
               if q.dropped_frames else "")  # fmt: skip
    lines = [
        f"sampling: {q.rate:g} Hz nominal, jitter {_us(q.jitter)} µs rms "
        f"(max {_us(q.max_jitter)} µs){dropped}, {q.duration:.3g} s recorded",
        "end cap        dropout  longest gap   noise",
    ]
    for what, times, rule in (
        ("steps too short to be capture times", q.short_steps, f"< {SHORT_STEP:g}"),
        ("gaps", q.gaps, f"> {GAP_STEP:g}"),
    ):
        if times:
            listed = ", ".join(f"{t:.3f}" for t in times[:LISTED_TIMES])
            more = ", ..." if len(times) > LISTED_TIMES else ""
            lines.insert(1, f"time stamps: {len(times)} {what} ({rule} x the median step "
                            f"{q.median_step * 1e3:.3g} ms), at {listed}{more} s")  # fmt: skip
    if q.placeholders:
        lines.insert(1, f"placeholder samples: {q.placeholders} ({PLACEHOLDER_KINDS}): unseen end "
                        "caps written as positions; identify refuses them, write them as NaN")  # fmt: skip
    for name, d, g, n in zip(cap_names, q.dropout, q.longest_gap, q.noise, strict=True):
        noise = "   n/a" if np.isnan(n) else f"{n * 1e3:6.3f} mm"
        lines.append(f"  {name:<12} {100 * d:6.2f} %  {g * 1e3:8.1f} ms  {noise}")
    return "\n".join(lines)


def plot_quality(ds: Dataset, q: SampleQuality, cap_names: list[str], path: str) -> None:
    """PNG: which end cap was seen when (first trajectory of each split), dropout and noise."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4), gridspec_kw={"width_ratios": [3, 1, 1]})
    s = ds.splits.get("train") or next(iter(ds.splits.values()))
    t = s.times(ds.dt)[0]
    ok = np.isfinite(t)
    valid = np.isfinite(s.nodes[0, ok]).all(-1)
    axes[0].imshow(~valid.T, aspect="auto", cmap="Reds", interpolation="nearest",
                   extent=(t[ok][0], t[ok][-1], len(cap_names) - 0.5, -0.5))  # fmt: skip
    axes[0].set(xlabel="time [s]", ylabel="end cap", title="gaps (red), first training take",
                yticks=range(len(cap_names)), yticklabels=cap_names)  # fmt: skip
    y = np.arange(len(cap_names))
    axes[1].barh(y, 100 * q.dropout)
    axes[1].set(xlabel="dropout [%]", yticks=y, yticklabels=[], title="dropout")
    axes[1].invert_yaxis()
    axes[2].barh(y, 1e3 * np.nan_to_num(q.noise))
    axes[2].set(xlabel="noise std [mm]", yticks=y, yticklabels=[], title="marker noise")
    axes[2].invert_yaxis()
    fig.suptitle(f"{ds.path}: {q.rate:g} Hz, jitter {_us(q.jitter)} µs rms")
    fig.tight_layout()
    with atomic_path(path, keep_extension=True) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
