"""A real take's floor fit from each first window length alone, judged by held-out prediction.

Where no window length's state fit reaches the markers' noise, the floor fit tries every
length near the best (``windows_from_data``) and keeps the one whose model fits the
validation windows' states best (``first_floor_fit``). This script measures that choice
against the benchmark's own yardstick: for each length the data offers, ``identify`` runs
with the floor fit's first windows restricted to that length alone (the count the data
gives it), and the model is scored as ``bench_real.py`` scores it (open-loop end-cap RMS
from measured states on the held-out pieces at 0.1, 0.25, 0.5 and 1 s; rest shape).

    OMP_NUM_THREADS=1 python benchmarks/floor_window_lengths.py --data ../shared/real \\
        --take eth_T2_drop --workdir W

Prints one row per length and writes ``W/lengths.json``; skips with a message without
the data folder.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_real import TAKES, evaluate  # noqa: E402

#: the window lengths [steps] the floor fit may start from (its halvings of 0.25 s at 120 Hz)
LENGTHS = (4, 8, 15, 30)


def restricted(steps: int, argv: list[str]) -> int:
    """The command line ``argv`` with the floor fit's first windows of ``steps`` alone."""
    import identification.trajectory.floor_declared as fd
    from tensegrity_sr.cli import main

    every = fd.windows_from_data

    def only(data, vec, longest, count, noise):
        choices, why = every(data, vec, longest, count, noise)
        kept = [c for c in choices if c[0] == steps] or [(steps, count)]
        return kept, f"{why} (restricted to {steps} steps)"

    fd.windows_from_data = only
    return int(main(argv) or 0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--data", type=Path, default=ROOT.parent / "shared/real", help="the real recordings' folder"
    )
    ap.add_argument("--take", default="eth_T2_drop", choices=sorted(TAKES))
    ap.add_argument(
        "--lengths", default=",".join(map(str, LENGTHS)), help="first window lengths [steps]"
    )
    ap.add_argument("--workdir", type=Path, required=True)
    ap.add_argument("--only", type=int, help=argparse.SUPPRESS)  # the child process
    args, command = ap.parse_known_args(argv)
    if args.only is not None:
        return restricted(args.only, command)
    if not args.data.is_dir():
        print(f"skipped: no real recordings at {args.data}")
        return 0
    file, robot = (args.data / p for p in TAKES[args.take][:2])
    work = args.workdir / args.take
    work.mkdir(parents=True, exist_ok=True)
    h5 = work / "take.h5"
    cli = [sys.executable, "-m", "tensegrity_sr.cli"]
    if not h5.is_file():
        subprocess.run([*cli, "import-mocap", str(file), "--robot", str(robot), "-o", str(h5),
                        *TAKES[args.take][2]], check=True, capture_output=True)  # fmt: skip
    rows: dict[str, Any] = {}
    for steps in (int(x) for x in args.lengths.split(",")):
        folder = work / f"first_{steps}"
        folder.mkdir(exist_ok=True)
        with open(folder / "identify.log", "w") as log:
            code = subprocess.run([sys.executable, __file__, "--workdir", str(args.workdir), "--only",
                                   str(steps), "identify", str(h5), "--params", str(robot), "-o",
                                   str(folder / "identified.json"), "--force"],
                                  stdout=log, stderr=subprocess.STDOUT).returncode  # fmt: skip
        rec: dict[str, Any] = {
            "file": TAKES[args.take][0],
            "robot": TAKES[args.take][1],
            "runs": {},
        }
        rec = evaluate(rec, h5, folder, robot) if code == 0 else {"identify_exit": code}
        rows[str(steps)] = {
            "heldout": rec.get("heldout"),
            "rest_shape_rms_m": rec.get("rest_shape_rms_m"),
        }
        held = (rec.get("heldout") or {}).get("identified_rms_m")
        rest = (rec.get("rest_shape_rms_m") or {}).get("identified")
        said = " ".join(f"{100 * x:.2f}" for x in held) if held else f"identify exit {code}"
        shape = f"; rest shape {1e3 * rest:.2f} mm" if rest is not None else ""
        print(
            f"first windows of {steps} steps: held-out [cm] at 0.1/0.25/0.5/1 s {said}{shape}",
            flush=True,
        )
    (work / "lengths.json").write_text(json.dumps(rows, indent=1) + "\n")
    print(f"wrote {work / 'lengths.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
