"""Drawn plants (``benchmarks/plant_family.py``) identified as a user would, and judged
against the invariants of ``benchmarks/family_invariants.py``.

For each seed and setting a plant is drawn (file conventions and physics at random),
its MJCF and data written, and ``tensegrity-sr identify`` run on the end caps from the
true model (``--params true.xml``) and, with ``--default-start``, from the regression
(anchored by the true first rod mass). Each record holds the draw, the command's status,
the end-cap RMS against the plant's noise, the largest relative error per parameter
group, the floor contact's errors and the invariant's verdict.

Plants run in parallel processes through Dask distributed: a local cluster of
``--workers`` processes by default, or the workers of a running scheduler
(``--scheduler tcp://HOST:8786``; start one with ``dask scheduler`` and, on each
machine, ``dask worker tcp://HOST:8786 --nthreads 1`` from a checkout with
``PYTHONPATH=$PWD:$PWD/benchmarks``). Results go to ``docs/results/family.json``, written
as each plant finishes; a rerun skips the records already there for the same draw (it is
resumable), ``--rerun`` replaces them. ``docs/results/family.md`` is generated from it.

    OMP_NUM_THREADS=1 python benchmarks/bench_family.py --seeds 0-9 --setting flight floor \\
        --default-start --share 0.25
    python benchmarks/bench_family.py --report-only
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench_measured import run_cli
from family_invariants import (
    DISSIPATION_TOL,
    GROUPS,
    MAX_SE_RMS,
    RMS_OVER_NOISE,
    STRUCTURE_TOL,
    at_the_truth,
    contact_errors,
    largest_move,
    relative_se,
    silently_wrong,
    structure_error,
    verdict,
    warned,
    worst_errors,
)
from plant_family import Draw, draw, write_family_cell
from stderr_survey import worst_ratio

from identification.data.dataset import read_ground_truth
from identification.trajectory.floor_declared import STARTS_APART
from tensegrity_env.io_utils import atomic_write_text

ROOT = Path(__file__).resolve().parent.parent
#: the draw's fields a record keeps
DRAWN = ("rate", "noise", "dropout", "length", "prestress", "end_cap", "friction")
STARTS = ("truth", "default")


def seeds_of(text: str) -> list[int]:
    """``"0-4"`` or ``"1,3,7"`` -> seeds."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def draw_id(d: Draw, share: float) -> str:
    """A short hash of everything drawn and of the data share: a record is reused only
    for the very plant and data it was measured on."""
    text = json.dumps({**d.summary(), "share": share}, sort_keys=True)
    return hashlib.sha1(text.encode()).hexdigest()[:12]


def identify(folder: Path, start: str, timeout: float) -> dict[str, Any]:
    """Run ``identify`` on ``folder``'s plant from ``start``; the record's result fields."""
    gt = read_ground_truth(folder / "measured.h5")
    assert gt is not None
    truth = gt.params.numpy()
    out = folder / f"{start}.json"
    out.unlink(missing_ok=True)
    args = ["identify", "measured.h5", "-o", out.name]
    args += (["--params", "true.xml"] if start == "truth"
             else ["--anchor", f"mass[rod0]={float(truth['mass'][0])!r}"])  # fmt: skip
    record: dict[str, Any] = {"identify": run_cli(args, folder, f"{start}.log", timeout)}
    if record["identify"]["status"] == "ok":
        doc = json.loads(out.read_text())
        noise = float(gt.sim.get("draw", {}).get("noise", float("nan")))
        record["end_cap_rms_m"] = doc["provenance"]["end_cap_rms_m"]
        record["rms_over_noise"] = record["end_cap_rms_m"] / noise
        record["worst"] = worst_errors(doc["params"], truth)
        record["moved"] = list(largest_move(doc, truth))
        record["relative_se"] = relative_se(doc)
        record["worst_se_ratio"] = worst_ratio(doc)[1]
        if "two_starts" in doc["provenance"]:
            record["two_starts"] = doc["provenance"]["two_starts"]
        record["contact"], record["contact_unseen"] = contact_errors(doc, gt.effects or [])
    return record


