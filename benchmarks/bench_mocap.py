"""Labelling unlabelled motion capture: mislabels and precision of an import.

Writes unlabelled C3D exports of the icosahedron from MuJoCo runs (its own runs of
the twin MJCF, not the dataset generator): 120 Hz, 1 mm marker noise, 2 % dropouts
(runs of 1-6 frames, a new track id at every reappearance), ghost points in 5 % of
frames, ``--takes`` takes of ``--duration`` s. Imports them with
``tensegrity-sr import-mocap`` as a user would and compares, frame by frame, every
imported end cap with the point written for it.

    python benchmarks/bench_mocap.py --takes 8 --duration 3 --seed 100
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from identification.data.dataset import read_dataset
from identification.data.mocap.c3d_files import write_c3d
from identification.simulation.mocap_takes import record_take, simulate_caps

ROBOT = Path(__file__).resolve().parents[1] / "tensegrity_env" / "assets" / "icosahedron_rolling.xml"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--takes", type=int, default=8)
    ap.add_argument("--duration", type=float, default=3.0, help="seconds per take")
    ap.add_argument("--rate", type=float, default=120.0, help="capture rate [Hz]")
    ap.add_argument("--noise", type=float, default=1e-3, help="marker noise std [m]")
    ap.add_argument("--dropout", type=float, default=0.02, help="fraction of samples lost")
    ap.add_argument("--seed", type=int, default=100)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        files, takes = [], []
        for k in range(args.takes):
            t, caps, names = simulate_caps(ROBOT.read_text(), args.rate, args.duration, rng)
            take = record_take(t, caps, names, rng, noise=args.noise, dropout=args.dropout,
                               unlabelled=True, ghosts=0.05)  # fmt: skip
            path = Path(tmp) / f"take{k}.c3d"
            write_c3d(path, take.points, take.names, args.rate)
            files.append(path)
            takes.append(take)
        out = Path(tmp) / "data.h5"
        t0 = time.perf_counter()
        r = subprocess.run(
            [sys.executable, "-m", "tensegrity_sr.cli", "import-mocap", *map(str, files),
             "--robot", str(ROBOT), "--split", "0.75,0.125,0.125", "-o", str(out)],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        wall = time.perf_counter() - t0
        print(r.stdout.strip() or r.stderr.strip())
        if r.returncode:
            return r.returncode
        ds = read_dataset(out)
        imported = [tr for s in ("train", "val", "test") if s in ds.splits for tr in ds.splits[s].nodes]
        mislabels = missed = invented = 0
        worst = 0.0
        for take, nodes in zip(takes, imported, strict=True):
            F, C = take.caps.shape[:2]
            written = np.full((F, C, 3), np.nan)
            for j, c in enumerate(take.cap_of_track):
                if c >= 0:
                    here = np.isfinite(take.points[:, j]).all(-1)
                    written[here, c] = take.points[here, j]
            seen_w, seen_i = np.isfinite(written).all(-1), np.isfinite(nodes[:F]).all(-1)
            missed += int((seen_w & ~seen_i).sum())
            invented += int((~seen_w & seen_i).sum())
            both = seen_w & seen_i
            err = np.linalg.norm(nodes[:F][both] - written[both], axis=-1)
            mislabels += int((err > 1e-3).sum())
            worst = max(worst, float(err.max()))
        n = sum(int(np.isfinite(t.caps).all(-1).sum()) for t in takes)
        print(f"takes {args.takes} x {args.duration:g} s at {args.rate:g} Hz, {n} end-cap samples")
        print(f"mislabels {mislabels}, seen caps not recovered {missed}, caps invented {invented}")
        print(f"largest |imported - written| over matched samples: {worst:.3g} m (C3D float32)")
        print(f"import-mocap wall time {wall:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
