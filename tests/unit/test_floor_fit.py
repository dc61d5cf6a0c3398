"""The floor fit's helpers: rods away from the floor, the floor height, the start contact,
the regression restricted to rods and the windows' states fitted afresh
(identification.trajectory.floor_fit)."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from identification.data.end_caps import RodAxes, odd_window, smooth_rod_states
from identification.linear.smoothed import smoothed_regression
from identification.simulation.generate import GenerateSpec, generate_dataset
from identification.trajectory.effect_coords import CONTACT_START, EffectCoords
from identification.trajectory.end_cap_data import held_drag_axis
from identification.trajectory.floor_fit import (
    FLOOR_FREE,
    fit_on_floor,
    floor_contact,
    floor_height,
    reseeded,
    rods_leaning,
    rods_off_floor,
    scale_directions,
    search_floor_contact,
    with_floor,
    without_stuck,
)
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.window_errors import better_states, window_errors, windows_within
from identification.trajectory.windows import STATE_KEYS, cut_windows
from tensegrity_env import assemblies
from tensegrity_env.effects import GroundContact, LinearDrag
from tensegrity_env.engine import Engine, State


def _caps(z: np.ndarray) -> np.ndarray:
    """End caps (1, T+1, 12, 3) of the icosahedron at heights ``z`` (T+1, 12) [m]."""
    nodes = np.zeros((1, *z.shape, 3))
    nodes[0, ..., 2] = z
    return nodes


def test_rods_off_floor_marks_rods_whose_caps_all_stay_clear_over_the_span() -> None:
    topo = assemblies.icosahedron().topology
    r = topo.rods[0].radius
    z = np.full((21, 12), 0.5)
    z[10, 0] = r  # rod 0's first cap touches at sample 10
    z[:, 5] = r + 0.001  # rod 2's second cap always within 5 mm
    off = rods_off_floor(_caps(z), topo, span=5)
    assert off.shape == (1, 20, 6)
    assert not off[0, 8:13, 0].any() and off[0, :8, 0].all() and off[0, 13:, 0].all()
    assert not off[0, :, 2].any()
    assert off[0, :, [1, 3, 4, 5]].all()


def test_floor_height_is_where_the_lowest_cap_rests() -> None:
    topo = assemblies.icosahedron().topology
    r = topo.rods[0].radius
    rng = np.random.default_rng(0)
    z = np.full((201, 12), 0.3)
    z[:, 0] = r - 0.004 + 1e-3 * rng.standard_normal(201)  # a cap resting 4 mm deep
    z[:20, 0] = 0.2  # the drop before it lands does not count
    assert abs(floor_height(_caps(z), topo) + 0.004) < 3e-4
    start = floor_contact(topo, _caps(z))
    assert abs(float(start.values["height"]) - floor_height(_caps(z), topo)) < 1e-12
    assert float(start.values["stiffness"]) == CONTACT_START["stiffness"]
    given = GroundContact(topo, stiffness=2000.0, friction=0.9, height=0.01)
    mine = floor_contact(topo, _caps(z), given)  # a params file's contact wins
    assert float(mine.values["friction"]) == 0.9 and float(mine.values["height"]) == 0.01


def test_a_rod_leans_on_the_cap_near_the_floor_while_the_other_stays_clear() -> None:
    topo = assemblies.icosahedron().topology
    r = topo.rods[0].radius
    z = np.full((40, 12), 0.3)
    z[:, 0] = r + 0.001  # rod 0 leans on cap 0 throughout
    z[:, 3] = r + 0.001  # rod 1 on cap 1 ...
    z[20:, 2] = r  # ... and from sample 20 on cap 0 too: both touch
    z[30:, 5] = r  # rod 2 touches with cap 1 from sample 30 on
    lean = rods_leaning(_caps(z), topo, span=5)
    assert lean.shape == (1, 39, 6)
    assert (lean[0, :, 0] == 0).all()
    assert (lean[0, :17, 1] == 1).all() and (lean[0, 23:, 1] == -1).all()  # the span's margin
    assert (lean[0, :27, 2] == -1).all() and (lean[0, 29:, 2] == 1).all()
    assert (lean[0, :, 3:] == -1).all()  # clear of the floor: rods_off_floor's


def test_moments_about_the_contact_point_identify_the_model_on_the_floor() -> None:
    """On clean floor data the rods leaning on one cap, by their moments about its contact
    point alone, give masses within 2 % and stiffnesses within 4 % (the smoothing's
    bias through impacts); their six equations, contact ignored, are off by > 50 %."""
    ds, truth = generate_dataset(GenerateSpec(n_train=4, n_val=0, n_test=0, steps=1500, seed=2,
                                              ground=True))  # fmt: skip
    split, topo = ds.split("train"), ds.topology
    span = odd_window(0.05 / ds.dt)
    smooth = smooth_rod_states(split.nodes, ds.dt, RodAxes.of(topo), span)
    anchors = {"mass[rod0]": float(truth.params.mass[0])}
    lean = rods_leaning(split.nodes, topo, span)
    assert (lean >= 0).mean() > 0.5  # most rod-samples lean on the floor
    radius = np.array([r.radius for r in topo.rods])
    none = np.zeros(lean.shape, bool)
    leaning = smoothed_regression(topo, smooth, split.control, anchors, rod_keep=none,
                                  pivots=np.where(lean >= 0, lean, -1), radius=radius)  # fmt: skip
    ignored = smoothed_regression(topo, smooth, split.control, anchors,
                                  rod_keep=rods_off_floor(split.nodes, topo, span) | (lean >= 0))  # fmt: skip
    true = truth.params.numpy()

    def worst(values: dict[str, np.ndarray], key: str) -> float:
        return float(np.max(np.abs(values[key] / true[key] - 1)))

    assert worst(leaning, "mass") < 0.02 and worst(leaning, "stiffness") < 0.04
    assert worst(leaning, "rest_length") < 0.005
    assert worst(ignored, "mass") > 0.5 or worst(ignored, "stiffness") > 0.5


def test_rod_keep_equal_to_sample_keep_gives_the_same_regression() -> None:
    a = assemblies.icosahedron()
    ds, truth = generate_dataset(GenerateSpec(n_train=2, n_val=0, n_test=0, steps=300, seed=1))
    split = ds.split("train")
    axes = RodAxes.of(a.topology)
    smooth = smooth_rod_states(split.nodes, ds.dt, axes, odd_window(0.05 / ds.dt))
    keep = np.zeros(split.control.shape[:2], bool)
    keep[:, 40:200] = True
    anchors = {"mass[rod0]": float(truth.params.mass[0])}
    by_sample = smoothed_regression(a.topology, smooth, split.control, anchors, keep=keep)
    rod_keep = np.repeat(keep[..., None], a.topology.n_rods, axis=-1)
    by_rod = smoothed_regression(a.topology, smooth, split.control, anchors, rod_keep=rod_keep)
    for key in ("stiffness", "mass", "rest_length"):
        np.testing.assert_allclose(by_rod[key], by_sample[key], rtol=1e-10)
    rod_keep[:, :, 1] = False  # rod 1's equations dropped: the others still pin the springs
    fewer = smoothed_regression(a.topology, smooth, split.control, anchors, rod_keep=rod_keep)
    assert np.isfinite(fewer["stiffness"]).all()
    assert not np.allclose(fewer["stiffness"], by_sample["stiffness"], rtol=1e-12)


def _on_the_floor(n_train: int, steps: int, window: int):
    """Clean floor data (seed 2) after landing, cut into windows of ``window`` steps at their
    true states, and the true model with the contact as a floor fit holds it."""
    ds, truth = generate_dataset(GenerateSpec(n_train=n_train, n_val=0, n_test=0, steps=steps,
                                              seed=2, ground=True))  # fmt: skip
    split, topo = ds.split("train"), ds.topology
    grid = {k: getattr(split, k)[:, 200:] for k in STATE_KEYS}  # after landing: on the floor
    windows = cut_windows(split.nodes[:, 200:], split.control[:, 200:], grid, window)
    contact = GroundContact(topo, **truth.effects[0]["params"])
    return ds, windows, with_floor(ParamVector.at(topo, truth.params), [], contact, None)


@pytest.mark.slow
def test_contact_search_on_windows_recovers_a_moved_contact_from_clean_floor_data() -> None:
    ds, windows, vec = _on_the_floor(2, 400, 40)
    topo = ds.topology
    theta = vec.theta0()
    moved = theta.clone()
    moved[-len(FLOOR_FREE) :] += torch.tensor([0.3, -0.3, 0.2, 0.0, 0.0], dtype=moved.dtype)
    found = search_floor_contact(Engine(topo, ds.dt), vec, windows, moved)
    np.testing.assert_allclose(found[: vec.n_free], theta[: vec.n_free])
    err = (found - theta)[-len(FLOOR_FREE) :].abs()
    assert err[:3].max() < 0.05, err  # stiffness, damping (log) and friction back within 5 %


def test_a_window_stuck_in_another_state_is_fitted_afresh_from_its_seed() -> None:
    ds, seeds, vec = _on_the_floor(1, 300, 20)
    theta, engine = vec.theta0(), Engine(ds.topology, ds.dt)
    shift = torch.zeros_like(seeds.state.p)
    shift[0, :, 0] = 0.02  # window 0 is 2 cm off, the others at their true states
    st = seeds.state
    stuck = replace(seeds, state=State(st.p + shift, st.v, st.q, st.omega))
    before = window_errors(engine, vec, stuck, theta)
    after = window_errors(engine, vec, reseeded(engine, vec, theta, stuck, seeds, 3), theta)
    assert before[0] > 1e-2 and (before[1:] < 1e-20).all()  # clean data: true states exact
    assert after[0] < 1e-12 and (after <= before).all()


def test_windows_whose_states_stay_off_by_more_than_the_noise_are_left_out() -> None:
    """Noisy end caps (1 mm) at the true model: the windows at their true states fit to
    about the noise and are kept; a window stuck 2 cm off is left out. Where most windows
    are off, the better half is kept."""
    ds, seeds, vec = _on_the_floor(1, 300, 20)
    theta, engine = vec.theta0(), Engine(ds.topology, ds.dt)
    gen = torch.Generator().manual_seed(0)
    noisy = replace(seeds, obs=seeds.obs + 1e-3 * torch.randn(seeds.obs.shape, generator=gen,
                                                              dtype=seeds.obs.dtype))  # fmt: skip
    shift = torch.zeros_like(seeds.state.p)
    shift[1, :, 0] = 0.02
    st = seeds.state
    stuck = replace(noisy, state=State(st.p + shift, st.v, st.q, st.omega))
    kept, rms = windows_within(engine, vec, stuck, theta, 1.5e-3)
    others = np.delete(rms, 1)
    assert np.allclose(others, 1e-3, rtol=0.1) and rms[1] > 1e-2
    assert list(kept.start) == list(np.delete(stuck.start, 1))
    shift[2:, :, 0] = 0.02  # most windows off: the better half stays
    most = replace(noisy, state=State(st.p + shift, st.v, st.q, st.omega))
    kept, rms = windows_within(engine, vec, most, theta, 1.5e-3)
    assert kept.size == (stuck.size + 1) // 2 and stuck.start[0] in kept.start


def _axial_drag_rms(ds, windows, vec: ParamVector, contact: list[GroundContact]) -> float:
    """End-cap RMS [m] that a rotational drag about the rods' axes (decay rate 50 1/s)
    adds to ``windows`` cut at their true states (the model otherwise true)."""
    topo = ds.topology
    axis = int(RodAxes.of(topo).axis[0])
    rate = np.zeros(3)
    rate[axis] = 50.0 * float(vec.params(vec.full(vec.theta0())).inertia[0, axis])
    drag = LinearDrag(topo, translational=[0.0, 0.0, 0.0], rotational=rate.tolist())
    dragged = replace(vec, coords=EffectCoords.of([drag, *contact], None, ()))
    sse = window_errors(Engine(topo, ds.dt), dragged, windows, dragged.theta0())
    return float(np.sqrt(float(sse.sum()) / windows.residuals))


def test_drag_about_the_rod_axis_shows_on_the_floor_and_not_in_flight() -> None:
    """On the floor, friction at the end caps spins each rod about its axis, and a drag on
    that spin changes how the caps roll: the floor fits leave it free
    (held_drag_axis). In flight the spin about the axis moves no end cap."""
    ds, windows, vec = _on_the_floor(1, 700, 250)  # windows of 0.25 s
    assert vec.coords is not None
    contact = [e for e in vec.coords.effects if isinstance(e, GroundContact)]
    on_floor = _axial_drag_rms(ds, windows, vec, contact)
    flight, truth = generate_dataset(GenerateSpec(n_train=1, n_val=0, n_test=0, steps=500, seed=2))
    split = flight.split("train")
    grid = {k: getattr(split, k) for k in STATE_KEYS}
    airborne = cut_windows(split.nodes, split.control, grid, 250)
    in_flight = _axial_drag_rms(flight, airborne, ParamVector.at(flight.topology, truth.params), [])
    assert on_floor > 1e-3, on_floor  # above 1 mm of motion-capture noise
    assert in_flight < 1e-2 * on_floor, (in_flight, on_floor)  # 9e-6 against 1.1e-2 m


def test_the_floor_fits_leave_the_axial_drag_free_and_flight_fits_hold_it() -> None:
    topo = assemblies.icosahedron().topology
    axes = RodAxes.of(topo)
    drag = LinearDrag(topo)  # 3 translational + 3 rotational coefficients
    floor = SimpleNamespace(on_floor=True, axes=axes)
    flight = SimpleNamespace(on_floor=False, axes=axes)
    assert held_drag_axis(floor) is None
    assert EffectCoords.of([drag], held_drag_axis(floor), ()).n == 6
    assert EffectCoords.of([drag], held_drag_axis(flight), ()).n == 5


def test_the_common_scale_with_the_drag_scaled_leaves_the_motion_unchanged() -> None:
    """Every mass, inertia, stiffness and damping and the drag coefficients times one
    factor: the same motion on the floor (gravity, springs, drag and the contact, per unit
    of effective mass, all scale). With the drag held, the masses move against it."""
    ds, windows, vec = _on_the_floor(1, 300, 40)
    topo = ds.topology
    assert vec.coords is not None
    drag = LinearDrag(topo, translational=[1.5, 1.0, 0.5], rotational=[0.05, 0.05, 0.0])
    contact = [e for e in vec.coords.effects if isinstance(e, GroundContact)]
    free = torch.zeros_like(vec.free)
    for group in ("stiffness", "damping", "mass", "inertia_perp"):
        free[vec.offset(group) : vec.offset(group) + vec.sizes[group]] = True
    vec = replace(vec, free=free, coords=EffectCoords.of([drag, *contact], None, FLOOR_FREE))
    theta, engine = vec.theta0(), Engine(topo, ds.dt)
    U = scale_directions(vec, theta)
    a = 0.2
    held = theta + a * U[0]
    scaled = held.clone()
    forces = vec.mass_scaled()
    assert int(forces.sum()) == 6  # the drag's coefficients, not the contact's
    scaled[forces] = theta[forces] * np.exp(a)
    held[forces] = theta[forces]
    base = window_errors(engine, vec, windows, theta).sum()
    same = window_errors(engine, vec, windows, scaled).sum()
    moved = window_errors(engine, vec, windows, held).sum()
    assert abs(float(same / base) - 1) < 1e-9, float(same / base)  # measured 1e-14
    assert abs(float(moved / base) - 1) > 1e-3, float(moved / base)  # measured -33 %


def test_floor_windows_take_the_flight_before_touchdown_first() -> None:
    """Half the floor windows start in the air where some do: a drop's flight before it lands
    pins drag and masses apart from the contact."""
    from identification.data.dataset import Dataset
    from identification.trajectory.airborne import AIRBORNE, cap_radii
    from identification.trajectory.end_cap_data import EndCapData, TrajectorySettings

    flight, _ = generate_dataset(GenerateSpec(n_train=2, n_val=1, n_test=1, steps=300, seed=3))
    train = flight.split("train")
    radii = cap_radii(flight.topology)
    nodes = train.nodes.copy()
    lift = np.where(np.arange(nodes.shape[1]) < 40, 0.3, 0.0)  # flies 40 samples, then rests
    nodes[..., 2] += ((radii - nodes[..., 2]).max(axis=-1) + lift)[..., None]
    splits = {**flight.splits, "train": replace(train, nodes=nodes)}
    data = EndCapData(Dataset(flight.topology, flight.dt, splits, flight.attrs),
                      TrajectorySettings(window=30))  # fmt: skip

    def in_air(w) -> np.ndarray:
        return (w.obs[:, 0, :, 2].numpy() - radii).min(axis=1) > AIRBORNE

    # tiles of 30 steps: those at samples 0 and 30 of each trajectory start in the air
    for lift_off, expect in ((4, 4), (2, 2), (0, None)):
        w = data.cut("train", 30, 8, 3, lift_off=lift_off)
        assert w.size == 8
        if expect is not None:
            assert int(in_air(w).sum()) == expect
            assert set(w.start[in_air(w)]) <= {0, 30}
    # in flight only (every window in the air): still 8 windows
    only_air = EndCapData(flight, TrajectorySettings(window=30)).cut("train", 30, 8, 3, lift_off=4)
    assert only_air.size == 8
    # the selection windows on the floor: half from those starting in the air, same length
    before = data.windows["train"]
    data.lift_off_selection()
    chosen = data.windows["train"]
    assert chosen.size == before.size == 8 and chosen.steps == before.steps
    assert int(in_air(chosen).sum()) == 4


def test_a_prefix_state_that_flies_off_over_the_window_is_not_kept(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The states fitted on the windows' prefixes are kept only where they fit the whole
    window better than the state the fit started from: a prefix state whose rollout
    diverges over the rest of the window (NaN) leaves the final fit nothing to descend
    from."""
    from identification.trajectory import window_states

    ds, seeds, vec = _on_the_floor(1, 300, 60)
    theta, engine = vec.theta0(), Engine(ds.topology, ds.dt)
    real = window_states.fit

    def flying_prefixes(problem, options):
        fit = real(problem, options)
        if problem.windows.steps < seeds.steps:  # a prefix: its state blows up further on
            st = fit.windows.state
            nan = torch.full_like(st.v, float("nan"))
            fit = replace(fit, windows=replace(fit.windows, state=State(st.p, nan, st.q, st.omega)))
        return fit

    monkeypatch.setattr(window_states, "fit", flying_prefixes)
    fitted = window_states.fit_states(vec.engine(engine, theta), vec.held_at(theta), seeds, 2)
    after = window_errors(engine, vec, fitted.windows, theta)
    assert torch.isfinite(after).all()
    assert (after < 1e-12).all()  # clean data from the true states: they stay exact
    assert np.isfinite(fitted.history[-1])