def run_plant(
    seed: int, setting: str, starts: list[str], share: float, timeout: float,
    workdir: str | None,
) -> list[dict[str, Any]]:  # fmt: skip
    """Draw, write and identify one plant from each of ``starts``; one record per start.
    ``workdir``: where its data and logs go (None: a temporary folder, removed after)."""
    d = draw(seed, setting)
    base: dict[str, Any] = {
        "seed": seed, "setting": setting, "label": d.label, "draw_id": draw_id(d, share),
        "share": share, "draw": {k: v for k, v in d.summary().items() if k in DRAWN},
        "reversed_rods": int(d.site_reversed.sum()), "mass": float(d.mass.mean()),
        "stiffness": float(d.stiffness.mean()),
    }  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(workdir or tmp) / f"family{seed}_{setting}_{base['draw_id']}"
        no_data = None
        if not (folder / "measured.h5").exists():
            try:
                write_family_cell(d, folder, share)
            except RuntimeError as e:  # MuJoCo's step diverged: no data to identify
                no_data = {"status": "no data", "code": None, "seconds": 0.0,
                           "message": str(e), "command": ""}  # fmt: skip
        records = []
        for start in starts:
            rec = {**base, "start": start}
            rec.update({"identify": no_data} if no_data else identify(folder, start, timeout))
            rec["verdict"] = verdict(rec)
            records.append(rec)
    return records


def key(r: dict[str, Any]) -> tuple[int, str, str]:
    return (r["seed"], r["setting"], r["start"])


def todo(
    records: list[dict[str, Any]], seeds: list[int], settings: list[str], starts: list[str],
    share: float, rerun: bool,
) -> Iterator[tuple[int, str, list[str]]]:  # fmt: skip
    """(seed, setting, starts still to run): those without a record of the same draw."""
    done = {key(r): r.get("draw_id") for r in records}
    for seed in seeds:
        for setting in settings:
            want = draw_id(draw(seed, setting), share)
            missing = [s for s in starts if rerun or done.get((seed, setting, s)) != want]
            if missing:
                yield seed, setting, missing


