"""A drawn floor plant whose proportions are nothing like the measured benchmark's:
``identify`` from the exact true model stays at the noise.

``plant_family`` seed 9 on the floor: 1.9 m rods of 75 g, 104 N/m springs, sphere end
caps, body frames off the centre of mass and turned on three rods, the axial moment of
inertia 1-5 % of the perpendicular one; 60 Hz end caps with 0.13 mm of noise and 1.7 %
of the samples lost (NaN gaps); two training trajectories of 3 s (a quarter of the
benchmark's). The structure tumbles at up to 5 m/s: over 0.25-s windows (15 samples)
the states fitted from smoothing stop in other basins, so the floor fit chooses shorter
ones on the data.

Measured (``identify --params true.xml``): end-cap RMS 0.91 x the noise, masses within
0.1 %, stiffness 0.26 %, the moves from the truth 0.91 standard errors RMS.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from identification.data.dataset import read_ground_truth
from tensegrity_sr.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from family_invariants import MAX_SE_RMS, RMS_OVER_NOISE, largest_move, worst_errors
from plant_family import draw, write_family_cell

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    d = draw(9, "floor")
    return d, write_family_cell(d, tmp_path_factory.mktemp("family_floor"), share=0.25)


def test_identify_from_the_true_model_stays_at_the_noise(cell, tmp_path, capsys) -> None:
    d, data = cell
    out = tmp_path / "from_true.json"
    code = main(["identify", str(data.measured), "--params", str(data.measured.parent / "true.xml"),
                 "-o", str(out)])  # fmt: skip
    text = capsys.readouterr().out
    assert code == 0
    # the windows were shortened on the data, and the report says so
    steps = int(text.split("floor windows from the data: ")[1].split(" of ")[1].split()[0])
    assert steps < round(0.25 * d.rate)
    doc = json.loads(out.read_text())
    truth = read_ground_truth(data.measured).params.numpy()
    assert doc["provenance"]["end_cap_rms_m"] <= RMS_OVER_NOISE * d.noise
    assert doc["provenance"]["noise_level_m"] == pytest.approx(d.noise, rel=0.1)
    _, _, rms = largest_move(doc, truth)
    assert rms <= MAX_SE_RMS
    worst = worst_errors(doc["params"], truth)
    assert worst["mass"] < 0.01 and worst["stiffness"] < 0.01
    assert np.isfinite(list(worst.values())).all()
