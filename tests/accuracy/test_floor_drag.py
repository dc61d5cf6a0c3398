"""Linear drag on a robot tumbling on the floor, fitted with the declared model and the
contact (identification.discovery.floor_fits).

The icosahedron of ``benchmarks/measured_plant.py`` (MuJoCo's default soft contact,
friction 1, fluid viscosity 0.5 Pa*s), 120 Hz end caps with 1 mm noise. Each training
trajectory flies 0.04-0.2 s before it lands: half the floor windows start there, where
the drag acts apart from the contact. Seed 2: the window choice was developed on seed 0.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from identification.data.dataset import read_dataset, read_ground_truth
from identification.discovery.end_cap_data import EndCapData, TrajectorySettings
from identification.discovery.floor_fits import fit_declared_on_floor
from tensegrity_env.effects import ImplicitLinearDrag
from tensegrity_env.effects.ground_contact import MUJOCO_DEFAULT

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from measured_plant import VISCOSITY, Cell, write_cell

#: about 10 minutes on one core: `pytest -m slow tests/accuracy/test_floor_drag.py`
pytestmark = [pytest.mark.usefixtures("one_torch_thread"), pytest.mark.slow]


def _mujoco_viscous_drag(mass: np.ndarray, inertia: np.ndarray) -> tuple[float, float]:
    """MuJoCo's inertia-box Stokes drag of a body: ``3 pi mu d`` [N*s/m] and ``pi mu d^3``
    [N*m*s], ``d`` the mean side of the box with the body's mass and principal inertia."""
    i = np.asarray(inertia)
    box = np.sqrt(6.0 * (i.sum() - 2.0 * i) / mass)  # sides of the equivalent box
    d = box.mean()
    return 3 * np.pi * VISCOSITY * d, np.pi * VISCOSITY * d**3


def test_linear_drag_and_contact_from_a_robot_on_the_floor(tmp_path) -> None:
    """Measured (seed 2): see the assertion messages; tolerances about twice as measured."""
    data_files = write_cell(Cell("floor", 120.0, 1e-3, 0.0, "linear_drag", seed=2), tmp_path)
    ds = read_dataset(data_files.measured)
    truth = read_ground_truth(data_files.measured)
    assert truth is not None
    t = truth.params
    b_true, beta_true = _mujoco_viscous_drag(float(t.mass[0]), t.inertia[0].numpy())
    s = TrajectorySettings(anchors={"mass[rod0]": float(t.mass[0])}, window=24, fit_window=36)
    data = EndCapData(ds, s)
    many, _ = fit_declared_on_floor(data, s, effects=[ImplicitLinearDrag(ds.topology)],
                                    selection=False)  # fmt: skip
    p = many.params
    drag = next(e for e in many.effects if e.name == "linear_drag")
    contact = many.effects[-1]
    b = drag.values["translational"].numpy()
    beta = drag.values["rotational"].numpy()[:2]  # about the rod axis: least seen
    errors = {
        "rms_mm": many.rms * 1e3,
        "mass": float(np.abs(p.mass.numpy() / t.mass.numpy() - 1).max()),
        "stiffness": float(np.abs(p.stiffness.numpy() / t.stiffness.numpy() - 1).max()),
        "drag": (b / b_true - 1).round(3).tolist(),
        "rotational": (beta / beta_true - 1).round(3).tolist(),
        "contact_stiffness": float(contact.values["stiffness"]) / MUJOCO_DEFAULT["stiffness"] - 1,
    }
    assert many.rms < 1.3e-3, errors  # 1 mm noise
    assert errors["mass"] < 0.03, errors
    assert errors["stiffness"] < 0.06, errors
    assert np.all(np.abs(b / b_true - 1) < 0.2), errors
    assert np.all(np.abs(beta / beta_true - 1) < 0.3), errors
    assert abs(errors["contact_stiffness"]) < 0.2, errors