def client_of(scheduler: str | None, workers: int) -> Any:
    """A Dask client: of the scheduler at ``scheduler``, else of a local cluster of
    ``workers`` single-threaded processes."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler)
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           memory_limit=0, dashboard_address=None)  # fmt: skip
    return Client(cluster)


def merged(records: list[dict[str, Any]], new: list[dict[str, Any]]) -> list[dict[str, Any]]:
    keys = {key(r) for r in new}
    return [r for r in records if key(r) not in keys] + new


def summary_lines(records: list[dict[str, Any]]) -> list[str]:
    """Per setting and start: how many records meet their invariants."""
    lines = []
    for setting in ("flight", "floor"):
        for start in STARTS:
            rs = [r for r in records if r["setting"] == setting and r["start"] == start]
            if rs:
                met = sum(not r["verdict"] for r in rs)
                line = f"- {setting}, from the {start}: {met} of {len(rs)} plants meet the invariants"
                if start != "truth":
                    near = sum(not at_the_truth(r) for r in rs)
                    line += (f"; {near} of {len(rs)} end where the data puts the truth (the truth's "
                             "own check: RMS / noise and the moves in standard errors)")  # fmt: skip
                    silent = sum(silently_wrong(r) for r in rs)
                    line += (f"; {silent} written with masses, inertias or stiffnesses off by more "
                             f"than {100 * STRUCTURE_TOL:g} % without identify's warning")  # fmt: skip
                    tried = [r for r in rs if r.get("two_starts", {}).get("tried")]
                    if tried:
                        apart = [r for r in tried if r["two_starts"]["apart"]]
                        within = sum(structure_error(r) <= STRUCTURE_TOL for r in apart)
                        line += (f"; the floor fit's two starts ended more than "
                                 f"{100 * STARTS_APART:g} % apart on {len(apart)} of {len(tried)} "
                                 f"(warned; {within} of those written within "
                                 f"{100 * STRUCTURE_TOL:g} %)")  # fmt: skip
                lines.append(line)
    return lines


def runs_lines(records: list[dict[str, Any]]) -> list[str]:
    """Per setting and start, the seeds measured (as ``--seeds`` takes them)."""
    lines = []
    for setting in ("flight", "floor"):
        for start in STARTS:
            seeds = sorted({r["seed"] for r in records
                            if r["setting"] == setting and r["start"] == start})  # fmt: skip
            if seeds:
                lines.append(f"- {setting}, from the {start}: seeds {spans_of(seeds)}")
    return lines


def spans_of(seeds: list[int]) -> str:
    """``[0, 1, 2, 5]`` -> ``"0-2,5"``."""
    parts, lo = [], seeds[0]
    for a, b in zip(seeds, [*seeds[1:], None], strict=True):
        if b != a + 1:
            parts.append(f"{lo}-{a}" if a > lo else f"{lo}")
            lo = b
    return ",".join(parts)


def write_markdown(records: list[dict[str, Any]], path: Path) -> None:
    """The table of ``records``, its summary and the misses, generated."""
    records = sorted(records, key=lambda r: (r["setting"], r["seed"], STARTS.index(r["start"])))
    for r in records:  # judged by the invariants as they are now
        r["verdict"] = verdict(r)
    shares = sorted({r.get("share", 1.0) for r in records})
    lines = [
        "# Drawn plants",
        "",
        "Plants drawn by `benchmarks/plant_family.py` (file conventions and physics at",
        "random), identified by `tensegrity-sr identify` on their end caps, from the true",
        "model (`--params true.xml`) or from the regression (`default`, anchored by the",
        "true first rod mass). RMS / noise: the fit's end-cap RMS over the plant's noise;",
        "moved: the RMS over all parameters of their moves from the truth in their stated",
        "standard errors (about 1 when they are honest; in brackets: the largest move,",
        "which grows like sqrt(2 ln N) with N honest ones, 2.9 for the 89 here);",
        "the group columns: the largest relative error (inertia: the perpendicular moments);",
        "contact: the floor contact's largest relative error (stiffness, damping,",
        "friction; those the data cannot pin are left out); se K / c: the median relative",
        "standard error the fit states for the stiffnesses and the spring damping (what the",
        "data determines them to); status: met or miss, \"(warned)\" where `identify` writes",
        "the fit with a warning: a mass, inertia, stiffness or rest length poorly",
        "determined, or the floor fit's two starts ending apart; starts: how far apart",
        "(the largest relative difference of a mass, inertia or stiffness; warned above",
        f"{100 * STARTS_APART:g} %; — where one start ran). Invariants: from the truth,",
        f"RMS / noise <= {RMS_OVER_NOISE:g} and the moves' RMS <= {MAX_SE_RMS:g} standard "
        "errors (the largest move is reported, not judged: \"none above 2\" fails most",
        "fits whose standard errors are honest);",
        f"from the default start, mass, inertia and stiffness within {100 * STRUCTURE_TOL:g} %,",
        f"damping and contact within {100 * DISSIPATION_TOL:g} %. Data: "
        + ", ".join(f"{s:g}" for s in shares)
        + " of the measured benchmark's trajectories per split. Seconds: wall time on 2",
        "shared cores (several plants at once). Each setting and start is measured with",
        "",
        "    OMP_NUM_THREADS=1 python benchmarks/bench_family.py --seeds SEEDS \\",
        "        --setting SETTING [--default-start] --share 0.25 --workers 2 [--rerun]",
        "",
        "(a rerun keeps the records of the same draw unless `--rerun`), the seeds being",
        "",
        *runs_lines(records),
        "",
        "and generated from `family.json` by `python benchmarks/bench_family.py --report-only`.",
        "",
        *summary_lines(records),
        "",
        "| plant | start | reversed rods | L [m] | M [kg] | K [N/m] | prestress | status | "
        "RMS / noise | moved [se] | mass | inertia | stiffness | damping | rest length "
        "| contact | se K / c | starts | seconds |",
        "|" + "---|" * 19,
    ]
    for r in records:
        w = r.get("worst", {})
        cells = [f"{100 * w[g]:.2f} %" if g in w else "—" for g in GROUPS]
        ratio = f"{r['rms_over_noise']:.3f}" if "rms_over_noise" in r else "—"
        moved = "—"
        if len(r.get("moved", [])) > 2 and r["moved"][0]:
            moved = f"{r['moved'][2]:.2f} ({r['moved'][1]:.2f})"
        contact = f"{100 * max(r['contact'].values()):.2f} %" if r.get("contact") else "—"
        status = ("met" if not r["verdict"] else "miss") + (" (warned)" if warned(r) else "")
        se = r.get("relative_se", {})
        se_cell = (f"{100 * se['stiffness']:.1f} / {100 * se['damping']:.1f} %"
                   if "stiffness" in se and "damping" in se else "—")  # fmt: skip
        two = r.get("two_starts", {})
        starts = f"{100 * two['largest_difference']['relative']:.1f} %" if two.get("tried") else "—"
        lines.append(
            f"| {r['label']} | {r['start']} | {r['reversed_rods']} | {r['draw']['length']:.2f} "
            f"| {r['mass']:.3g} | {r['stiffness']:.3g} | {r['draw']['prestress']:.2f} "
            f"| {status} | {ratio} | {moved} | " + " | ".join(cells)
            + f" | {contact} | {se_cell} | {starts} | {r['identify']['seconds']:.0f} |"
        )
    misses = [r for r in records if r["verdict"]]
    if misses:
        lines += ["", "## Misses", ""]
        lines += [f"- {r['label']} from the {r['start']}: {r['verdict']}" for r in misses]
    atomic_write_text(path, "\n".join(lines) + "\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-4", help="seeds, e.g. 0-4 or 1,3 (default 0-4)")
    ap.add_argument("--setting", nargs="+", choices=("flight", "floor"), default=["flight"])
    ap.add_argument("--default-start", action="store_true",
                    help="also identify from the regression (anchored by the true rod0 mass)")
    ap.add_argument("--share", type=float, default=1.0,
                    help="fraction of the measured benchmark's trajectories per split "
                         "(default 1)")  # fmt: skip
    ap.add_argument("--timeout", type=float, default=1800, help="seconds per command")
    ap.add_argument("--workdir", type=Path, help="where plant data and logs go (default: temp)")
    ap.add_argument("--scheduler", help="address of a running Dask scheduler (default: a "
                    "local cluster)")  # fmt: skip
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                    help="processes of the local cluster (default: one per core)")
    ap.add_argument("--rerun", action="store_true", help="replace records already there")
    ap.add_argument("--json", type=Path, default=ROOT / "docs/results/family.json")
    ap.add_argument("--md", type=Path, default=ROOT / "docs/results/family.md")
    ap.add_argument("--report-only", action="store_true", help="only regenerate --md")
    a = ap.parse_args()
    records = json.loads(a.json.read_text()) if a.json.exists() else []
    if not a.report_only:
        starts = list(STARTS) if a.default_start else ["truth"]
        jobs = list(todo(records, seeds_of(a.seeds), a.setting, starts, a.share, a.rerun))
        print(f"{len(jobs)} plants to run", flush=True)
        if jobs:
            from dask.distributed import as_completed

            client = client_of(a.scheduler, a.workers)
            workdir = str(a.workdir.resolve()) if a.workdir else None
            futures = [
                client.submit(run_plant, seed, setting, missing, a.share, a.timeout, workdir,
                              pure=False)
                for seed, setting, missing in jobs
            ]
            for fut in as_completed(futures):
                try:
                    new = fut.result()
                except Exception as e:  # left for the next run to redo
                    print(f"a plant failed to run: {type(e).__name__}: {e}", flush=True)
                    continue
                records = merged(records, new)
                atomic_write_text(a.json, json.dumps(records, indent=1) + "\n")
                write_markdown(records, a.md)
                for r in new:
                    print(f"{r['label']} from the {r['start']}: {r['identify']['status']} "
                          f"{r.get('rms_over_noise', float('nan')):.3f} x noise; "
                          f"{r['verdict'] or 'invariants met'}", flush=True)  # fmt: skip
            client.close()
    write_markdown(records, a.md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
