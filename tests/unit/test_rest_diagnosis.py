"""The rest diagnosis's measurements (``benchmarks/rest_diagnosis.py``) on NTRT's example
3-prism: a pose the model's springs hold is balanced by their own tensions, a pose off
it is not, and caps on rigid rods of the model's length project onto themselves."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from identification.trajectory.windows import rollout_caps
from tensegrity_env.engine import State
from tensegrity_env.model import Model
from tensegrity_env.ntrt import EXAMPLE_PRISM, from_ntrt

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from rest_diagnosis import equilibrium_matrix, on_rods, tensions

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: time step [s] and settling time [s] of the weightless prism, its velocities zeroed
#: every RELAX steps (dynamic relaxation: the prism's twist is a soft mode its springs'
#: damping takes long to stop)
DT, SETTLE, RELAX = 0.01, 20.0, 5


@pytest.fixture(scope="module")
def settled(tmp_path_factory: pytest.TempPathFactory) -> tuple[Model, np.ndarray, np.ndarray]:
    """The prism without gravity, its end caps as built and after settling from there."""
    path = tmp_path_factory.mktemp("prism") / "prism.yaml"
    path.write_text(EXAMPLE_PRISM)
    robot = from_ntrt(path)
    model = Model(
        robot.topology, robot.params.replace(gravity=torch.zeros(3, dtype=torch.float64)), (), DT
    )
    p, q = torch.as_tensor(robot.rest_p)[None], torch.as_tensor(robot.rest_q)[None]
    state = State(p, torch.zeros_like(p), q, torch.zeros_like(p))
    engine = model.engine()
    zeros = torch.zeros(1, robot.topology.n_rods, 3, dtype=torch.float64)
    with torch.no_grad():  # dynamic relaxation: velocities zeroed every RELAX steps
        for k in range(round(SETTLE / DT)):
            state = engine.step(state, model.params, zeros)
            if k % RELAX == 0:
                state = State(
                    state.p, torch.zeros_like(state.v), state.q, torch.zeros_like(state.omega)
                )
        caps = rollout_caps(engine, model.params, state, torch.zeros(1, 1, robot.topology.n_rods, 3,
                                                                     dtype=torch.float64))[0].numpy()  # fmt: skip
    # at rest: its springs' lengths no longer change
    assert np.abs(tensions(model, caps[-1])[0] - tensions(model, caps[0])[0]).max() < 1e-9
    return model, robot.rest_caps, caps[0]


def unbalance(model: Model, caps: np.ndarray) -> float:
    """The model's own tensions' unbalance [N per N of tension] at ``caps``."""
    A = equilibrium_matrix(model, caps, list(range(model.topology.n_springs)))
    _, t = tensions(model, caps)
    assert (t > 0).all()
    return float(np.linalg.norm(A @ t) / np.linalg.norm(t))


def test_settled_pose_balances_its_springs(settled: tuple[Model, np.ndarray, np.ndarray]) -> None:
    model, built, rest = settled
    assert unbalance(model, rest) < 1e-3
    assert unbalance(model, built) > 100 * unbalance(model, rest)


def test_a_cap_off_its_rod_is_seen(settled: tuple[Model, np.ndarray, np.ndarray]) -> None:
    model, _, rest = settled
    np.testing.assert_allclose(on_rods(rest, model), rest, atol=1e-9)
    moved = rest.copy()
    axis = (rest[1] - rest[0]) / np.linalg.norm(rest[1] - rest[0])
    moved[1] += 0.004 * axis  # rod 0 measured 4 mm long
    caps = on_rods(moved, model)
    np.testing.assert_allclose(
        np.linalg.norm(caps[[0, 1]] - moved[[0, 1]], axis=-1), 0.002, atol=1e-9
    )
    assert unbalance(model, moved) > 100 * unbalance(model, rest)
