"""The closed loop on measured data: identify and diagnose, run as a user would.

For each cell of the matrix (setting x rate x noise x dropouts x planted effect x
seed) this script writes motion-capture-like data with its own MuJoCo script
(``benchmarks/measured_plant.py``: end caps only, noise, gap-filled dropouts),
runs ``tensegrity-sr identify`` and ``tensegrity-sr diagnose`` on it through the
command line, and records:

* whether each command succeeded, crashed (a traceback) or stopped with a message
  (its last line), its exit code, wall time and CPU time (user + system, its worker
  processes included: unlike the wall time, it does not grow with other jobs' load);
* the effects ``diagnose`` named against the planted ones;
* relative parameter errors against the truth (masses, inertias, stiffness, damping,
  rest lengths) of both params files, and any unphysical value written;
* the open-loop rollout error over the first second of each clean test trajectory,
  from its true initial state, of the declared model (``identify``: "before") and of
  the diagnosed model (``diagnose``: "after"), stepped at <= 1 ms between samples;
* the 2-sigma coverage of the stated standard errors.

``--identify-only`` runs ``identify`` alone (``diagnose`` is recorded as skipped): the
cheap way to measure that coverage over many seeds.

Results accumulate in ``docs/results/measured.json`` (one record per cell label; a
rerun replaces that cell's record) and ``docs/results/measured.md`` is generated from
it. Default: the 120 Hz / 1 mm / no-dropout cells of both settings, seed 0.

    OMP_NUM_THREADS=1 nice -n 10 python benchmarks/bench_measured.py            # default cells
    python benchmarks/bench_measured.py --settings flight --effects none,linear_drag
    python benchmarks/bench_measured.py --all                                   # whole matrix
    python benchmarks/bench_measured.py --settings flight --effects none --seeds 10 --identify-only
    python benchmarks/bench_measured.py --all --sample 8 --shard 0/2 --identify-only \
        --json sweep0.json          # crash sweep: 8 random cells not yet run, half of them
    python benchmarks/bench_measured.py --report-only                           # rewrite the .md
    python benchmarks/bench_measured.py --settings floor --seeds 2 --effects none --reference-only
    python benchmarks/bench_measured.py --settings floor --rescore --workdir DIR   # kept cells
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from measured_plant import (
    DROPOUTS,
    NOISES,
    PLANT_VERSION,
    PLANTED,
    RATES,
    SETTINGS,
    Cell,
    CellData,
    true_model,
    write_cell,
)
from measured_report import evaluate_cell, floor_windows, selection, write_markdown
from measured_tolerance import tolerance_reference

from tensegrity_env.io_utils import atomic_write_text

ROOT = Path(__file__).resolve().parent.parent


def run_cli(args: list[str], folder: Path, log: str, timeout: float) -> dict[str, Any]:
    """Run ``tensegrity-sr ARGS`` in ``folder``; returns status, exit code, wall time and
    CPU time [s], last line."""
    cmd = [sys.executable, "-m", "tensegrity_sr.cli", *args]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    c0 = children_cpu()
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env,
                           cwd=folder)  # fmt: skip
    except subprocess.TimeoutExpired as e:
        out = (e.stdout or b"").decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
        (folder / log).write_text(out)
        return {"status": "timeout", "code": None, "seconds": timeout,
                "message": f"no result within {timeout:g} s", "command": shlex.join(args)}  # fmt: skip
    wall = time.perf_counter() - t0
    cpu = children_cpu() - c0
    (folder / log).write_text(f"$ {shlex.join(cmd)}\n{p.stdout}\n--- stderr ---\n{p.stderr}")
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    if "Traceback (most recent call last)" in p.stderr:
        status = "crash"
    elif p.returncode != 0:
        status = "failed"
    else:
        status = "ok"
    message = lines[-1] if (lines and status != "ok") else ""
    return {"status": status, "code": p.returncode, "seconds": round(wall, 2),
            "cpu_seconds": round(cpu, 2), "message": message, "command": shlex.join(args)}  # fmt: skip


def children_cpu() -> float:
    """User + system CPU seconds of this process's finished children (and theirs) [s]."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_cell(
    cell: Cell,
    work: Path,
    timeout: float,
    diagnose_args: list[str] | None,
    identify_args: Sequence[str] = (),
) -> dict[str, Any]:
    """Write the cell's data, run identify (with ``identify_args``) and diagnose (None:
    skipped) on it, evaluate both."""
    folder = work / cell.label.replace("/", "_")
    t0 = time.perf_counter()
    data = write_cell(cell, folder)
    record: dict[str, Any] = {"cell": cell.__dict__ | {"label": cell.label},
                              "expected": list(cell.expected), "plant_version": PLANT_VERSION,
                              "data_seconds": round(time.perf_counter() - t0, 2)}  # fmt: skip
    anchor = f"mass[rod0]={float(data.truth.params.mass[0])!r}"
    ident = folder / "identify.json"
    diag = folder / "diagnose"
    for f in (ident, diag / "params.json"):
        f.unlink(missing_ok=True)
    record["identify"] = run_cli(
        ["identify", "measured.h5", "--anchor", anchor, "-o", ident.name, *identify_args],
        folder, "identify.log", timeout,
    )  # fmt: skip
    if diagnose_args is None:
        record["diagnose"] = {"status": "skipped", "code": None, "seconds": 0.0,
                              "message": "--identify-only", "command": ""}  # fmt: skip
    else:
        record["diagnose"] = run_cli(
            ["diagnose", "measured.h5", "--anchor", anchor, "-o", diag.name, "--force",
             *diagnose_args],
            folder, "diagnose.log", timeout,
        )  # fmt: skip
    record.update(evaluate_cell(data, ident, diag / "params.json"))
    if cell.setting == "floor":
        record["reference"] = tolerance_reference(data)
    return record


