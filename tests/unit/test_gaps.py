"""Gaps in measured end caps: smoothing fits through them, fits compare only seen caps."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.signal import savgol_filter

from identification.data.end_caps import (
    RodAxes,
    check_caps_seen,
    masked_savgol,
    measured_rod_states,
    smooth_nodes,
    smooth_rod_states,
)
from identification.trajectory.windows import cut_windows, fill_grid
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.engine import Engine
from tensegrity_env.io_utils import InputError


def cubic_caps(t1: int = 120, dt: float = 0.01) -> np.ndarray:
    t = np.arange(t1) * dt
    x = np.stack([1 + t - t**3, 0.5 * t**2, 2 * t**3 - t], -1)
    return np.broadcast_to(x[None, :, None, :], (2, t1, 4, 3)).copy()


def test_masked_savgol_is_savgol_without_gaps_and_exact_on_a_cubic_through_a_gap() -> None:
    rng = np.random.default_rng(0)
    noisy = cubic_caps() + rng.normal(0, 1e-3, (2, 120, 4, 3))
    ours = masked_savgol(noisy, 0.01, 11, 3)
    for d, got in enumerate(ours):
        ref = savgol_filter(noisy, 11, 3, deriv=d, axis=1, delta=0.01, mode="interp")
        np.testing.assert_allclose(got, ref, atol=1e-9 * 10.0**d)
    exact = cubic_caps()
    gapped = exact.copy()
    gapped[0, 40:44, 2] = np.nan  # 4 samples of one end cap unseen
    x, xd, _ = masked_savgol(gapped, 0.01, 11, 3)
    np.testing.assert_allclose(x, exact, atol=1e-10)  # a cubic is refitted exactly
    t = np.arange(120) * 0.01
    np.testing.assert_allclose(xd[0, :, 2, 0], 1 - 3 * t**2, atol=1e-8)


def test_a_gap_longer_than_the_filter_stays_a_gap_and_its_samples_are_left_out() -> None:
    gapped = cubic_caps()
    gapped[1, 30:60, 0] = np.nan
    smooth = smooth_nodes(gapped, 0.01, 0.02)
    inside = ~np.isfinite(smooth[1, :, 0]).all(-1)
    assert inside[40:50].all() and not inside[:25].any() and not inside[65:].any()
    assert np.isfinite(smooth[0]).all() and np.isfinite(smooth[1, :, 1:]).all()
    topo = icosahedron().topology
    nodes = np.repeat(gapped[:, :, :1], 12, axis=2) + topo.end_offsets.reshape(1, 1, 12, 3)
    for method, smoothing in (("exact", 0.0), ("gaussian", 0.02), ("savgol", 0.07)):
        _, st = measured_rod_states(nodes, topo, 0.01, method, smoothing)
        undefined = ~np.isfinite(st["p"]).all(axis=(2, 3))
        assert not undefined[0].any(), method
        # every sample whose differences or filter window reach the gap is left out
        reach = 1 if method != "savgol" else 3
        assert (
            undefined[1, 30 - reach : 60 + reach].all() and not undefined[1, : 30 - reach].any()
        ), method
    s = smooth_rod_states(nodes, 0.01, RodAxes.of(topo), 7)
    assert s.whole[0].all() and not s.whole[1, 27:63].any() and s.whole[1, :27].all()
    assert not s.finite[1, 40:50].any() and s.finite[1, :25].all()


def test_windows_weigh_unseen_end_caps_zero() -> None:
    nodes = cubic_caps()
    nodes[0, 10:13, 1] = np.nan
    grid = {k: np.zeros((2, 120, 2, w)) for k, w in (("p", 3), ("v", 3), ("q", 4), ("omega", 3))}
    grid["q"][..., 0] = 1.0
    win = cut_windows(nodes, np.zeros((2, 119, 2, 3)), grid, 30)
    assert win.valid is not None and torch.isfinite(win.obs).all()
    assert int((~win.valid).sum()) == 3 and win.residuals == (win.obs[..., 0].numel() - 3) * 3
    w = win.weights()
    assert w is not None and float(w[0, 10:13, 1].sum()) == 0.0 and float(w.sum()) == w.numel() - 3


def test_windows_start_where_the_smoothing_is_defined() -> None:
    nodes = cubic_caps()
    grid = {k: np.zeros((2, 120, 2, w)) for k, w in (("p", 3), ("v", 3), ("q", 4), ("omega", 3))}
    grid["q"][..., 0] = 1.0
    grid["p"][0, 25:33] = np.nan  # an unbridged gap at the start of trajectory 0's second window
    grid["v"][1, 0:30] = np.nan  # and over trajectory 1's whole first window
    win = cut_windows(nodes, np.zeros((2, 119, 2, 3)), grid, 25)
    pairs = list(zip(win.traj.tolist(), win.start.tolist(), strict=True))
    assert (0, 0) in pairs and (0, 33) in pairs and (0, 29) not in pairs
    assert not any(t == 1 and s < 30 for t, s in pairs) and (1, 30) in pairs  # 0 dropped, 29 moved
    assert all(torch.isfinite(x).all() for x in win.state.tensors())
    assert all(s + win.steps <= 119 for s in win.start)


def test_a_window_over_the_whole_trajectory_starts_after_a_gap_and_ends_with_it() -> None:
    """A gap in the first samples leaves the smoothing undefined there; a window over the
    whole trajectory then starts at the first sample where it is defined and ends where
    the trajectory does (its samples past the end count in no residual), and its rollout
    is written back up to that end only."""
    topo = icosahedron().topology
    dt = 0.01
    nodes = np.repeat(cubic_caps()[:1, :, :1], 12, axis=2) + topo.end_offsets.reshape(1, 1, 12, 3)
    nodes[0, 2:6, 7] = np.nan  # 4 samples of one end cap lost near the start
    smooth = smooth_rod_states(nodes, dt, RodAxes.of(topo), 7)
    grid = {k: getattr(smooth, k) for k in ("p", "v", "q", "omega")}
    first = int(np.flatnonzero(smooth.finite[0])[0])
    assert 0 < first < 10  # the smoothing starts in the gap
    T = nodes.shape[1] - 1
    win = cut_windows(nodes, np.zeros((1, T, 6, 3)), grid, T)
    assert win.size == 1 and win.steps == T and int(win.start[0]) == first
    assert win.valid is not None and all(torch.isfinite(x).all() for x in win.state.tensors())
    seen = win.seen()[0]
    assert not seen[T - first + 1 :].any()  # past the trajectory's end
    mine = seen[: T - first + 1].numpy()
    np.testing.assert_array_equal(mine, np.isfinite(nodes[0, first:]).all(-1))
    np.testing.assert_array_equal(win.obs[0, : T - first + 1].numpy()[mine], nodes[0, first:][mine])
    engine = Engine(topo, dt)
    filled = {k: v.copy() for k, v in grid.items()}
    fill_grid(engine, icosahedron().params, win, filled)
    for k in filled:
        np.testing.assert_array_equal(filled[k][0, :first], grid[k][0, :first])
    np.testing.assert_allclose(filled["p"][0, first], grid["p"][0, first], atol=1e-12)
    assert not np.allclose(filled["p"][0, -1], grid["p"][0, -1])  # the rollout reaches the end


def test_an_end_cap_never_seen_is_refused_by_name() -> None:
    """Gaps anywhere are fine as long as every end cap is seen somewhere in the split;
    one never seen (a marker the map missed) is named."""
    topo = icosahedron().topology
    nodes = np.random.default_rng(0).normal(size=(2, 30, 12, 3))
    nodes[0, :, 3] = np.nan
    nodes[1, :20, 3] = np.nan
    check_caps_seen(nodes, topo, "d.h5: split 'train'")  # rod1.1 seen in trajectory 1
    nodes[1, :, 3] = np.nan
    nodes[:, :, 10, 1] = np.nan
    with pytest.raises(InputError, match=r"^d.h5: split 'train': end caps rod1.1, rod5.0 never "
                       r"seen \(a rod's pose needs both of its end caps\)"):  # fmt: skip
        check_caps_seen(nodes, topo, "d.h5: split 'train'")
    nodes = np.random.default_rng(0).normal(size=(2, 30, 12, 3))
    nodes[:, ::3] = np.nan  # every third frame lost: no four consecutive samples
    with pytest.raises(InputError, match="no end cap is seen in four consecutive samples"):
        check_caps_seen(nodes, topo, "d.h5: split 'train'")
    nodes[1, 4:8] = np.random.default_rng(1).normal(size=(4, 12, 3))  # one run of four
    check_caps_seen(nodes, topo, "d.h5: split 'train'")


@pytest.mark.slow
def test_diagnose_runs_through_an_import_with_gaps(tmp_path: Path) -> None:
    import re

    from identification.data.mocap.c3d_files import write_c3d
    from identification.simulation.mocap_takes import record_take, simulate_caps

    asset = Path(__file__).resolve().parents[2] / "tensegrity_env/assets/icosahedron_rolling.xml"
    xml = re.sub(r'<geom name="floor"[^>]*/>', "", asset.read_text())
    (tmp_path / "free.xml").write_text(xml)
    rng = np.random.default_rng(5)
    for k in range(6):
        t, caps, names = simulate_caps(xml, 120.0, 0.6, rng)
        take = record_take(t, caps, names, rng, noise=1e-3, dropout=0.02)
        write_c3d(tmp_path / f"take{k}.c3d", take.points, names, 120.0)
    run = [sys.executable, "-m", "tensegrity_sr.cli"]
    files = sorted(str(p) for p in tmp_path.glob("take*.c3d"))
    subprocess.run([*run, "import-mocap", *files, "--robot", str(tmp_path / "free.xml"),
                    "-o", str(tmp_path / "d.h5")], check=True)  # fmt: skip
    r = subprocess.run([*run, "diagnose", str(tmp_path / "d.h5"), "--method", "trajectory",
                        "--max-effects", "1", "--anchor", "mass[rod0]=1.0", "-o",
                        str(tmp_path / "diag")], capture_output=True, text=True, check=False)  # fmt: skip
    assert r.returncode == 0, r.stderr
    found = re.search(r"test errors: end-cap RMS \(noisy, window states fitted\) ([0-9.]+) mm",
                      r.stdout)  # fmt: skip
    assert found is not None, r.stdout
    rms = float(found.group(1))
    assert rms < 1.3  # the declared model explains free flight to the 1 mm marker noise


def test_windows_the_gaps_left_out_start_at_other_defined_samples() -> None:
    """A gapped take's rod states are defined in short stretches: a tile per window keeps
    one window in a stretch; the windows the gaps removed start in those stretches
    instead (overlapping), so that the samples seen are fitted."""
    nodes = cubic_caps()
    grid = {k: np.zeros((2, 120, 2, w)) for k, w in (("p", 3), ("v", 3), ("q", 4), ("omega", 3))}
    grid["q"][..., 0] = 1.0
    grid["p"][:] = np.nan
    grid["p"][0, 40:52] = 0.0  # states defined over 12 samples of trajectory 0 only
    win = cut_windows(nodes, np.zeros((2, 119, 2, 3)), grid, 20, least=10)
    # 2 x 5 tiles of 23 samples: two keep a start (40 and 46), 8 more start within 40-51
    starts = win.start.tolist()
    assert win.traj.tolist() == [0] * len(starts) and len(starts) == 10
    assert starts == sorted(starts) and len(set(starts)) == len(starts)
    assert all(40 <= s < 52 for s in starts) and 40 in starts and 46 in starts
    assert all(torch.isfinite(x).all() for x in win.state.tensors())
    # up to ``least`` windows only, and none where the tiles give enough
    assert cut_windows(nodes, np.zeros((2, 119, 2, 3)), grid, 20, least=4).size == 4
    assert cut_windows(nodes, np.zeros((2, 119, 2, 3)), grid, 20).size == 2
    # without gaps the tiling is as it was: no overlapping windows
    grid["p"][:] = 0.0
    full = cut_windows(nodes, np.zeros((2, 119, 2, 3)), grid, 20)
    assert full.size == 10 and np.all(np.diff(full.start[full.traj == 0]) == full.steps)
