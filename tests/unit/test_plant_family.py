"""Drawn plants: file conventions and physics at random, and the engine still reproduces
MuJoCo on each of them from the true model the MJCF reader gives."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from measured_plant import Cell, measure
from plant_family import (
    AXIAL_RATIO,
    MIN_SOLREF_STEPS,
    draw,
    family_initial_states,
    principal_caps,
    simulate_family,
    truth_of,
)

from identification.trajectory.windows import end_caps
from tensegrity_env.effects import GroundContact
from tensegrity_env.engine import Engine, State, substeps_for
from tensegrity_env.mjcf.reader import from_mjcf
from tensegrity_env.rotations import np_quat_to_matrix


def test_draws_cover_every_convention_and_repeat_from_their_seed() -> None:
    draws = [draw(seed) for seed in range(12)]
    rev = np.concatenate([d.site_reversed for d in draws])
    assert 0.3 < rev.mean() < 0.7
    assert {int(a) for d in draws for a in d.axis} == {0, 1, 2}
    assert {float(s) for d in draws for s in d.axis_sign} == {-1.0, 1.0}
    assert {d.end_cap for d in draws} == {"capsule", "sphere"}
    off = np.concatenate([np.linalg.norm(d.frame_origin, axis=1) for d in draws])
    assert (off == 0).any() and (off > 0).any()
    assert len({d.rate for d in draws}) > 3 and all(0 <= d.dropout <= 0.02 for d in draws)
    assert all(0.3 <= d.length <= 2.0 and 0.0 <= d.prestress <= 0.6 for d in draws)
    assert all(20 * 0.9 <= d.stiffness.min() and d.stiffness.max() <= 5000 * 1.1 for d in draws)
    assert len({d.solref for d in draws}) == 12 and all(0.8 <= d.solimp[0] < d.solimp[1] < 1
                                                         for d in draws)  # fmt: skip
    np.testing.assert_array_equal(draw(5).frame_turn, draw(5).frame_turn)
    fixed = draw(5, rate=120.0, site_reversed=np.ones(6, bool))
    assert fixed.rate == 120.0 and fixed.site_reversed.all() and fixed.length == draws[5].length


def test_the_reader_gives_the_drawn_model_in_the_files_site_order() -> None:
    d = draw(1, site_reversed=np.array([True, False, True, False, True, False]))
    truth, topo = truth_of(d)
    read = from_mjcf("family.xml", xml=truth.xml)
    for k, v in truth.params.numpy().items():
        np.testing.assert_allclose(read.params.numpy()[k], v, rtol=1e-12, err_msg=k)
    caps = principal_caps(d)  # nominal caps 0, 1 (principal frame)
    for r in range(6):
        want = caps[r, ::-1] if d.site_reversed[r] else caps[r]
        np.testing.assert_allclose(topo.end_offsets[r], want, atol=1e-12)
        np.testing.assert_allclose(topo.rods[r].frame_origin, d.frame_origin[r], atol=1e-12)


@pytest.mark.parametrize(("seed", "setting"), [(0, "flight"), (3, "floor"), (4, "floor")])
def test_the_engine_from_the_true_model_reproduces_the_drawn_plant(seed: int, setting: str) -> None:
    """Seed 4 has sphere end caps, seed 3 capsules."""
    d = draw(seed, setting, rate=120.0)
    truth, topo = truth_of(d)
    init = family_initial_states(d, 2, np.random.default_rng(0))
    clean = simulate_family(d, truth.xml, init, 0.5)
    effects = from_mjcf("family.xml", xml=truth.xml).declared_effects()  # the drawn contact
    assert [e.name for e in effects] == (["ground_contact"] if setting == "floor" else [])
    engine = Engine(topo, 1 / d.rate, effects, substeps=substeps_for(1 / d.rate))
    state = State(*(torch.as_tensor(getattr(clean, k)[:, 0]) for k in ("p", "v", "q", "omega")))
    with torch.no_grad():
        roll = engine.rollout(state, truth.params, clean.n_transitions)
    caps = end_caps(engine, roll.p, roll.q).numpy()
    assert np.abs(caps - clean.nodes).max() < 1e-9
    if setting == "floor":  # the floor is really touched, and the model needs it
        assert (clean.nodes[..., 2] < 2 * d.radius).any()
        with torch.no_grad():
            fall = Engine(topo, 1 / d.rate, substeps=substeps_for(1 / d.rate)).rollout(
                state, truth.params, clean.n_transitions
            )
        assert np.abs(fall.p.numpy() - clean.p).max() > 1e-3
        # and the drawn contact is not MuJoCo's default: the default one misses it
        default = [GroundContact(topo, friction=d.friction, height=0.0)]
        with torch.no_grad():
            other = Engine(topo, 1 / d.rate, default, substeps=substeps_for(1 / d.rate)).rollout(
                state, truth.params, clean.n_transitions
            )
        assert np.abs(other.p.numpy() - clean.p).max() > 1e-5


def test_dropouts_can_stay_gaps() -> None:
    cell = Cell("flight", 120.0, 1e-3, 0.02, "none")
    nodes = np.zeros((2, 301, 12, 3))
    gaps = measure(nodes, cell, np.random.default_rng(1), fill=False)
    lost = np.isnan(gaps).all(-1)
    assert np.isnan(gaps).any(-1).sum() == lost.sum()  # a whole end cap is lost, x, y and z
    assert abs(lost.mean() - 0.02) < 0.002 and not lost[:, [0, -1]].any()


def test_floor_starts_rest_on_a_face_drop_from_rest_or_are_thrown() -> None:
    d = draw(2, "floor")
    init = family_initial_states(d, 24, np.random.default_rng(5))
    caps = init["p"][:, :, None] + np.einsum(
        "nrij,rkj->nrki", np_quat_to_matrix(init["q"]), principal_caps(d)
    )
    low = np.sort(caps[..., 2].reshape(24, -1), axis=1) - d.radius
    still = (np.abs(init["v"]).max(axis=(1, 2)) == 0) & (np.abs(init["omega"]).max(axis=(1, 2)) == 0)
    resting = still & (low[:, 0] < 1.001e-3)
    dropped = still & ~resting
    assert resting.any() and dropped.any() and (~still).any()
    # on a face: three end caps down together (the hull's face), the rest well above
    np.testing.assert_allclose(low[resting, 2], low[resting, 0], atol=1e-9)
    assert (low[resting, 3] - low[resting, 0] > 0.01 * d.length).all()
    assert ((low[dropped, 0] >= 0.1 - 1e-9) & (low[dropped, 0] <= 0.5)).all()
    assert ((low[~still, 0] >= 0.02 - 1e-9) & (low[~still, 0] <= 0.2)).all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_floor_draws_stay_stable_in_mujoco(seed: int) -> None:
    """A solid rod's axial moment (m r^2 / 2) let these diverge within 3 s."""
    d = draw(seed, "floor")
    assert d.solref[0] >= MIN_SOLREF_STEPS * 1e-3 and (d.axial_ratio >= AXIAL_RATIO[0]).all()
    truth, _ = truth_of(d)
    init = family_initial_states(d, 4, np.random.default_rng([seed, 64, 0, 3]))
    clean = simulate_family(d, truth.xml, init, 3.0)
    assert np.isfinite(clean.nodes).all() and (clean.nodes[..., 2] < 2 * d.radius).any()
