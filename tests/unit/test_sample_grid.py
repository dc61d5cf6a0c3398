"""Measured sample times onto the nominal grid; fits leave gaps out instead of filling them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from identification.data.dataset import Dataset, Split
from identification.data.end_caps import dataset_from_end_caps, with_measured_states
from identification.data.mocap.importer import read_robot
from identification.data.quality import quality_text, sample_quality
from identification.data.sample_grid import on_nominal_grid
from identification.linear.regression import SpringRodIdentifier
from identification.simulation.mocap_takes import simulate_caps
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.io_utils import InputError

ROBOT = Path(__file__).resolve().parents[2] / "tensegrity_env/assets/icosahedron_rolling.xml"


def one_split(time: np.ndarray, control: np.ndarray | None = None) -> Dataset:
    topo = icosahedron().topology
    T1 = time.shape[1]
    nodes = np.random.default_rng(0).normal(size=(time.shape[0], T1, 12, 3))
    ctrl = np.zeros((time.shape[0], T1 - 1, 6, 3)) if control is None else control
    return Dataset(topo, 0.01, {"train": Split(nodes=nodes, control=ctrl, time=time)})


def test_a_dropped_frame_becomes_a_gap_and_commands_are_held() -> None:
    t = np.array([[0.0, 0.01, 0.03, 0.04]])  # the frame at 0.02 s was dropped
    control = np.arange(3.0)[None, :, None, None] * np.ones((1, 3, 6, 3))
    ds = one_split(t, control)
    out, rep = on_nominal_grid(ds)
    s = out.split("train")
    assert s.time is None and s.nodes.shape[1] == 5
    np.testing.assert_array_equal(s.nodes[0, [0, 1, 3, 4]], ds.split("train").nodes[0])
    assert np.isnan(s.nodes[0, 2]).all()
    np.testing.assert_array_equal(s.control[0, :, 0, 0], [0.0, 1.0, 1.0, 2.0])
    assert (rep.kept, rep.empty, rep.left_out) == (4, 1, 0)


def test_jitter_within_a_tenth_of_a_step_is_kept_further_is_left_out() -> None:
    t = np.array([[0.0, 0.0104, 0.0197, 0.0331, 0.04, 0.0402]])
    ds = one_split(t)
    out, rep = on_nominal_grid(ds)
    s, raw = out.split("train"), ds.split("train").nodes[0]
    np.testing.assert_array_equal(
        s.nodes[0, [0, 1, 2, 4]], raw[[0, 1, 2, 4]]
    )  # 0.0402: a second at 0.04
    assert np.isnan(s.nodes[0, 3]).all()  # 0.0331 is 0.31 of a step off
    assert rep.left_out == 2 and rep.max_offset == pytest.approx(4e-4)


def test_times_on_the_grid_are_left_alone() -> None:
    ds = one_split(np.arange(6)[None] * 0.01)
    out, rep = on_nominal_grid(ds)
    assert out is ds and not rep.changed


@pytest.fixture(scope="module")
def flight() -> Dataset:
    """Clean end caps of the floorless icosahedron at 500 Hz (MuJoCo)."""
    xml = ROBOT.read_text().replace('<geom name="floor"', '<geom name="unused"')
    import re

    xml = re.sub(r'<geom name="unused"[^>]*/>', "", xml)
    rng = np.random.default_rng(3)
    caps = np.stack([simulate_caps(xml, 500.0, 0.6, rng)[1] for _ in range(4)])
    topo = read_robot(ROBOT).topology
    return dataset_from_end_caps(topo, 1 / 500, {"train": caps})


def test_the_regression_leaves_a_gap_out_rather_than_fitting_made_up_samples(
    flight: Dataset,
) -> None:
    def fit(nodes: np.ndarray) -> tuple[np.ndarray, int]:
        ds = dataset_from_end_caps(flight.topology, flight.dt, {"train": nodes})
        states = with_measured_states(ds, 0.014, "savgol")  # 7-sample windows
        est = SpringRodIdentifier(anchors={"mass[rod0]": 1.0}).fit(states)
        return est.params_.stiffness.numpy(), est.n_transitions_

    clean = flight.split("train").nodes
    full, n_full = fit(clean)
    gapped = clean.copy()
    gapped[1, 100:140, 3] = np.nan  # one end cap unseen for 80 ms
    with_gap, n_gap = fit(gapped)
    zeros = clean.copy()
    zeros[1, 100:140, 3] = 0.0  # what filling the gap with zeros would do
    filled, _ = fit(zeros)
    # exactly the transitions touching a sample whose filter window reaches the gap
    # (samples 97-142) are left out: t = 96 ... 142
    assert n_full - n_gap == 47
    assert np.isfinite(with_gap).all()
    # a gap read as zeros would have pulled the fit far away
    assert np.max(np.abs(filled / full - 1)) > 10 * np.max(np.abs(with_gap / full - 1))


def test_a_paused_recording_counts_dropped_frames_not_jitter() -> None:
    """Intervals of 1 step +- 0.3 ms and one of 100 s: 9999 frames dropped in a
    100-s pause, and the jitter is the 0.3 ms about whole steps, not seconds."""
    t = np.array([[0.0, 0.0103, 0.0200, 100.0200, 100.0300]])
    q = sample_quality(one_split(t))
    assert q.dropped_frames == 9999 and q.longest_pause == pytest.approx(100.0)
    assert q.max_jitter == pytest.approx(3e-4) and q.jitter < 3e-4
    line = quality_text(q, [f"c{i}" for i in range(12)]).splitlines()[0]
    assert "9999 dropped frames (longest pause 100 s)" in line


def test_a_timestamp_glitch_is_refused_before_its_grid_is_allocated() -> None:
    """One sample stamped 1e6 s late would need a grid of 1e8 steps (27 GB of end caps):
    refused with the split, the trajectory and the pause named."""
    t = np.arange(40)[None] * 0.01
    t[0, 25:] += 1e6
    with pytest.raises(InputError, match=r"split 'train', trajectory 0: 40 samples span "
                       r"100000040 steps .* longest pause is 1e\+06 s \(between samples 24 "
                       r"and 25\)"):  # fmt: skip
        on_nominal_grid(one_split(t))
    t = np.array([[0.0, 0.01, 0.05, 0.06]])  # 3 frames dropped: a grid of 7 steps is fine
    assert on_nominal_grid(one_split(t))[1].empty == 3
