"""The declared model and ground contact from a robot that never leaves the floor
(identification.trajectory.floor_fit, identification.trajectory.floor_declared).

The icosahedron of ``benchmarks/measured_plant.py`` tumbling and rolling on a floor
(MuJoCo's default soft contact, friction 1), 120 Hz end caps with 1 mm noise; no
stretch of the data is airborne. Seed 1: the floor fit was developed on seed 0.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from identification.data.dataset import read_dataset, read_ground_truth
from identification.trajectory.airborne import has_airborne_stretch
from identification.trajectory.end_cap_data import TrajectorySettings
from identification.trajectory.floor_declared import identify_on_floor, on_floor
from tensegrity_env.effects.ground_contact import MUJOCO_DEFAULT

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from measured_plant import Cell, write_cell

#: 5-15 minutes on one core: run with `pytest -m slow tests/accuracy/test_floor_identification.py`
pytestmark = [pytest.mark.usefixtures("one_torch_thread"), pytest.mark.slow]


@pytest.fixture(scope="module")
def floor_fit(tmp_path_factory):
    folder = tmp_path_factory.mktemp("floor")
    data = write_cell(Cell("floor", 120.0, 1e-3, 0.0, "none", seed=1), folder)
    ds = read_dataset(data.measured)
    truth = read_ground_truth(data.measured)
    assert truth is not None
    anchors = {"mass[rod0]": float(truth.params.mass[0])}
    settings = TrajectorySettings(anchors=anchors, fit_window=25, floor_windows=8)
    return ds, truth, identify_on_floor(ds, settings, log=lambda line: None)


def test_floor_data_has_no_airborne_stretch(floor_fit):
    ds, _, _ = floor_fit
    assert not has_airborne_stretch(ds.split("train").nodes, ds.topology)
    assert on_floor(ds)


def test_declared_model_and_contact_from_floor_data_alone(floor_fit):
    """Tolerances about twice as measured (8 windows of 25 steps): masses within 2.8 %,
    stiffness 1.0 % (median), rest lengths 0.1 % (median), end-cap RMS 1.35 mm (1 mm
    noise), friction 0.9995, contact stiffness 1 % off; far from the airborne fits' 0.1 %.

    On the floor the contact is parametrised per unit effective mass, so it carries the
    weight whatever the masses' scale: the masses follow only from their ratios to the
    anchored rod (the floor fit searches that common scale).
    """
    _, truth, est = floor_fit
    p, t = est.params_, truth.params

    def rel(a, b):
        return np.abs(a.detach().numpy() / b.detach().numpy() - 1)

    c = est.contact_
    errors = {
        "rms_mm": est.rms_ * 1e3,
        "mass_max": rel(p.mass, t.mass).max(),
        "stiffness_median": np.median(rel(p.stiffness, t.stiffness)),
        "rest_length_median": np.median(rel(p.rest_length, t.rest_length)),
        "contact": {k: float(c.values[k]) for k in ("stiffness", "damping", "friction", "height")},
    }
    assert est.rms_ < 2e-3, errors  # 1 mm noise
    assert errors["mass_max"] < 0.05, errors
    assert errors["stiffness_median"] < 0.02, errors
    assert errors["rest_length_median"] < 0.003, errors
    assert abs(errors["contact"]["friction"] - 1.0) < 0.02, errors
    assert abs(errors["contact"]["stiffness"] / MUJOCO_DEFAULT["stiffness"] - 1) < 0.05, errors
    assert abs(errors["contact"]["height"]) < 3e-3, errors  # the floor at z = 0
    assert c.physical()