def matrix(args: argparse.Namespace) -> list[Cell]:
    """The cells selected by the command line."""

    def pick(text: str | None, full: tuple[Any, ...], cast: Any) -> list[Any]:
        return list(full) if args.all and text is None else [cast(x) for x in text.split(",")]

    settings = pick(args.settings, SETTINGS, str)
    rates = pick(args.rates, RATES, float)
    noises = [n * 1e-3 for n in pick(args.noise, NOISES, float)]
    drops = [d / 100 for d in pick(args.dropout, DROPOUTS, float)]
    effects = pick(args.effects, tuple(PLANTED), str)
    bad = [e for e in effects if e not in PLANTED] + [s for s in settings if s not in SETTINGS]
    if bad:
        raise SystemExit(f"error: unknown setting/effect {bad} (effects: {', '.join(PLANTED)})")
    seeds = range(args.seed0, args.seed0 + args.seeds)
    return [Cell(s, r, n, d, e, k) for s, r, n, d, e, k in
            itertools.product(settings, rates, noises, drops, effects, seeds)]  # fmt: skip


def sample_cells(cells: list[Cell], done: set[str], n: int, seed: int, shard: str) -> list[Cell]:
    """``n`` cells drawn at random (``seed``) from ``cells`` whose labels are not in
    ``done`` (a crash sweep over the matrix), then every ``N``-th from ``K`` for
    ``shard`` ``"K/N"`` (parallel runs with their own ``--json``, merged afterwards)."""
    try:
        k, of = (int(x) for x in shard.split("/"))
    except ValueError:
        raise SystemExit(f"error: --shard {shard!r}: expected K/N, e.g. 0/2") from None
    if not 0 <= k < of:
        raise SystemExit(f"error: --shard {shard}: K must be in 0..N-1")
    todo = [c for c in cells if c.label not in done]
    order = np.random.default_rng(seed).permutation(len(todo))
    return [todo[i] for i in order[:n]][k::of]


def add_references(args: argparse.Namespace, results: dict[str, Any]) -> None:
    """Add the tolerance reference (:func:`tolerance_reference`) to the selected floor
    cells already recorded in ``results``, rewriting ``--json`` after each."""
    with tempfile.TemporaryDirectory(prefix="bench_measured_") as work:
        cells = matrix(args)
        if args.sample:
            cells = sample_cells(cells, set(results["cells"]), args.sample, args.sample_seed,
                                 args.shard)  # fmt: skip
        for cell in cells:
            rec = results["cells"].get(cell.label)
            if cell.setting != "floor" or rec is None:
                continue
            print(f"{cell.label}: models within the targets ...", flush=True)
            data = write_cell(cell, Path(work) / cell.label.replace("/", "_"))
            rec["reference"] = tolerance_reference(data)
            atomic_write_text(args.json, json.dumps(results, indent=1) + "\n")


