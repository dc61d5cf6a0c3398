"""Later fits on the floor keep the contact within range of the floor fit's values
(identification.trajectory.floor_fit.contact_box): a step leaving the range is cut at
its edge.

The plant is ``benchmarks/measured_plant.py``'s icosahedron rolling on MuJoCo's soft
floor; end caps from its clean rod states, windows started at the true states, the
declared parameters true and held. The contact starts with a stiffness ten times too
low and its range around that start: the fit would take the stiffness back to the
truth, but stops at the range's edge.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from identification.trajectory.floor_fit import FLOOR_FREE, contact_box, with_floor
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
from identification.trajectory.windows import STATE_KEYS, cut_windows
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import GroundContact
from tensegrity_env.engine import Engine, substeps_for

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from measured_plant import clean_rolling

pytestmark = [pytest.mark.usefixtures("one_torch_thread"), pytest.mark.slow]

STEPS = 30  # 0.25 s at 120 Hz, the floor fit's window


def test_contact_stays_within_its_range_of_the_start() -> None:
    truth, clean = clean_rolling(seed=3)
    topo = icosahedron().topology
    grid = {k: getattr(clean, k) for k in STATE_KEYS}
    windows = cut_windows(clean.nodes, clean.control, grid, STEPS)
    true = GroundContact(topo, friction=1.0, height=0.0)  # MuJoCo's default floor
    k_true = float(true.values["stiffness"])
    start = true.with_values(stiffness=k_true / 10)
    box = contact_box(start)
    held = ParamVector.at(topo, truth.params)
    held = replace(held, free=torch.zeros_like(held.free))
    vec = with_floor(held, [], start, None, box)
    engine = Engine(topo, 1 / 120, substeps=substeps_for(1 / 120))
    done = fit(WindowedProblem(engine, vec, windows), FitOptions(max_iter=4, line_search=True))
    lo, hi = (np.array([box[k][i] for k in FLOOR_FREE]) for i in (0, 1))
    x = done.theta[vec.n_free :].numpy()
    assert np.all(x >= lo - 1e-12) and np.all(x <= hi + 1e-12), (x, lo, hi)
    stiffness = float(np.exp(x[FLOOR_FREE.index("stiffness")]))
    assert stiffness > k_true / 10  # it moved towards the truth ...
    edge = float(np.exp(hi[FLOOR_FREE.index("stiffness")]))
    assert stiffness <= edge * (1 + 1e-9) < k_true  # ... not past the range
    assert done.history[-1] < done.history[0], done.history
