"""Several runs (seeds) of one recipe, summarized as rliable recommends.

Each run is one policy evaluated over the same seeded episodes in the source and the
target env (:class:`~policies.transfer.TransferResult`); its score is the mean over
those episodes. Across runs, :func:`aggregate` reports the interquartile mean (IQM,
``rliable.metrics.aggregate_iqm``) with a 95 % stratified bootstrap interval
(``rliable.library.get_interval_estimates``, percentile method) of the return and the
success rate in each env, and of the transfer ratio ``IQM(target return) /
IQM(source return)``. For the ratio rliable resamples the runs' source and target
scores independently (``StratifiedIndependentBootstrap``, as for any metric of two
score sets), which ignores that they come from the same runs: the interval is wider
than a paired one would be.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from policies.transfer import TransferResult

#: bootstrap replications (rliable's default is 50,000; fewer keep a summary of a
#: handful of runs to seconds)
REPS = 5_000


def run_scores(results: Sequence[TransferResult]) -> dict[str, np.ndarray]:
    """Per-run mean scores, each (n_runs, 1): one task, rliable's layout."""
    def col(values: list[float]) -> np.ndarray:
        return np.asarray(values, dtype=float).reshape(-1, 1)

    return {
        "source_return": col([r.source.mean_return for r in results]),
        "target_return": col([r.target.mean_return for r in results]),
        "source_success": col([r.source.success_rate for r in results]),
        "target_success": col([r.target.success_rate for r in results]),
    }


def aggregate(
    results: Sequence[TransferResult], reps: int = REPS, seed: int = 0
) -> dict[str, dict[str, float]]:
    """IQM and 95 % interval of each score and of the transfer ratio over the runs.

    Returns ``{name: {"iqm", "low", "high"}}`` for ``source_return``,
    ``target_return``, ``source_success``, ``target_success`` and ``ratio``. The
    bootstrap is seeded (``seed``), so the intervals are reproducible; rliable draws
    from NumPy's global generator, whose state is restored afterwards.
    """
    from rliable import library, metrics

    scores = run_scores(results)

    def iqm(x: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(x)])

    def ratio(src: np.ndarray, tgt: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(tgt) / metrics.aggregate_iqm(src)])

    rng = np.random.RandomState(seed)
    saved = np.random.get_state()  # noqa: NPY002  (rliable draws from the legacy global generator)
    np.random.seed(seed)  # noqa: NPY002
    pair = {"ratio": [scores["source_return"], scores["target_return"]]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # arch: random_state's new name
        points, intervals = library.get_interval_estimates(
            scores, iqm, reps=reps, random_state=rng
        )
        p2, i2 = library.get_interval_estimates(pair, ratio, reps=reps, random_state=rng)
    np.random.set_state(saved)  # noqa: NPY002
    points.update(p2)
    intervals.update(i2)
    return {
        k: {"iqm": float(points[k][0]), "low": float(intervals[k][0, 0]),
            "high": float(intervals[k][1, 0])}
        for k in points
    }  # fmt: skip


def aggregate_table(agg: dict[str, dict[str, float]], n_runs: int, source: str, target: str) -> str:
    """A markdown table of :func:`aggregate`'s output."""
    def cell(k: str, scale: float = 1.0, spec: str = ".2f", unit: str = "") -> str:
        a = agg[k]
        return (
            f"{format(scale * a['iqm'], spec)}{unit} "
            f"[{format(scale * a['low'], spec)}, {format(scale * a['high'], spec)}]"
        )

    return "\n".join([
        f"IQM over {n_runs} runs [95 % stratified bootstrap interval]\n",
        "| env | return | success |",
        "| --- | --- | --- |",
        f"| {source} | {cell('source_return')} | {cell('source_success', 100, '.0f', '%')} |",
        f"| {target} | {cell('target_return')} | {cell('target_success', 100, '.0f', '%')} |",
        f"\ntransfer ratio (IQM target return / IQM source return): {cell('ratio', spec='.3f')}",
    ])  # fmt: skip


def to_dict(agg: dict[str, dict[str, float]], n_runs: int) -> dict[str, Any]:
    """Plain data for JSON."""
    return {"n_runs": n_runs, "estimator": "IQM, 95% stratified bootstrap (rliable)", **agg}
