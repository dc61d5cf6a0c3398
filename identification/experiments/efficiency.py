"""The paper's data-efficiency experiment: identify from random fractions of the data.

The paper (Sec. "Data Efficiency Experiment") trains on 100 %, 10 %, 1 %, 0.1 % and
0.01 % of the 736,167 training transitions of the icosahedron data and reports that
73 transitions still suffice. :func:`run_efficiency` repeats that with the exact
regression of :class:`~identification.linear.regression.SpringRodIdentifier`: for each
fraction and seed it fits on a random subset of the training transitions and records

* the number of transitions used and how many parameters the subset cannot identify;
* the largest relative parameter error per group and overall, against the dataset's
  ground truth (when it has one);
* the one-step and rollout position errors of the identified engine on the test split
  (mean over the horizon and at its end) [m].

Scale: from motion alone ``M, I, K, c, h`` share one unknown factor. With ``anchors``
(e.g. a weighed rod, ``{"mass[rod0]": 1.95}``) the values are absolute; without, they
are ratios to the first rod's mass and are compared with the ratios of the ground
truth. The ground truth is only used to score, never to pick the anchor. Rollouts are
valid in either mode, since the motion does not change when all of them are scaled.

Example::

    result = run_efficiency(dataset, truth.params, anchors={"mass[rod0]": 1.95})
    print(result.markdown())
    write_outputs(result, "out/efficiency")   # efficiency.md, .json, .png

Over 400 lines because it is one experiment: the sweep, its result type and its three
outputs (markdown, JSON, figure) read the same records.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from tqdm.auto import tqdm

from identification.data.dataset import Dataset
from identification.defaults import DEFAULT_FRACTIONS
from identification.linear.regression import SpringRodIdentifier
from identification.report.plots import save_figure
from identification.report.tables import group_errors
from tensegrity_env.io_utils import InputError, atomic_write_text
from tensegrity_env.params import Params

#: Parameter groups shown, in this order (``stiffness_rest`` = K·l0 is internal: its
#: error shows up in ``rest_length``).
GROUPS: tuple[str, ...] = (
    "mass",
    "inertia",
    "stiffness",
    "rest_length",
    "damping",
    "control_gain",
)

_GROUP_LABELS = {
    "mass": "M",
    "inertia": "I",
    "stiffness": "K",
    "rest_length": "l0",
    "damping": "c",
    "control_gain": "h",
}


@dataclass(frozen=True)
class EfficiencyRun:
    """One fit on one random subset.

    Attributes:
        fraction: requested fraction of the training transitions.
        seed: seed of the random subset.
        n_transitions: transitions actually used.
        group_errors: largest relative error per parameter group (identified
            parameters only; empty without ground truth).
        max_error: largest of ``group_errors`` (NaN without ground truth).
        not_identifiable: names of the parameters this subset cannot identify.
        one_step_error: mean one-step position error on the test split [m].
        rollout_mean_error: mean rod position error over the rollout horizon [m].
        rollout_final_error: mean rod position error at the end of the horizon [m].
        fit_seconds: wall time of ``fit`` [s].
        note: why the test errors are missing, if they are.
    """

    fraction: float
    seed: int
    n_transitions: int
    group_errors: dict[str, float]
    max_error: float
    not_identifiable: list[str]
    one_step_error: float
    rollout_mean_error: float
    rollout_final_error: float
    fit_seconds: float
    note: str = ""


@dataclass
class EfficiencyResult:
    """All runs of the experiment and how they were made.

    Attributes:
        runs: one entry per (fraction, seed); a fraction that covers every
            transition is fitted once (all seeds would pick the same subset).
        mode: ``"anchored"`` (absolute values) or ``"ratios"`` (relative to the
            first rod's mass).
        anchors: the anchors used, name -> value in the parameter's unit.
        total_transitions: transitions in the training split.
        horizon_steps: rollout horizon on the test split [steps] (0: no test split).
        dt: time step [s].
        has_truth: whether parameter errors were measured against ground truth.
        source: where the data came from (file path or description).
    """

    runs: list[EfficiencyRun]
    mode: str
    anchors: dict[str, float]
    total_transitions: int
    horizon_steps: int
    dt: float
    has_truth: bool
    source: str = ""
    groups: list[str] = field(default_factory=list)

    def fractions(self) -> list[float]:
        """The fractions, in the order they were run."""
        return list(dict.fromkeys(r.fraction for r in self.runs))

    def runs_of(self, fraction: float) -> list[EfficiencyRun]:
        return [r for r in self.runs if r.fraction == fraction]

    def summary(self) -> list[dict[str, Any]]:
        """Per fraction: the worst value over seeds of each error (NaN-aware)."""
        out = []
        for f in self.fractions():
            runs = self.runs_of(f)
            out.append(
                {
                    "fraction": f,
                    "n_transitions": int(np.median([r.n_transitions for r in runs])),
                    "seeds": len(runs),
                    "groups": {g: _worst(r.group_errors.get(g) for r in runs) for g in self.groups},
                    "max_error": _worst(r.max_error for r in runs),
                    "median_max_error": _median(r.max_error for r in runs),
                    "not_identifiable": max(len(r.not_identifiable) for r in runs),
                    "one_step_error": _worst(r.one_step_error for r in runs),
                    "rollout_mean_error": _worst(r.rollout_mean_error for r in runs),
                    "rollout_final_error": _worst(r.rollout_final_error for r in runs),
                    "fit_seconds": _median(r.fit_seconds for r in runs),
                }
            )
        return out

    def markdown(self) -> str:
        """The table: one row per fraction, worst value over seeds in each column."""
        scale = (
            "absolute values (anchors: "
            + ", ".join(f"{k}={v:g}" for k, v in self.anchors.items())
            + ")"
            if self.mode == "anchored"
            else "ratios to mass of the first rod, compared with the true ratios (no anchor)"
        )
        lines = [
            f"Data efficiency: {self.total_transitions:,} training transitions, "
            f"dt = {self.dt:g} s; parameters as {scale}.",
            "Relative errors are the largest over the identified parameters of each group "
            "and over the seeds; rollout errors are mean rod-position errors on the test "
            f"split over {self.horizon_steps} steps ({self.horizon_steps * self.dt:g} s), "
            "worst seed.",
            "",
        ]
        group_cols = [f"{_GROUP_LABELS.get(g, g)} rel. err" for g in self.groups]
        header = [
            "fraction",
            "transitions",
            "seeds",
            "max rel. err (median seed)",
            *group_cols,
            "not identifiable",
            "one-step [m]",
            "rollout mean [m]",
            "rollout final [m]",
            "fit [s]",
        ]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for s in self.summary():
            cells = [
                f"{100 * s['fraction']:g}%",
                f"{s['n_transitions']:,}",
                str(s["seeds"]),
                f"{_e(s['max_error'])} ({_e(s['median_max_error'])})",
                *(_e(s["groups"][g]) for g in self.groups),
                str(s["not_identifiable"]),
                _e(s["one_step_error"]),
                _e(s["rollout_mean_error"]),
                _e(s["rollout_final_error"]),
                f"{s['fit_seconds']:.2f}",
            ]
            lines.append("| " + " | ".join(cells) + " |")
        notes = sorted({f"{100 * r.fraction:g}%: {r.note}" for r in self.runs if r.note})
        if notes:
            lines += ["", *(f"- {n}" for n in notes)]
        missing = sorted({n for r in self.runs for n in r.not_identifiable})
        if missing:
            lines += ["", f"Not identifiable in some runs: {', '.join(missing[:12])}"]
            if len(missing) > 12:
                lines[-1] += f", ... ({len(missing)} in all)"
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "anchors": self.anchors,
            "total_transitions": self.total_transitions,
            "horizon_steps": self.horizon_steps,
            "dt": self.dt,
            "has_truth": self.has_truth,
            "source": self.source,
            "groups": self.groups,
            "summary": self.summary(),
            "runs": [asdict(r) for r in self.runs],
        }


def _jsonable(x: Any) -> Any:
    """``x`` with NaN/inf as None (strict JSON)."""
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def _finite(values: Any) -> list[float]:
    return [float(v) for v in values if v is not None and np.isfinite(v)]


def _worst(values: Any) -> float:
    v = _finite(values)
    return max(v) if v else float("nan")


def _median(values: Any) -> float:
    v = _finite(values)
    return float(np.median(v)) if v else float("nan")


def _e(x: float) -> str:
    return "—" if not np.isfinite(x) else f"{x:.2e}"


def run_efficiency(
    dataset: Dataset,
    truth: Params | None = None,
    anchors: Mapping[str, float] | None = None,
    fractions: Sequence[float] = DEFAULT_FRACTIONS,
    seeds: int = 3,
    split: str = "train",
    test_split: str | None = "test",
    horizon: int | None = None,
    progress: bool = False,
    **identifier_kwargs: Any,
) -> EfficiencyResult:
    """Fit on random fractions of the training transitions; see the module docstring.

    Args:
        dataset: trajectories with rod states (``split`` and, for test errors,
            ``test_split``).
        truth: ground-truth parameters to measure relative errors against (only
            for scoring; None: no parameter errors).
        anchors: known values fixing the scale, e.g. ``{"mass[rod0]": 1.95}`` [kg];
            None or empty: results are ratios to the first rod's mass.
        fractions: fractions of the training transitions, each in (0, 1].
        seeds: random subsets per fraction (seeds 0 .. seeds-1).
        split: the split to fit on.
        test_split: the split to measure one-step and rollout errors on (None or
            absent: none).
        horizon: rollout horizon on the test split [steps] (None: whole trajectories).
        progress: show a progress bar over the fits.
        identifier_kwargs: further :class:`SpringRodIdentifier` settings (``solver``,
            ``shared``, ...).

    Returns:
        The runs, in the order of ``fractions`` and seeds.
    """
    fractions = [float(f) for f in fractions]
    bad = [f for f in fractions if not (np.isfinite(f) and 0 < f <= 1)]
    if bad:
        raise InputError(f"fractions must be in (0, 1], got {bad}")
    if seeds < 1:
        raise InputError(f"seeds must be >= 1, got {seeds}")
    data = dataset.split(split)
    total = data.n_trajectories * data.n_transitions
    anchors = dict(anchors or {})
    has_test = (
        test_split is not None
        and test_split in dataset.splits
        and dataset.split(test_split).has_states
    )
    jobs = []
    for f in fractions:
        n = max(1, round(f * total))
        for seed in range(1 if n >= total else seeds):
            jobs.append((f, seed))
    runs: list[EfficiencyRun] = []
    mode = "anchored" if anchors else "ratios"
    horizon_steps = 0
    for f, seed in tqdm(jobs, desc="efficiency", unit="fit", disable=not progress):
        est = SpringRodIdentifier(anchors=anchors, fraction=f, seed=seed, **identifier_kwargs)
        t0 = time.perf_counter()
        est.fit(dataset, split)
        fit_s = time.perf_counter() - t0
        mode = est.mode_
        ratios = mode == "ratios"
        errs: dict[str, float] = {}
        if truth is not None:
            errs = {g: e for g, e in group_errors(est.table_, truth, ratios).items() if g in GROUPS}
        scores: dict[str, Any] = {}
        note = ""
        if has_test:
            assert test_split is not None
            try:
                scores = est.score(dataset, test_split, horizon=horizon)
            except InputError as e:
                note = f"no test errors ({e})"
            else:
                horizon_steps = int(scores["horizon_steps"])
        nan = float("nan")
        runs.append(
            EfficiencyRun(
                fraction=f,
                seed=seed,
                n_transitions=int(est.n_transitions_),
                group_errors=errs,
                max_error=max(errs.values()) if errs else nan,
                not_identifiable=est.unidentifiable(),
                one_step_error=float(scores.get("one_step_position_error", nan)),
                rollout_mean_error=float(scores.get("rollout_mean_position_error", nan)),
                rollout_final_error=float(scores.get("rollout_final_position_error", nan)),
                fit_seconds=fit_s,
                note=note,
            )
        )
    present = {g for r in runs for g in r.group_errors}
    return EfficiencyResult(
        runs=runs,
        mode=mode,
        anchors=anchors,
        total_transitions=total,
        horizon_steps=horizon_steps,
        dt=float(dataset.dt),
        has_truth=truth is not None,
        source=str(dataset.path) if dataset.path is not None else "",
        groups=[g for g in GROUPS if g in present],
    )


# ---------------------------------------------------------------------- outputs
def plot_efficiency(result: EfficiencyResult, path: str | Path) -> Path:
    """Log-log plot: parameter error and rollout error vs training transitions.

    Each seed is a dot; the line goes through the median over seeds and the band
    spans the seeds' minimum to maximum. Written atomically as PNG.
    """
    floor = 1e-18  # exact fits give errors at round-off; keep them on a log axis
    panels = [("rollout", "test-split rod position error [m]")]
    if result.has_truth:
        panels.insert(0, ("params", "largest relative parameter error"))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4.2), squeeze=False,
                             layout="constrained")  # fmt: skip
    fracs = result.fractions()
    n = np.array([np.median([r.n_transitions for r in result.runs_of(f)]) for f in fracs])
    order = np.argsort(n)

    def series(ax: Any, key: str, label: str, color: str) -> None:
        per = [[getattr(r, key) for r in result.runs_of(f)] for f in fracs]
        xs = [r.n_transitions for f in fracs for r in result.runs_of(f)]
        ys = [v for vals in per for v in vals]
        ok = np.isfinite(ys)
        if not ok.any():
            return
        ax.scatter(
            np.array(xs)[ok], np.maximum(np.array(ys)[ok], floor), s=14, color=color, alpha=0.6
        )
        med = np.array([_median(v) for v in per])[order]
        lo = np.array([min(_finite(v), default=np.nan) for v in per])[order]
        hi = np.array([max(_finite(v), default=np.nan) for v in per])[order]
        ax.plot(n[order], np.maximum(med, floor), "-o", color=color, label=label, ms=4)
        ax.fill_between(
            n[order], np.maximum(lo, floor), np.maximum(hi, floor), color=color, alpha=0.15
        )

    for ax, (kind, ylabel) in zip(axes[0], panels, strict=True):
        if kind == "params":
            series(ax, "max_error", "all groups", "k")
            colors = plt.get_cmap("tab10")
            for i, g in enumerate(result.groups):
                vals = [[r.group_errors.get(g, np.nan) for r in result.runs_of(f)] for f in fracs]
                med = np.array([_median(v) for v in vals])[order]
                ax.plot(
                    n[order], np.maximum(med, floor), "--", lw=1, color=colors(i),
                    label=_GROUP_LABELS.get(g, g), zorder=3,
                )  # fmt: skip
            ax.set_title("identified parameters vs ground truth")
        else:
            series(ax, "rollout_mean_error", "mean over horizon", "tab:blue")
            series(ax, "rollout_final_error", "end of horizon", "tab:red")
            series(ax, "one_step_error", "one step", "tab:green")
            ax.set_title(
                f"identified engine, {result.horizon_steps}-step rollouts"
                if result.horizon_steps
                else "no test split"
            )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("training transitions")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        if ax.has_data():
            ax.legend(fontsize=8)
    fig.suptitle(
        f"data efficiency ({'absolute, anchored' if result.mode == 'anchored' else 'ratios'}; "
        "dots: seeds, line: median, band: min–max)",
        fontsize=10,
    )
    return save_figure(fig, path)


def write_outputs(result: EfficiencyResult, out_dir: str | Path) -> dict[str, Path]:
    """Write ``efficiency.md`` (table), ``efficiency.json`` (every run) and
    ``efficiency.png`` (plot) into ``out_dir``, each atomically."""
    out = Path(out_dir)
    paths = {
        "table": atomic_write_text(out / "efficiency.md", result.markdown() + "\n"),
        "json": atomic_write_text(
            out / "efficiency.json", json.dumps(_jsonable(result.to_json()), indent=2) + "\n"
        ),
        "plot": plot_efficiency(result, out / "efficiency.png"),
    }
    return paths
