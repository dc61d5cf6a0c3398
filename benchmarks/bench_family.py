"""Drawn plants (``benchmarks/plant_family.py``) identified as a user would.

For each seed a plant is drawn (file conventions and physics at random), its MJCF and
data written, and ``tensegrity-sr identify`` run on the end caps from the true model
(``--params true.xml``) and, with ``--default-start``, from the regression (anchored by
the true first rod mass). Each record holds the draw, the command's status, the end-cap
RMS against the plant's noise and the largest relative error per parameter group.

Results go to ``docs/results/family.json`` (one record per seed and start; a rerun
replaces it) and ``docs/results/family.md`` is generated from it.

    OMP_NUM_THREADS=1 python benchmarks/bench_family.py --seeds 0-4
    python benchmarks/bench_family.py --seeds 0-4 --setting floor --default-start
    python benchmarks/bench_family.py --report-only
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench_measured import run_cli
from plant_family import draw, write_family_cell

from identification.data.dataset import read_ground_truth
from tensegrity_env.io_utils import atomic_write_text

ROOT = Path(__file__).resolve().parent.parent
GROUPS = ("mass", "inertia", "stiffness", "damping", "rest_length")
#: the draw's fields a record keeps
DRAWN = ("rate", "noise", "dropout", "length", "prestress", "end_cap", "friction")


def seeds_of(text: str) -> list[int]:
    """``"0-4"`` or ``"1,3,7"`` -> seeds."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def worst_errors(params: dict[str, Any], truth: dict[str, np.ndarray]) -> dict[str, float]:
    """Largest relative error per group; inertia: the perpendicular moments only."""
    out = {}
    for g in GROUPS:
        got, want = np.asarray(params[g], float), np.asarray(truth[g], float)
        if g == "inertia":  # the axial moment is assumed, not identified
            keep = want > want.min(axis=1, keepdims=True) * (1 + 1e-9)
            got, want = got[keep], want[keep]
        out[g] = float(np.max(np.abs(got / want - 1)))
    return out


def run_seed(seed: int, setting: str, start: str, work: Path, timeout: float) -> dict[str, Any]:
    """Draw, write and identify one plant from ``start`` (``truth`` or ``default``)."""
    d = draw(seed, setting)
    folder = work / f"family{seed}_{setting}"
    record: dict[str, Any] = {
        "seed": seed, "setting": setting, "start": start, "label": d.label,
        "draw": {k: v for k, v in d.summary().items() if k in DRAWN},
        "reversed_rods": int(d.site_reversed.sum()), "mass": float(d.mass.mean()),
        "stiffness": float(d.stiffness.mean()),
    }  # fmt: skip
    if not (folder / "measured.h5").exists():
        try:
            write_family_cell(d, folder)
        except RuntimeError as e:  # MuJoCo's step diverged: no data to identify
            record["identify"] = {"status": "no data", "code": None, "seconds": 0.0,
                                  "message": f"the plant: {e}", "command": ""}  # fmt: skip
            return record
    gt = read_ground_truth(folder / "measured.h5")
    assert gt is not None
    t = gt.params
    out = folder / f"{start}.json"
    out.unlink(missing_ok=True)
    args = ["identify", "measured.h5", "-o", out.name]
    args += (["--params", "true.xml"] if start == "truth"
             else ["--anchor", f"mass[rod0]={float(t.mass[0])!r}"])  # fmt: skip
    run = run_cli(args, folder, f"{start}.log", timeout)
    record["identify"] = run
    if run["status"] == "ok":
        doc = json.loads(out.read_text())
        prov = doc["provenance"]
        record["end_cap_rms_m"] = prov["end_cap_rms_m"]
        record["rms_over_noise"] = prov["end_cap_rms_m"] / d.noise
        record["worst"] = worst_errors(doc["params"], t.numpy())
    return record


def write_markdown(records: list[dict[str, Any]], path: Path) -> None:
    """The table of ``records``, generated."""
    lines = [
        "# Drawn plants",
        "",
        "Plants drawn by `benchmarks/plant_family.py` (file conventions and physics at",
        "random), identified by `tensegrity-sr identify` on their end caps, from the true",
        "model (`--params true.xml`) or from the regression (`default`, anchored by the",
        "true first rod mass). RMS / noise: the fit's end-cap RMS over the plant's noise;",
        "the group columns: the largest relative error (inertia: the perpendicular",
        "moments). Seconds: wall time on 2 shared cores. Measured with",
        "`OMP_NUM_THREADS=1 python benchmarks/bench_family.py --seeds 0-4` (add",
        "`--default-start`, `--setting floor`); generated from `family.json` by",
        "`python benchmarks/bench_family.py --report-only`.",
        "",
        "| plant | start | reversed rods | L [m] | M [kg] | K [N/m] | prestress | status | "
        "RMS / noise | mass | inertia | stiffness | damping | rest length | seconds |",
        "|" + "---|" * 15,
    ]
    for r in sorted(records, key=lambda r: (r["setting"], r["seed"], r["start"])):
        w = r.get("worst", {})
        cells = [f"{100 * w[g]:.2f} %" if g in w else "—" for g in GROUPS]
        ratio = f"{r['rms_over_noise']:.3f}" if "rms_over_noise" in r else "—"
        status = r["identify"]["status"]
        if status != "ok":
            status += f": {r['identify']['message'][:80]}"
        lines.append(
            f"| {r['label']} | {r['start']} | {r['reversed_rods']} | {r['draw']['length']:.2f} "
            f"| {r['mass']:.3g} | {r['stiffness']:.3g} | {r['draw']['prestress']:.2f} "
            f"| {status} | {ratio} | " + " | ".join(cells)
            + f" | {r['identify']['seconds']:.0f} |"
        )
    atomic_write_text(path, "\n".join(lines) + "\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-4", help="seeds, e.g. 0-4 or 1,3 (default 0-4)")
    ap.add_argument("--setting", choices=("flight", "floor"), default="flight")
    ap.add_argument("--default-start", action="store_true",
                    help="also identify from the regression (anchored by the true rod0 mass)")
    ap.add_argument("--timeout", type=float, default=1800, help="seconds per command")
    ap.add_argument("--workdir", type=Path, help="where plant data and logs go (default: temp)")
    ap.add_argument("--json", type=Path, default=ROOT / "docs/results/family.json")
    ap.add_argument("--md", type=Path, default=ROOT / "docs/results/family.md")
    ap.add_argument("--report-only", action="store_true", help="only regenerate --md")
    a = ap.parse_args()
    records = json.loads(a.json.read_text()) if a.json.exists() else []
    if not a.report_only:
        starts = ["truth", "default"] if a.default_start else ["truth"]
        with tempfile.TemporaryDirectory() as tmp:
            work = a.workdir or Path(tmp)
            for seed in seeds_of(a.seeds):
                for start in starts:
                    rec = run_seed(seed, a.setting, start, work, a.timeout)
                    key = (rec["seed"], rec["setting"], rec["start"])
                    records = [r for r in records
                               if (r["seed"], r["setting"], r["start"]) != key] + [rec]  # fmt: skip
                    atomic_write_text(a.json, json.dumps(records, indent=1) + "\n")
                    print(f"{rec['label']} from {start}: {rec['identify']['status']} "
                          f"{rec.get('rms_over_noise', float('nan')):.3f} x noise")  # fmt: skip
    write_markdown(records, a.md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
