"""The declared model from the airborne stretches of floor data (identification.trajectory.airborne).

MuJoCo drops onto a floor the identifier is not told about, end caps only, 1 mm noise.
Each airborne stretch is fitted whole (one window, ``Windows.valid`` masking the rest of
the batch). Seed 5: the bench was tuned on seed 0.
"""

import numpy as np
import pytest
import torch

from identification.data.end_caps import RodAxes, odd_window, smooth_rod_states
from identification.experiments.drop_check import DROP_TOLERANCE, drop_check
from identification.simulation.planted import PlantSpec
from identification.trajectory.airborne import (
    AIRBORNE,
    airborne_stretches,
    cap_radii,
    past_touchdown,
)
from identification.trajectory.end_cap_data import EndCapData, TrajectorySettings
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.presets import fit_declared
from identification.trajectory.window_errors import window_sse
from identification.trajectory.windows import STATE_KEYS, local_basis
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.ground_contact import MUJOCO_DEFAULT
from tensegrity_env.engine import Engine

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def floor(mujoco_data):
    return mujoco_data.planted(PlantSpec("ground_contact", "moderate", noise=1e-3, seed=5, n_train=6,
                                     n_val=1, n_test=1, steps=500))  # fmt: skip


@pytest.fixture(scope="module")
def stretches(floor):
    ds, split = floor.dataset, floor.dataset.split("train")
    smooth = smooth_rod_states(split.nodes, ds.dt, RodAxes.of(ds.topology), odd_window(0.1 / ds.dt))
    grid = {k: getattr(smooth, k) for k in STATE_KEYS}
    return airborne_stretches(split.nodes, split.control, grid, ds.topology)


def test_stretches_are_airborne_and_end_at_the_touchdown(floor, stretches):
    topo = floor.dataset.topology
    clean = floor.clean.split("train").nodes
    gap = clean[..., 2] - cap_radii(topo)  # (N, T+1, 2R) [m], the truth
    assert stretches is not None and 0 in stretches.start  # drops start in the air
    for b in range(stretches.size):
        i, a = stretches.traj[b], stretches.start[b]
        n = int(stretches.valid[b].sum()) - 1  # steps of this stretch
        assert gap[i, a : a + n + 1].min() > 0  # nothing touches inside it
        assert gap[i, a + n + 1 : a + n + 20].min() < AIRBORNE + 4e-3  # it ends at a touch
        assert np.allclose(stretches.obs[b, : n + 1].numpy(), floor.dataset.split("train")
                           .nodes[i, a : a + n + 1])  # fmt: skip


def test_stretches_run_on_past_the_touchdown_where_the_data_allows(floor, stretches):
    nodes = floor.dataset.split("train").nodes
    T = nodes.shape[1] - 1
    longer = past_touchdown(stretches, nodes, 150)
    for b in range(stretches.size):
        i, a = stretches.traj[b], stretches.start[b]
        n = min(int(stretches.valid[b].sum()) - 1 + 150, T - a)
        assert int(longer.valid[b].sum()) - 1 == n
        assert np.array_equal(longer.obs[b, : n + 1].numpy(), nodes[i, a : a + n + 1])
    assert longer.residuals > stretches.residuals


def test_samples_outside_a_window_do_not_count(floor, stretches):
    topo, dt = floor.dataset.topology, floor.dataset.dt
    vec = ParamVector.at(topo, floor.ground_truth.params)
    engine, basis = Engine(topo, dt), local_basis(RodAxes.of(topo), spin=False)
    theta = torch.zeros(0, dtype=torch.float64)
    masked = window_sse(engine, vec, stretches, basis, theta, 4)
    garbage = stretches.obs + 1.0 * (~stretches.valid)[:, :, None, None]
    assert window_sse(engine, vec, stretches.__class__(
        garbage, stretches.control, stretches.state, stretches.traj, stretches.start,
        stretches.valid), basis, theta, 4) == masked  # fmt: skip
    one = stretches.take(np.array([0]))
    n = int(one.valid[0].sum()) - 1
    whole = one.__class__(one.obs[:, : n + 1], None if one.control is None else
                          one.control[:, :n], one.state, one.traj, one.start)  # fmt: skip
    assert whole.residuals == one.residuals == (n + 1) * one.obs[0, 0].numel()
    assert window_sse(engine, vec, whole, basis, theta, 4) == pytest.approx(
        window_sse(engine, vec, one, basis, theta, 4), rel=1e-12
    )


def test_declared_model_from_airborne_stretches_is_good_enough_for_a_2s_drop(floor):
    true = floor.ground_truth.params
    s = TrajectorySettings(anchors={"mass[rod0]": float(true.mass[0])}, fit_windows=16, seed=5)
    many, _ = fit_declared(EndCapData(floor.dataset, s), s)
    p = many.params
    err = {k: float(np.median(np.abs(getattr(p, k).numpy() / getattr(true, k).numpy() - 1)))
           for k in ("mass", "stiffness", "damping")}  # fmt: skip
    print(err)
    assert err["mass"] < 0.005 and err["stiffness"] < 0.005 and err["damping"] < 0.03, err
    contact = GroundContact(floor.dataset.topology, **MUJOCO_DEFAULT)
    assert drop_check(p, [contact]).worst < DROP_TOLERANCE
