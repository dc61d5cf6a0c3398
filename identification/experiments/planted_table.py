"""The residual loop on every planted effect, strength and noise level: one markdown table.

``python -m identification.experiments.planted_table -o OUT`` runs the residual loop
(:class:`~identification.discovery.loop.EffectDiscovery`) on
:func:`identification.simulation.planted.planted_dataset` for each case and writes
``OUT/planted_table.md`` (and a JSON copy): planted effect, strength, noise, the
effect(s) named, and held-out (test) one-step and 1-s rollout errors before and
after. Clean data is scored by one-step regressions on rod states
(:class:`~identification.discovery.one_step.OneStepScorer`). Noisy data (end caps
only) is scored by multi-step prediction of the end caps
(:class:`~identification.discovery.multi_step.MultiStepScorer`), started from the data alone
(``--start data``: smoothing + regression, then the fit on many windows) or from the
declared model's true parameters (``--start truth``: standing in for a params file from
an earlier calibration; every parameter is refitted jointly); its one-step and rollout
errors are measured
on the test split against the **clean** trajectories, which nothing else sees (the
noisy end caps cannot show a one-step error below the 1 mm noise).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TypedDict

import numpy as np
import torch

from identification.discovery.choose import choose_scorer, uses_trajectories
from identification.discovery.library import FitSettings
from identification.discovery.loop import EffectDiscovery
from identification.discovery.multi_step import MultiStepScorer
from identification.discovery.one_step import OneStepScorer
from identification.discovery.report import fmt_err, ratio, write_params
from identification.experiments.drop_check import drop_check
from identification.simulation.planted import PLANTS, PlantSpec, planted_dataset
from identification.trajectory.end_cap_data import FIT_WINDOW, TrajectorySettings
from tensegrity_env.io_utils import atomic_write_text


def cases(noises: tuple[float, ...], seed: int) -> list[PlantSpec]:
    """Every plant at every strength (the clean control once) and noise level."""
    out = []
    for noise in noises:
        for effect, strengths in PLANTS.items():
            for s in strengths:
                out.append(PlantSpec(effect, s, noise=noise, seed=seed))
    return out


class Row(TypedDict):
    """One row of the table (see the module docstring)."""

    planted: str
    strength: str
    noise_mm: float
    named: list[str]
    flagged: list[str]
    one_step_before: float
    one_step_after: float
    rollout_before: float
    rollout_after: float
    drop_2s: float | None
    seconds: float
    start: str
    params: list[str]


def run_case(
    spec: PlantSpec,
    smoothing: float = 0.01,
    settings: TrajectorySettings | None = None,
    log: Callable[[str], None] = lambda s: None,
    start: str = "data",
    params_out: Path | None = None,
    max_effects: int = 2,
) -> Row:
    """Diagnose one planted dataset; the row of the table (see the module docstring).

    ``params_out``: write the extended params file the loop identified there.
    """
    data = planted_dataset(spec)
    anchors = {"mass[rod0]": float(data.ground_truth.params.mass[0])}
    t0 = time.perf_counter()
    ts = replace(settings or TrajectorySettings(), anchors=anchors, seed=spec.seed)
    truth = data.ground_truth.params if start == "truth" else None
    dataset, scorer = choose_scorer(
        data.dataset, "auto",
        lambda d: OneStepScorer(FitSettings(anchors=anchors), horizon_s=1.0),
        lambda d: MultiStepScorer(ts, horizon_s=1.0, start=truth, clean=data.clean),
        smoothing,
    )  # fmt: skip
    if uses_trajectories(data.dataset):  # noisy: end caps only
        loop = EffectDiscovery(scorer, max_effects, log=log)
    else:
        loop = EffectDiscovery(scorer, max_effects=3, log=lambda s: None)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = loop.fit(dataset).result_
    if params_out is not None:
        write_params(r, params_out, {"planted": spec.label})
    b, f = r.baseline_test, r.final_test
    drop: float | None = None  # the 2-s drop against MuJoCo, for an identified contact
    if any(e.gate.needs == "floor" for e in r.model.effects):
        drop = drop_check(r.model.params, r.model.effects).worst
    flagged = [f"{it.chosen.name}~{amb[0]}" for it in r.iterations
               if it.chosen is not None and (amb := it.ambiguous) is not None]  # fmt: skip
    return {
        "planted": spec.effect, "strength": f"{spec.strength} ({spec.value:g})",
        "noise_mm": spec.noise * 1e3, "named": r.model.names, "flagged": flagged,
        "one_step_before": b["one_step"], "one_step_after": f["one_step"],
        "rollout_before": b["rollout"], "rollout_after": f["rollout"],
        "drop_2s": drop, "seconds": time.perf_counter() - t0, "start": start if spec.noise > 0 else "data",
        "params": [e.describe() for e in r.model.effects],
    }  # fmt: skip


def table(rows: list[Row]) -> str:
    lines = [
        "| planted | strength | noise | named | one-step before | after | gain "
        "| 1-s rollout before | after | gain | 2-s drop vs MuJoCo |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        named = ", ".join(r["named"]) or "nothing"
        if r["flagged"]:
            named += f" (flag: {', '.join(r['flagged'])})"
        ob, oa = float(r["one_step_before"]), float(r["one_step_after"])
        rb, ra = float(r["rollout_before"]), float(r["rollout_after"])
        drop = r["drop_2s"]
        lines.append(
            f"| {r['planted']} | {r['strength']} | {r['noise_mm']:g} mm | {named} | {fmt_err(ob)} | "
            f"{fmt_err(oa)} | {ratio(ob, oa)} | {fmt_err(rb)} | {fmt_err(ra)} | {ratio(rb, ra)} "
            f"| {'-' if drop is None else fmt_err(drop)} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("-o", "--output", type=Path, default=Path("planted_out"))
    p.add_argument("--noise", default="0,0.001", help="noise levels [m], comma-separated")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--effects", default="", help="comma-separated plants (default: all)")
    p.add_argument("--strengths", default="", help="comma-separated strengths (default: all)")
    p.add_argument(
        "--fit-window",
        type=int,
        default=FIT_WINDOW,
        help=f"noisy data: steps per window of each model's final fit (default {FIT_WINDOW}; "
        "0: 100)",
    )
    p.add_argument(
        "--fit-windows",
        type=int,
        default=32,
        help="noisy data: windows of each model's final fit (default 32)",
    )
    p.add_argument(
        "--max-effects",
        type=int,
        default=2,
        help="noisy data: most effects the loop adds (default 2)",
    )
    p.add_argument("--start", choices=("data", "truth"), default="data",
                   help="noisy data: start from the data alone or from the true declared "
                   "parameters (default: data)")  # fmt: skip
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    args.output.mkdir(parents=True, exist_ok=True)
    rows: list[Row] = []
    only = [e for e in args.effects.split(",") if e]
    strengths = [e for e in args.strengths.split(",") if e]
    for spec in cases(tuple(float(x) for x in args.noise.split(",")), args.seed):
        if (only and spec.effect not in only) or (
            strengths and spec.effect != "none" and spec.strength not in strengths
        ):
            continue
        print(f"{spec.label} ...", flush=True)
        name = f"params_{spec.effect}_{spec.strength}_{spec.noise * 1e3:g}mm_seed{spec.seed}.json"
        rows.append(run_case(spec, log=lambda s: print(s, flush=True), start=args.start,
                             settings=TrajectorySettings(fit_window=args.fit_window,
                                                         fit_windows=args.fit_windows),
                             max_effects=args.max_effects,
                             params_out=args.output / name))  # fmt: skip
        print(table(rows[-1:]).splitlines()[-1], flush=True)
        atomic_write_text(
            args.output / "planted_table.json", json.dumps(rows, indent=1, default=str)
        )
    atomic_write_text(args.output / "planted_table.md", table(rows) + "\n")
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