def rescore(args: argparse.Namespace, results: dict[str, Any]) -> None:
    """Score again the selected cells recorded in ``results`` whose files are kept in
    ``--workdir`` (``measured.h5``, ``clean.h5``, ``identify.json``,
    ``diagnose/params.json``): the command records stay, the scores are replaced."""
    if args.workdir is None:
        raise SystemExit("error: --rescore needs --workdir, the folder of a run's kept cells")
    for cell in matrix(args):
        rec = results["cells"].get(cell.label)
        folder = args.workdir / cell.label.replace("/", "_")
        if rec is None or not (folder / "clean.h5").is_file():
            continue
        print(f"{cell.label}: scored again from {folder}", flush=True)
        data = CellData(folder / "measured.h5", folder / "clean.h5", true_model(cell), cell)
        rec.update(evaluate_cell(data, folder / "identify.json", folder / "diagnose/params.json"))
        atomic_write_text(args.json, json.dumps(results, indent=1) + "\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--settings", help=f"comma-separated of {','.join(SETTINGS)} (default both)")
    ap.add_argument("--rates", help="sample rates [Hz] (default 120)")
    ap.add_argument("--noise", help="end-cap noise std [mm] (default 1)")
    ap.add_argument("--dropout", help="dropped samples [%%] (default 0)")
    ap.add_argument("--effects", help=f"planted effects of {','.join(PLANTED)} (default all)")
    ap.add_argument("--seeds", type=int, default=1, help="seeds per cell (default 1)")
    ap.add_argument("--seed0", type=int, default=0, help="first seed (default 0)")
    ap.add_argument("--all", action="store_true", help="every value of unspecified axes")
    ap.add_argument("--timeout", type=float, default=3600, help="seconds per command")
    ap.add_argument("--diagnose-args", default="", help="extra diagnose options, one string")
    ap.add_argument("--identify-args", default="", help="extra identify options, one string")
    ap.add_argument("--sample", type=int, default=0,
                    help="run this many cells drawn at random from the selection, skipping "
                         "those already in --json (a crash sweep; with --all: the matrix)")
    ap.add_argument("--sample-seed", type=int, default=0, help="seed of --sample (default 0)")
    ap.add_argument("--shard", default="0/1",
                    help="K/N: run every N-th sampled cell from K (default 0/1)")  # fmt: skip
    ap.add_argument("--identify-only", action="store_true",
                    help="run identify alone (standard-error coverage over many seeds)")  # fmt: skip
    ap.add_argument("--workdir", type=Path, help="where cell data and logs go (default: temp)")
    ap.add_argument("--json", type=Path, default=ROOT / "docs/results/measured.json")
    ap.add_argument("--md", type=Path, default=ROOT / "docs/results/measured.md")
    ap.add_argument("--report-only", action="store_true", help="only regenerate --md from --json")
    ap.add_argument("--reference-only", action="store_true",
                    help="only measure the floor checks of models within the targets for the "
                         "selected floor cells already in --json (no identify or diagnose)")  # fmt: skip
    ap.add_argument("--rescore", action="store_true",
                    help="only score again the selected cells in --json from the files a run "
                         "kept in --workdir (no identify or diagnose)")  # fmt: skip
    args = ap.parse_args()
    if not args.all:
        args.settings = args.settings or ",".join(SETTINGS)
        args.rates, args.noise = args.rates or "120", args.noise or "1"
        args.dropout, args.effects = args.dropout or "0", args.effects or ",".join(PLANTED)
    results: dict[str, Any] = {"cells": {}}
    if args.json.is_file():
        results = json.loads(args.json.read_text())
    if args.reference_only:
        add_references(args, results)
    elif args.rescore:
        rescore(args, results)
    elif not args.report_only:
        work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_measured_"))
        extra = None if args.identify_only else shlex.split(args.diagnose_args)
        cells = matrix(args)
        if args.sample:
            cells = sample_cells(cells, set(results["cells"]), args.sample, args.sample_seed,
                                 args.shard)  # fmt: skip
        for cell in cells:
            print(f"{cell.label} ...", flush=True)
            rec = run_cell(cell, work, args.timeout, extra, shlex.split(args.identify_args))
            rec["diagnose_args"] = args.diagnose_args
            if args.identify_args:
                rec["identify_args"] = args.identify_args
            rec["selection"] = selection(args.diagnose_args)
            if cell.setting == "floor":
                rec["floor_windows"] = floor_windows(args.identify_args, args.diagnose_args)
            results["cells"][cell.label] = rec
            atomic_write_text(args.json, json.dumps(results, indent=1) + "\n")
            print(f"  identify {rec['identify']['status']}, diagnose {rec['diagnose']['status']} "
                  f"({rec['diagnose']['seconds']} s), named {rec.get('named')}", flush=True)  # fmt: skip
        print(f"data and logs in {work}")
    write_markdown(results, args.md)
    print(f"wrote {args.json} and {args.md}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
