"""Regenerate the environments' assets: the MuJoCo twin and the identified params file.

    python -m tensegrity_sr.make_default_params [--work DIR] [--quick] [--out DIR]

writes, next to this script (or into ``--out``),

* ``icosahedron_rolling.xml``: the twin (:func:`tensegrity_env.envs.twin.twin_mjcf`);
* ``icosahedron_rolling_params.json``: what the identification pipeline makes of it,
  through the command line a user would type:

  1. ``tensegrity-sr generate --mjcf free.xml --control-std 1`` - the twin without its
     floor, random pushes ``f_u`` (so ``h`` is identifiable);
  2. ``tensegrity-sr identify free.h5 --anchor mass[rod0]=M0`` - K, c, l0, M, I, h by
     linear regression, rod 0 "weighed" to fix the scale;
  3. ``tensegrity-sr generate --mjcf icosahedron_rolling.xml --control-std 1`` - the
     twin dropped on its floor and pushed around;
  4. ``tensegrity-sr diagnose ground.h5 --params identified.json --candidates
     ground_contact`` - the residual loop names and fits the ground contact and
     writes the params file with its ``effects`` section.

Intermediate files go to ``--work`` (a temporary folder by default).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from tensegrity_env.envs.twin import twin_assembly, twin_mjcf
from tensegrity_env.io_utils import atomic_write_text
from tensegrity_sr.cli import main as cli

HERE = Path(__file__).resolve().parent.parent / "tensegrity_env" / "assets"
TWIN = HERE / "icosahedron_rolling.xml"
PARAMS = HERE / "icosahedron_rolling_params.json"


def run(argv: list[str]) -> None:
    print("$ tensegrity-sr " + " ".join(argv), flush=True)
    code = cli(argv)
    if code:
        raise SystemExit(code)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, help="folder for the datasets (default: temporary)")
    parser.add_argument(
        "--quick", action="store_true", help="smaller datasets (a check, not the asset)"
    )
    parser.add_argument("--out", type=Path, default=HERE, help="folder for the two assets")
    args = parser.parse_args(argv)
    twin_path, params_path = args.out / TWIN.name, args.out / PARAMS.name
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    work = args.work or Path(tempfile.mkdtemp(prefix="tensegrity_assets_"))
    work.mkdir(parents=True, exist_ok=True)
    n = ["--n-train", "4", "--n-val", "2", "--n-test", "2"] if args.quick else \
        ["--n-train", "16", "--n-val", "4", "--n-test", "4"]  # fmt: skip

    atomic_write_text(twin_path, twin_mjcf(ground=True))
    free_xml = work / "icosahedron_rolling_free.xml"
    atomic_write_text(free_xml, twin_mjcf(ground=False))
    mass0 = float(twin_assembly().params.mass[0])  # the rod a user would weigh

    free, ident = work / "free.h5", work / "identified.json"
    run(["generate", "--mjcf", str(free_xml), *n, "--steps", "1000", "--control-std", "1",
         "--seed", "0", "--no-progress", "-o", str(free)])  # fmt: skip
    run(["identify", str(free), "--anchor", f"mass[rod0]={mass0!r}", "-o", str(ident)])
    ground, diag = work / "ground.h5", work / "diagnose"
    run(["generate", "--mjcf", str(twin_path), *n, "--steps", "1000", "--control-std", "1",
         "--seed", "1", "--no-progress", "-o", str(ground)])  # fmt: skip
    run(["diagnose", str(ground), "--params", str(ident), "--candidates", "ground_contact",
         "--max-effects", "1", "-o", str(diag)])  # fmt: skip

    doc = json.loads((diag / "params.json").read_text())
    doc.setdefault("provenance", {})["environment_assets"] = {
        "script": "python -m tensegrity_sr.make_default_params",
        "twin": TWIN.name,
        "quick": bool(args.quick),
    }
    atomic_write_text(params_path, json.dumps(doc, indent=2) + "\n")
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)
    print(f"wrote {twin_path} and {params_path} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