def test_a_window_whose_rollout_is_not_finite_has_an_infinite_error() -> None:
    ds, seeds, vec = _on_the_floor(1, 300, 60)
    theta, engine = vec.theta0(), Engine(ds.topology, ds.dt)
    st = seeds.state
    broken = replace(seeds, state=State(st.p, torch.full_like(st.v, float("nan")), st.q, st.omega))
    assert torch.isinf(window_errors(engine, vec, broken, theta)).all()
    picked, _, best = better_states(engine, vec, theta, seeds, broken)
    assert (best < 1e-12).all()
    assert torch.isfinite(picked.state.v).all()


@pytest.mark.slow
def test_the_floor_fit_leaves_out_a_window_no_state_fits() -> None:
    """Clean floor data at the true model, one window's end caps moved 2 cm from its
    middle on (no initial state fits it: as a state stuck in another basin): the start
    model fits the others, so it is left out from the first round, and the joint fit on
    the others stays at the truth. Without ``stuck`` it stays in and bends the contact."""
    ds, seeds, vec = _on_the_floor(1, 300, 20)
    theta, engine = vec.theta0(), Engine(ds.topology, ds.dt)
    obs = seeds.obs.clone()
    obs[1, 10:, :, 0] += 0.02
    bad = replace(seeds, obs=obs)
    fit = fit_on_floor(engine, vec, bad, theta, 3, rounds=2, max_rounds=2, stuck=1e-4)
    assert list(fit.windows.start) == list(np.delete(bad.start, 1))
    assert np.sqrt(fit.history[-1]) < 1e-6
    assert float((fit.theta - theta).abs().max()) < 1e-5  # contact back at the truth
    kept = fit_on_floor(engine, vec, bad, theta, 3, rounds=2, max_rounds=2)
    assert kept.windows.size == bad.size and np.sqrt(kept.history[-1]) > 1e-3
    assert float((kept.theta - theta).abs().max()) > 1e-2


def test_a_start_that_fits_few_windows_leaves_none_out_before_a_joint_fit() -> None:
    """``without_stuck(near=True)`` (the first round): where most windows are off at the
    model, the model is off, not their states, and every window stays; where one is, it
    goes. From the second round (``near=False``) the better half stays."""
    ds, seeds, vec = _on_the_floor(1, 300, 20)
    theta, engine = vec.theta0(), Engine(ds.topology, ds.dt)
    st = seeds.state
    shift = torch.zeros_like(st.p)
    shift[1, :, 0] = 0.02
    one = replace(seeds, state=State(st.p + shift, st.v, st.q, st.omega))
    kept = without_stuck(engine, vec, theta, one, 1e-4, near=True)
    assert list(kept.start) == list(np.delete(seeds.start, 1))
    shift[2:, :, 0] = 0.02
    most = replace(seeds, state=State(st.p + shift, st.v, st.q, st.omega))
    assert without_stuck(engine, vec, theta, most, 1e-4, near=True).size == seeds.size
    assert without_stuck(engine, vec, theta, most, 1e-4).size == (seeds.size + 1) // 2
