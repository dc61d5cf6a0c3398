"""How well do a params file's standard errors tell a wrong fit from a right one?

For each params file written by ``identify`` on a plant with ground truth (the family
benchmark's ``--workdir`` holds one per plant and start: ``truth.json``,
``default.json``), prints the largest ratio of standard error to value among the
identified masses, inertias, stiffnesses and rest lengths (the ratio
:func:`identification.trajectory.stage_check.undetermined` judges against
``UNDETERMINED``), the largest relative error of the masses, inertias and stiffnesses
against the truth, the end-cap RMS over the noise level, and whether ``identify`` now
refuses the fit. The measurement behind ``UNDETERMINED`` in docs/decisions.md.

    python benchmarks/stderr_survey.py WORKDIR/family*/*.json
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from identification.linear.regression import ParameterRow
from identification.trajectory.stage_check import DETERMINED_GROUPS, undetermined

NAME = re.compile(r"(\w+)\[\D*(\d+)(?:,([xyz]))?\]")


def rows_of(doc: dict) -> list[ParameterRow]:
    """The identified rows of a params file's ``uncertainty`` (absolute standard errors)
    in :data:`DETERMINED_GROUPS`, with their values from ``params``."""
    p, rows = doc["params"], []
    for name, se in doc.get("uncertainty", {}).items():
        m = NAME.fullmatch(name)
        if not m or m[1] not in DETERMINED_GROUPS:
            continue
        value = p[m[1]][int(m[2])]
        value = value["xyz".index(m[3])] if m[3] else value
        rows.append(ParameterRow(name, m[1], int(m[2]), float(value), float(se), "", "identified"))
    return rows


def worst_ratio(doc: dict) -> tuple[str, float]:
    """The identified parameter of :func:`rows_of` with the largest standard error over
    its value, and that ratio (``("-", 0.0)`` where none states one)."""
    ratios = [(r.name, abs(r.stderr) / abs(r.value)) for r in rows_of(doc) if r.value]
    return max(ratios, key=lambda x: x[1], default=("-", 0.0))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", type=Path, help="params files written by identify")
    a = ap.parse_args()
    print("worst SE/value | parameter | worst error (M, I, K) | RMS/noise | refused | file")
    for f in a.files:
        doc = json.loads(f.read_text())
        if "params" not in doc or "relative_error_vs_ground_truth" not in doc:
            continue
        rows = rows_of(doc)
        name, worst = worst_ratio(doc)
        errs = [v for k, v in doc["relative_error_vs_ground_truth"].items()
                if k.startswith(("mass", "inertia", "stiffness"))]  # fmt: skip
        prov = doc["provenance"]
        rms = prov["end_cap_rms_m"] / prov["noise_level_m"]
        refused = "yes" if undetermined(rows) else "no"
        print(f"{worst:.3g} | {name} | {max(errs, default=float('nan')):.3g} | {rms:.3g} | "
              f"{refused} | {f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
