"""Ground contact from the touchdowns of noisy end caps (identification.trajectory.touchdown).

MuJoCo data with a floor the identifier is not told about (friction 1, MuJoCo's default
soft contact), end caps only, 1 mm noise; the declared model is the true one (a prior
calibration). Seed 5: the bench was tuned on seed 0.
"""

import numpy as np
import pytest

from identification.data.end_caps import RodAxes, odd_window, smooth_rod_states
from identification.experiments.drop_check import DROP_TOLERANCE, drop_check
from identification.simulation.planted import PlantSpec
from identification.trajectory.effect_coords import CONTACT_START
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.touchdown import TOUCH, find_touchdowns, search_contact
from identification.trajectory.windows import STATE_KEYS
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.ground_contact import MUJOCO_DEFAULT
from tensegrity_env.engine import Engine

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def touchdowns(mujoco_data):
    data = mujoco_data.planted(PlantSpec("ground_contact", "moderate", noise=1e-3, seed=5, n_train=6,
                                     n_val=0, n_test=0, steps=500))  # fmt: skip
    ds, split = data.dataset, data.dataset.split("train")
    topo = ds.topology
    vec = ParamVector.at(topo, data.ground_truth.params)
    smooth = smooth_rod_states(split.nodes, ds.dt, RodAxes.of(topo), odd_window(0.1 / ds.dt))
    grid = {k: getattr(smooth, k) for k in STATE_KEYS}
    radius = np.repeat([r.radius for r in topo.rods], 2)
    engine = Engine(topo, ds.dt, native=True)  # as the contact search builds it
    touch = find_touchdowns(engine, vec, split.nodes, split.control, grid, radius)
    return data, engine, vec, touch, radius, split


def test_touchdowns_are_the_first_impacts_and_airborne_states_fit_to_the_noise(touchdowns):
    data, _, _, touch, radius, _ = touchdowns
    assert touch is not None and touch.size == 6  # every trajectory starts in the air
    clean = data.clean.split("train").nodes
    for i, t in zip(touch.traj, touch.first, strict=True):
        gap = clean[i, :, :, 2] - radius
        assert gap[: t - 3].min() > 0  # nothing touched before (clean data: the truth)
        assert gap[t].min() < TOUCH + 5e-3
    assert 0.9e-3 < touch.prefix_rms < 1.1e-3  # 1 mm noise: the free fall is fitted


@pytest.fixture(scope="module")
def searched(touchdowns):
    data, engine, vec, touch, _, _ = touchdowns
    start = GroundContact(data.dataset.topology, **CONTACT_START)
    return search_contact(engine, vec.params(vec.start), [], start, touch, horizons=(60, 150))


def test_contact_from_noisy_touchdowns_is_good_enough_for_a_2s_drop(touchdowns, searched):
    data = touchdowns[0]
    c = searched.contact
    drop = drop_check(data.ground_truth.params, [c])
    assert drop.lowest < 0.0 and drop.worst < DROP_TOLERANCE
    for key, rel in (("stiffness", 0.05), ("damping", 0.05), ("friction", 0.02)):
        value, true = float(c.values[key]), MUJOCO_DEFAULT[key]
        assert abs(value - true) < rel * true, (key, value)
    assert abs(float(c.values["impedance"]) - MUJOCO_DEFAULT["impedance"]) < 0.01
    assert searched.rms[150] < 1.2e-3  # the noise, 150 steps after each touchdown


def test_searched_contact_uncertainty_covers_its_error(searched):
    c = searched.contact
    for key in ("stiffness", "damping", "friction", "impedance"):
        value, true = float(c.values[key]), MUJOCO_DEFAULT[key]
        assert 0 < c.uncertainty[key] < 0.1 * true, key  # stated, and not vacuous
        assert abs(value - true) < 3 * c.uncertainty[key], (key, value, c.uncertainty[key])
