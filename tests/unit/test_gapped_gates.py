"""Gates and statistics over measured data with gaps (unseen end caps as NaN).

A marker lost for a few frames must neither hide the floor nor turn a statistic into
NaN: each gate reads the seen samples only.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from identification.data.dataset import Dataset, Split
from identification.discovery.end_cap_residuals import summarize_window_residuals, window_residuals
from identification.linear.extended import evaluate_model
from identification.linear.features import defined_transitions, drawn_transitions
from identification.simulation.generate import GenerateSpec, generate_dataset
from identification.trajectory.airborne import (
    airborne_mask,
    contact_gate,
    has_airborne_stretch,
    lowest_seen,
)
from identification.trajectory.end_cap_data import seen_gaps
from identification.trajectory.floor_fit import floor_height
from identification.trajectory.windows import cut_windows
from tensegrity_env.assemblies import icosahedron

TOPO = icosahedron().topology
RADIUS = TOPO.rods[0].radius


def resting_caps(n: int = 2, t1: int = 60) -> np.ndarray:
    """End caps (n, t1, 12, 3) [m]: half of them touching a floor at z = 0, half 0.3 m up,
    with 1 mm of noise."""
    rng = np.random.default_rng(0)
    caps = rng.normal(size=(n, 1, 12, 3)).repeat(t1, axis=1)
    caps[..., 2] = np.where(np.arange(12) % 2 == 0, RADIUS - 5e-4, 0.3)
    return caps + rng.normal(0.0, 1e-3, caps.shape)


def gapped(caps: np.ndarray) -> np.ndarray:
    out = caps.copy()
    out[0, 10:14, 3] = np.nan  # one marker lost for 4 frames
    out[1, 30, 0] = np.nan
    return out


def test_contact_gate_tries_the_floor_through_gaps() -> None:
    caps = resting_caps()
    split = Split(nodes=gapped(caps), control=np.zeros((2, 59, 6, 3)))
    ok, why = contact_gate(split, TOPO)
    assert ok and "nan" not in why, why
    clean_ok, clean_why = contact_gate(Split(nodes=caps, control=split.control), TOPO)
    assert clean_ok and clean_why.split("%")[0] == why.split("%")[0]  # same share, seen only
    # still refused where the caps sink through: a gap hides no depth
    deep = gapped(caps)
    deep[1, 40:, 2, 2] = -0.5
    ok, why = contact_gate(replace(split, nodes=deep), TOPO)
    assert not ok and "0.52 m" in why, why  # 0.5 m plus the radius
    none = np.full_like(caps, np.nan)
    assert contact_gate(replace(split, nodes=none), TOPO) == (False, "no end cap is seen")


def test_the_lowest_end_cap_and_the_floor_height_read_the_seen_caps() -> None:
    caps = gapped(resting_caps())
    gap = caps[..., 2] - RADIUS
    low = lowest_seen(gap)
    assert np.isfinite(low).all()
    np.testing.assert_allclose(low, np.nanmin(gap, axis=-1))
    # a gap in the touching marker at sample 30 of trajectory 1: the others still touch
    assert low[1, 30] < 0.01
    assert abs(floor_height(caps, TOPO) - float(np.median(low))) < 1e-12
    assert -4e-3 < floor_height(caps, TOPO) < 0.0  # the lowest of six caps with 1 mm noise
    all_unseen = np.full((3, 12), np.nan)
    assert np.isnan(lowest_seen(all_unseen)).all()


def test_window_heights_ignore_unseen_end_caps() -> None:
    caps = resting_caps()
    caps[..., 2] += 0.2  # every end cap in the air
    gaps = gapped(caps)
    grid = {k: np.zeros((2, 60, 6, w)) for k, w in (("p", 3), ("v", 3), ("q", 4), ("omega", 3))}
    grid["q"][..., 0] = 1.0
    win = cut_windows(gaps, np.zeros((2, 59, 6, 3)), grid, 20)
    assert win.valid is not None and not bool(win.valid.all())
    h = seen_gaps(win, TOPO)
    # unseen caps read 0 in the windows' observations: as heights they would be below
    # the floor; seen_gaps leaves them out, so every window stays airborne
    assert float((win.obs[..., 2] - RADIUS).amin()) < 0
    assert float(h.amin()) > 0.1
    assert torch.isinf(h).sum() == int((~win.valid).sum())


def test_transitions_across_a_gap_are_not_drawn_and_the_errors_stay_finite() -> None:
    ds, truth = generate_dataset(GenerateSpec(assembly="icosahedron", n_train=2, n_val=0,
                                              n_test=2, steps=60, seed=1))  # fmt: skip
    test = ds.split("test")
    holed = {k: getattr(test, k).copy() for k in ("p", "v", "q", "omega")}
    for v in holed.values():
        v[0, 20:23] = np.nan  # rod states undefined over a gap
    split = replace(test, **holed)
    defined = defined_transitions(split)
    T = split.n_transitions
    assert len(defined) == 2 * T - 4 and not np.isin(np.arange(19, 23), defined).any()
    drawn = drawn_transitions(split, 1000, 0)
    assert np.array_equal(drawn, defined)
    assert len(drawn_transitions(split, 10, 0)) == 10
    # without gaps the draw is the one of all transitions
    np.testing.assert_array_equal(
        drawn_transitions(test, 50, 3),
        np.sort(np.random.default_rng(3).choice(2 * T, 50, replace=False)),
    )
    holey = Dataset(ds.topology, ds.dt, {**ds.splits, "test": split})
    clean = evaluate_model(ds.topology, truth.params, [], ds, split="test")
    got = evaluate_model(ds.topology, truth.params, [], holey, split="test")
    assert np.isfinite(got["one_step"]) and np.isfinite(got["curve"]).all()
    assert abs(got["one_step"] - clean["one_step"]) < 1e-6 and clean["one_step"] < 1e-6


def test_a_lost_marker_does_not_end_a_flight() -> None:
    """Every twelfth sample loses one marker: the flight is still one airborne stretch;
    a sample where no marker is seen is not known to be airborne."""
    caps = resting_caps(1, 120)
    caps[..., 2] += 0.5  # in the air throughout
    holes = caps.copy()
    holes[0, ::12, 5] = np.nan
    assert airborne_mask(holes, TOPO).all()
    assert has_airborne_stretch(holes, TOPO, shortest=100)
    holes[0, 60] = np.nan  # nothing seen at sample 60
    mask = airborne_mask(holes, TOPO)
    assert not mask[0, 60] and mask[0, :60].all() and mask[0, 61:].all()
    assert not has_airborne_stretch(holes, TOPO, shortest=100)
    low = caps.copy()
    low[0, 30, 4, 2] = RADIUS  # one seen marker touches: not airborne there
    low[0, 30, 5] = np.nan
    assert not airborne_mask(low, TOPO)[0, 30]


def test_held_out_residuals_leave_unseen_end_caps_out() -> None:
    """Unseen end caps read 0 in the windows: as residuals they would be metres."""
    clean = resting_caps(2, 60)
    clean[..., 2] += 0.2
    noisy = clean + np.random.default_rng(5).normal(0.0, 1e-3, clean.shape)
    grid = {k: np.zeros((2, 60, 6, w)) for k, w in (("p", 3), ("v", 3), ("q", 4), ("omega", 3))}
    grid["q"][..., 0] = 1.0
    win = cut_windows(gapped(noisy), np.zeros((2, 59, 6, 3)), grid, 20)
    span = torch.as_tensor(win.start[:, None] + np.arange(win.steps + 1))
    pred = torch.as_tensor(clean)[torch.as_tensor(win.traj)[:, None], span]
    radius = np.full(12, RADIUS)
    res = window_residuals(pred, win.obs, 0.01, radius, win.seen())
    r = summarize_window_residuals(res)
    assert abs(r["rms"] / (1e-3 * np.sqrt(3)) - 1) < 0.1, r
    assert np.isnan(r.pop("near_floor"))  # no end cap near the floor: nothing to tell
    assert np.isfinite(list(r.values())).all()
    blind = summarize_window_residuals(window_residuals(pred, win.obs, 0.01, radius))
    assert blind["rms"] > 0.05  # the unseen caps counted as errors of their position


def test_the_noise_level_reads_the_seen_rods_when_one_is_never_seen() -> None:
    """A rod whose end caps are unseen throughout a trajectory (a cap hidden under the
    robot) adds no lengths and no warning; the others give the noise."""
    import warnings

    from identification.trajectory.stage_check import noise_level

    rng = np.random.default_rng(3)
    caps = resting_caps(t1=200)
    noisy = caps + rng.normal(0.0, 1e-3, caps.shape)
    noisy[0, :, 5] = np.nan  # rod 2's second cap never seen in the first trajectory
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        level = noise_level(noisy, rods=True)
    assert abs(level / np.sqrt(2e-6) - 1.0) < 0.1  # 1 mm twice over
