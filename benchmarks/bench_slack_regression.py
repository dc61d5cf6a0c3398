"""Which cables the segmented regression sees, cell by cell of the measured benchmark.

``diagnose`` proposes slack cables from a segmented regression on the smoothed end caps
(:mod:`identification.trajectory.slack_regression`); on the floor it uses the rods away
from the floor over the smoothing window and, for each rod leaning on it with one end cap,
its moments about the contact point (``leaning_rows``; ``--no-pivots``: the rods away from
it only), in free flight the samples away from any floor (all of them without one). This script writes a ``slack_cables`` cell of ``bench_measured.py`` with the
benchmark's own MuJoCo plant, runs that regression as ``diagnose`` does, and prints,
per spring, whether it is a true cable, the stiffness it loses in compression
(``loss``, 1 for a cable) and the significance of that loss, against the bars
``CABLE_LOSS`` and ``CABLE_SIGNIFICANCE``; then the fraction of rod equations used.

    python benchmarks/bench_slack_regression.py --setting floor --rate 120 --noise 1
    python benchmarks/bench_slack_regression.py --setting floor --no-pivots
    python benchmarks/bench_slack_regression.py --setting flight --smoothing 0.05
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np
from measured_plant import Cell, true_model, write_cell

from identification.data.dataset import read_dataset
from identification.data.end_caps import RodAxes, odd_window, smooth_rod_states
from identification.trajectory.airborne import airborne_samples, contact_gate
from identification.trajectory.floor_fit import rods_leaning, rods_off_floor
from identification.trajectory.slack_regression import (
    CABLE_LOSS,
    CABLE_SIGNIFICANCE,
    slack_regression,
)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--setting", choices=("floor", "flight"), default="floor")
    ap.add_argument("--rate", type=float, default=120.0, help="sample rate [Hz] (default 120)")
    ap.add_argument("--noise", type=float, default=1.0, help="end-cap noise std [mm] (default 1)")
    ap.add_argument("--seed", type=int, default=0, help="cell seed (default 0)")
    ap.add_argument("--smoothing", type=float, default=0.1,
                    help="Savitzky-Golay window [s] (default 0.1, diagnose's)")  # fmt: skip
    ap.add_argument("--no-pivots", action="store_true",
                    help="on the floor, only the rods away from it (no moment equations about "
                         "a contact point)")  # fmt: skip
    args = ap.parse_args()
    cell = Cell(args.setting, args.rate, args.noise * 1e-3, 0.0, "slack_cables", args.seed)
    with tempfile.TemporaryDirectory(prefix="bench_slack_") as work:
        data = write_cell(cell, Path(work))
        ds = read_dataset(data.measured)
    train, topo = ds.split("train"), ds.topology
    span = odd_window(args.smoothing / ds.dt)
    smooth = smooth_rod_states(train.nodes, ds.dt, RodAxes.of(topo), span)
    anchors = {"mass[rod0]": float(data.truth.params.mass[0])}
    if args.setting == "floor":
        rows = {"rod_keep": rods_off_floor(train.nodes, topo, span)}
        used = float(rows["rod_keep"].mean())
        if not args.no_pivots:
            rows |= {"pivots": rods_leaning(train.nodes, topo, span),
                     "radius": np.array([r.radius for r in topo.rods])}  # fmt: skip
            used += 0.5 * float((rows["pivots"] >= 0).mean())
    elif contact_gate(train, topo)[0]:
        rows = {"keep": airborne_samples(train.nodes, topo, span)}
        used = float(rows["keep"].mean())
    else:
        rows, used = {}, 1.0
    reg = slack_regression(topo, smooth, train.control, anchors, **rows)
    cables = next(e["params"]["springs"] for e in true_model(cell).effects if e["name"] == "slack_springs")
    print(f"{cell.label}: smoothing {args.smoothing} s ({span} samples); rod equations used: {100 * used:.1f} %")
    print(f"a cable: loss >= {CABLE_LOSS} with significance >= {CABLE_SIGNIFICANCE}")
    print("spring  true   loss   significance  named")
    named = set(reg.cables())
    for i in range(topo.n_springs):
        print(f"{i:6d}  {'cable' if i in cables else 'spring':6s} {reg.loss[i]:6.3f} {reg.significance[i]:10.2f}"
              f"     {'yes' if i in named else ''}")  # fmt: skip
    hit = len(named & set(cables))
    print(f"named {len(named)}: {hit} of {len(cables)} cables, {len(named) - hit} springs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
