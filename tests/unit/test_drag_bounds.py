"""Drag coefficients stay in their physical domain (>= 0) inside the trajectory fit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from identification.trajectory.effect_coords import EffectCoords
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.windowed_fit import NormalEquations, bounded_step
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
from identification.trajectory.windows import Windows, end_caps
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import ForceField, LinearDrag, QuadraticDrag
from tensegrity_env.engine import Engine, State, substeps_for


def test_drag_coordinates_are_bounded_below_by_zero_and_signed_ones_are_free() -> None:
    top = icosahedron().topology
    coords = EffectCoords.of([LinearDrag(top), ForceField(top), QuadraticDrag(top)], axial=2)
    lo, hi = coords.bounds()
    names = coords.names()
    assert len(lo) == len(names) == 5 + 3 + 5  # the axial rotational drags are held
    for name, low, high in zip(names, lo.tolist(), hi.tolist(), strict=True):
        assert high == np.inf
        assert low == (-np.inf if name.startswith("force_field") else 0.0), name


def _normal(H: np.ndarray, g: np.ndarray) -> NormalEquations:
    """Normal equations of a sum of squares ``sse + 2 gᵀδ + δᵀHδ`` in two global
    coordinates (one window with a decoupled, unit local coordinate)."""
    return NormalEquations(
        H_ll=torch.ones(1, 1, 1, dtype=torch.float64),
        H_lg=torch.zeros(1, 1, 2, dtype=torch.float64),
        g_l=torch.zeros(1, 1, dtype=torch.float64),
        H_gg=torch.as_tensor(H, dtype=torch.float64),
        g_g=torch.as_tensor(g, dtype=torch.float64),
        sse=1.0,
        m=10,
        g_gb=torch.zeros(1, 2, dtype=torch.float64),
    )


def test_a_step_out_of_the_bound_holds_that_coordinate_and_solves_for_the_rest() -> None:
    H = np.array([[2.0, 0.8], [0.8, 1.0]])
    g = np.array([1.0, -1.0])  # free minimum: δ = -H⁻¹g = (-1.21, 1.97): θ0 would go < 0
    theta = torch.zeros(2, dtype=torch.float64)
    lo = torch.tensor([0.0, -np.inf], dtype=torch.float64)
    hi = torch.full((2,), np.inf, dtype=torch.float64)
    _, d_theta, pred, _ = bounded_step(_normal(H, g), 0.0, theta, lo, hi)
    assert float(d_theta[0]) == 0.0
    # with θ0 held at 0, the minimum along θ1 is -g1/H11
    assert abs(float(d_theta[1]) - 1.0) < 1e-12
    assert abs(pred - 1.0) < 1e-12  # g1² / H11, the decrease of the sse the held step makes
    # a coordinate inside the box that the step would carry past it stops on the bound
    _, d_theta, _, _ = bounded_step(_normal(H, g), 0.0, torch.tensor([0.5, 0.0]), lo, hi)
    assert float(d_theta[0]) == -0.5
    # a search range (not a physical bound) is not held: the free step, stopped on it
    soft = torch.tensor([False, False])
    _, d_theta, _, _ = bounded_step(_normal(H, g), 0.0, theta, lo, hi, soft)
    free = -np.linalg.solve(H, g)
    assert float(d_theta[0]) == 0.0 and abs(float(d_theta[1]) - free[1]) < 1e-12


def test_a_held_coordinate_stays_and_the_rest_take_the_conditional_minimum() -> None:
    H = np.array([[2.0, 0.8], [0.8, 1.0]])
    g = np.array([1.0, -1.0])
    theta = torch.zeros(2, dtype=torch.float64)
    lo = torch.full((2,), -np.inf, dtype=torch.float64)
    hi = torch.full((2,), np.inf, dtype=torch.float64)
    hold = torch.tensor([True, False])
    _, d_theta, pred, _ = bounded_step(_normal(H, g), 0.0, theta, lo, hi, None, hold)
    assert float(d_theta[0]) == 0.0  # well inside its (infinite) box, held all the same
    assert abs(float(d_theta[1]) - 1.0) < 1e-12 and abs(pred - 1.0) < 1e-12  # -g1/H11
    _, d_theta, _, _ = bounded_step(_normal(H, g), 0.0, theta, lo, hi, None, ~hold)
    assert float(d_theta[1]) == 0.0 and abs(float(d_theta[0]) + 0.5) < 1e-12  # -g0/H00


def test_only_drag_coordinates_have_hard_bounds() -> None:
    """The log-parameters' box and the contact's search box are ranges, not physics."""
    a = icosahedron()
    coords = EffectCoords.of([LinearDrag(a.topology), ForceField(a.topology)], axial=2)
    vec = replace(ParamVector.at(a.topology, a.params), coords=coords)
    hard = vec.hard_bounds()
    assert hard.shape == (vec.n_free + 5 + 3,)
    assert not bool(hard[: vec.n_free].any())
    assert hard[vec.n_free :].tolist() == [True] * 5 + [False] * 3


def test_the_fit_keeps_a_drag_at_zero_where_the_data_asks_for_a_negative_one() -> None:
    """Data from a plant whose drag along the rods is negative (it feeds energy in, which
    no drag does): the fit holds that coefficient at 0 and still finds the sideways one."""
    a = icosahedron()
    dt = 1 / 120
    engine = Engine(a.topology, dt, substeps=substeps_for(dt), native=True)  # C kernel: same physics
    plant = LinearDrag(a.topology, validate=False, translational=[0.6, 0.6, -0.3],
                       rotational=[0.0, 0.0, 0.0])  # fmt: skip
    rng = np.random.default_rng(0)
    states = []
    for _ in range(4):
        p = torch.as_tensor(a.pose_p[None] + rng.normal(0, 0.01, (1, 6, 3)))
        v = torch.as_tensor(rng.normal(0, 0.5, (1, 6, 3)))
        w = torch.as_tensor(rng.normal(0, 1.0, (1, 6, 3)))
        states.append(State(p, v, torch.as_tensor(a.pose_q[None]), w))
    truth = State(*(torch.cat([getattr(s, k) for s in states]) for k in ("p", "v", "q", "omega")))
    with torch.no_grad():
        roll = engine.with_effects([plant]).rollout(truth, a.params, 24)
    obs = end_caps(engine, roll.p, roll.q)
    coords = EffectCoords.of([LinearDrag(a.topology)], axial=2)
    vec = replace(ParamVector.at(a.topology, a.params), coords=coords)
    win = Windows(obs=obs, control=None, state=truth, traj=np.arange(4), start=np.zeros(4, int))
    done = fit(WindowedProblem(engine, vec, win), FitOptions(max_iter=15))
    (drag,) = vec.effects(done.theta)
    b = drag.values["translational"].numpy()
    assert b[2] == 0.0  # held on the bound, not negative
    assert (drag.values["rotational"].numpy() >= 0).all()
    assert np.abs(b[:2] - 0.6).max() < 0.1 * 0.6  # the drag the data does show is still found
    assert drag.physical()
