"""OptiTrack row-format exports with re-issued ids, ghosts and repeated frames, imported
with an NTRT robot and no --up: labelled up to the robot's symmetry, the vertical found."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from identification.data.dataset import read_dataset
from identification.data.mocap.formats import read_recording
from identification.data.mocap.optitrack_rows import write_optitrack_rows
from identification.data.mocap.vertical import find_vertical, free_flight
from identification.data.quality import repeated_frames
from tensegrity_env.io_utils import InputError
from tensegrity_env.ntrt import EXAMPLE_PRISM as PRISM
from tensegrity_env.ntrt import from_ntrt
from tensegrity_env.rotations import TO_Z_UP, axis_angle_to_quat, np_quat_to_matrix

RATE = 120.0
G = 9.81


def motion(rest: np.ndarray, beyond: float = 0.003) -> tuple[np.ndarray, np.ndarray]:
    """Markers (F, 6, 3) [m], z up, ``beyond`` [m] beyond the end caps along each rod:
    resting on the floor, lifted and turned by a hand, dropped (free fall), resting
    again."""
    time = np.arange(int(2.0 * RATE)) / RATE
    axis = rest[1::2] - rest[0::2]
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    markers = rest.copy()
    markers[0::2] -= beyond * axis
    markers[1::2] += beyond * axis
    centre = markers.mean(0)
    lift, fall = 0.8, 1.2  # [s]
    drop = np.sqrt(2 * 0.2 / G)
    out = np.empty((len(time), 6, 3))
    for f, t in enumerate(time):
        s = np.clip((t - lift) / (fall - lift), 0.0, 1.0)
        turn = np_quat_to_matrix(axis_angle_to_quat(np.array([0.0, 0, 1]), 0.5 * (1 - np.cos(np.pi * s))))
        if t < fall:
            h = 0.2 * 0.5 * (1 - np.cos(np.pi * s))
        else:
            h = max(0.0, 0.2 - 0.5 * G * (t - fall) ** 2) if t < fall + drop else 0.0
        out[f] = (markers - centre) @ turn.T + centre + [0, 0, h]
    return time, out


def export(tmp_path: Path, rng: np.random.Generator, floor: float = 0.0) -> dict[str, object]:
    """A row-format take of the prism in y-up file coordinates, its floor at height
    ``floor`` [m] (the end caps resting one rod radius above it); returns what was
    planted: ``truth`` the markers, ``caps`` the end caps (z-up)."""
    (tmp_path / "prism.yaml").write_text(PRISM)
    robot = from_ntrt(tmp_path / "prism.yaml")
    lift = floor + robot.topology.rods[0].radius  # the rest pose's lowest caps lie at z = 0
    time, truth = motion(robot.rest_caps + np.array([0, 0, lift]))
    _, caps = motion(robot.rest_caps + np.array([0, 0, lift]), beyond=0.0)
    F = len(time)
    file_xyz = truth @ TO_Z_UP["y"]  # z-up -> the file's y-up
    pts = file_xyz + rng.normal(0, 5e-5, file_xyz.shape)
    ids = np.tile(np.arange(100, 106), (F, 1))
    visible = np.ones((F, 6), dtype=bool)
    visible[0] = False  # an empty first frame
    visible[60:70, 2] = False  # lost, found again under a new id
    ids[70:, 2] = 500
    visible[150:156, 4] = False  # lost during the drop
    ids[156:, 4] = 501
    ghost_far = np.tile([2.0, -1.0, 0.5], (F, 1))  # a static reflection
    ghost_near = pts[:, 0] + [0.0, 0.08, 0.0]  # a flicker 8 cm from a cap, now and then
    near_on = (np.arange(F) % 10 == 5) & (np.arange(F) > 0)
    pts = np.concatenate([pts, ghost_far[:, None], ghost_near[:, None]], axis=1)
    ids = np.concatenate([ids, np.full((F, 1), 900), (1000 + np.arange(F))[:, None]], axis=1)
    visible = np.concatenate([visible, np.ones((F, 1), dtype=bool), near_on[:, None]], axis=1)
    visible[0] = False
    repeated = (np.arange(F) % 4 == 3) & (np.arange(F) > 1)  # every 4th frame repeats the one before
    for f in np.flatnonzero(repeated):
        pts[f] = pts[f - 1] + rng.normal(0, 1e-8, pts[f].shape)
        visible[f], ids[f] = visible[f - 1], ids[f - 1]
    write_optitrack_rows(tmp_path / "take.csv", time, np.where(visible[..., None], pts, np.nan),
                         np.where(visible, ids, -1))  # fmt: skip
    return {"time": time, "truth": truth, "caps": caps, "visible": visible[:, :6], "repeated": repeated,
            "ghost_samples": int(visible[~repeated, 6:].sum())}  # fmt: skip


def cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tensegrity_sr.cli", *map(str, args)],
                          capture_output=True, text=True, check=False)  # fmt: skip


def test_row_format_is_read_with_its_ids_and_repeated_frames_become_gaps(tmp_path: Path) -> None:
    planted = export(tmp_path, np.random.default_rng(0))
    rec = read_recording(tmp_path / "take.csv")
    assert rec.unlabelled and rec.rate == pytest.approx(RATE)
    assert rec.repeated_frames == int(planted["repeated"].sum())  # type: ignore[union-attr]
    assert np.isnan(rec.points[planted["repeated"]]).all()  # type: ignore[index]
    assert rec.ids is not None and {100, 500, 501, 900} <= set(rec.ids.ravel().tolist())
    # ids are packed into as many columns as markers are seen at once, not one per id
    assert rec.points.shape[1] < len(set(rec.ids.ravel().tolist()) - {-1})


def test_an_unlabelled_take_is_labelled_up_to_symmetry_and_set_upright(tmp_path: Path) -> None:
    planted = export(tmp_path, np.random.default_rng(1))
    r = cli("import-mocap", tmp_path / "take.csv", "--robot", tmp_path / "prism.yaml", "--split", "1,0,0",
            "--segments", "0-2", "--piece", "0", "-o", tmp_path / "take.h5")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "up is y (free flight" in r.stdout and "tracking per end cap" in r.stdout
    # the hand's lift (0.8-1.2 s) is found, the whole take kept as --segments names it
    assert "external 0.7" in r.stdout and "the fit uses 0.01-2.00 s" in r.stdout
    caps = read_dataset(tmp_path / "take.h5").split("train").nodes[0]  # tracking starts at frame 1
    # the markers, 3 mm beyond the end caps, are placed onto them; the floor is at z = 0
    assert "3.0 to 3.0 mm beyond the model's end caps along 3 rods" in r.stdout
    truth, visible, repeated = planted["caps"][1:], planted["visible"][1:], planted["repeated"][1:]  # type: ignore[index]
    # one labelling of the robot's symmetric ones: a permutation of the caps keeping rods whole
    perm = np.array([int(np.argmin(np.linalg.norm(truth[0] - c, axis=-1))) for c in caps[0]])
    assert sorted(perm.tolist()) == list(range(6))
    assert all(perm[2 * r] // 2 == perm[2 * r + 1] // 2 for r in range(3))
    seen = np.isfinite(caps).all(-1)
    np.testing.assert_array_equal(seen, (visible & ~repeated[:, None])[:, perm])  # nothing lost, nothing invented
    np.testing.assert_allclose(caps[seen], truth[:, perm][seen], atol=5e-4)  # 0.05 mm noise


def test_a_given_up_that_the_data_contradicts_is_refused(tmp_path: Path) -> None:
    export(tmp_path, np.random.default_rng(2))
    r = cli("import-mocap", tmp_path / "take.csv", "--robot", tmp_path / "prism.yaml", "--up", "z",
            "-o", tmp_path / "take.h5")  # fmt: skip
    assert r.returncode != 0 and "Traceback" not in r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert "--up z contradicts the data: free flight" in last and last.endswith("the file is y-up")
    assert not (tmp_path / "take.h5").exists()


def test_the_floor_gives_the_vertical_without_free_flight() -> None:
    """A robot resting on a floor normal to -x (file coordinates), lifted for a while:
    the floor, and the lift that leaves it upwards, say up is -x."""
    rest = np.array([[0.0, 0.01, 0.02], [0.0, 0.31, 0.52], [0.0, 0.43, 0.11], [0.3, 0.07, 0.41],
                     [0.25, 0.33, 0.17], [0.12, 0.52, 0.33]])  # three caps on the floor x = 0
    rest[:, 0] *= -1  # up is -x: the robot at x <= 0
    time = np.arange(600) / 120.0
    lift = np.clip(np.sin(np.pi * (time - 2.0) / 1.5), 0, None) * ((time > 2.0) & (time < 3.5))
    caps = rest[None] + (-0.3 * lift)[:, None, None] * np.array([1.0, 0, 0])
    caps += np.random.default_rng(3).normal(0, 1e-4, caps.shape)
    found = find_vertical(caps, time)
    assert found is not None and found.axis == "-x" and "plane normal to x" in found.evidence
    assert "leaves it goes towards -x" in found.evidence


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda row: row.replace(",8,", ",8,O", 1), "column 6: marker 1 x 'O"),
        (lambda row: row.rsplit(",", 5)[0], "cells, but 0 rigid bodies and 8 markers make 45"),
        (lambda row: row.replace("frame,5,", "frame,five,", 1), "row 11, column 2: frame index 'five'"),
    ],
)
def test_malformed_rows_are_one_line_errors_naming_row_and_column(tmp_path: Path, edit, message: str) -> None:  # type: ignore[no-untyped-def]
    export(tmp_path, np.random.default_rng(4))
    lines = (tmp_path / "take.csv").read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("frame,5,"))
    lines[k] = edit(lines[k])
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as e:
        read_recording(tmp_path / "bad.csv")
    text = str(e.value)
    assert "bad.csv" in text and f"row {k + 1}" in text and message in text and "\n" not in text


def test_a_copy_of_the_frame_before_is_repeated_a_still_robot_is_not() -> None:
    """Markers at rest with 30 µm noise (the finest optical systems) never repeat within
    1 µm; an exporter's copy to 1e-8 m does."""
    rng = np.random.default_rng(5)
    x = np.ones((50, 12, 3)) + rng.normal(0, 3e-5, (50, 12, 3))
    x[20] = x[19] + rng.normal(0, 1e-8, (12, 3))
    x[30, 3:] = x[29, 3:]  # a partial copy: three markers moved
    x[40, :] = np.nan
    x[40, 0] = x[39, 0]  # one marker alone is no frame
    np.testing.assert_array_equal(np.flatnonzero(repeated_frames(x)), [20])


def test_marker_noise_makes_no_free_flight() -> None:
    """A robot resting on a z floor, its markers 1 mm noisy at 120 Hz: the noise's
    accelerations reach g now and then, but never measured well enough to be a flight."""
    rest = np.array([[0.0, 0.01, 0.0], [0.31, 0.52, 0.3], [0.43, 0.11, 0.0], [0.07, 0.41, 0.3],
                     [0.33, 0.17, 0.0], [0.52, 0.33, 0.25]])  # fmt: skip
    time = np.arange(240) / 120.0
    caps = rest[None] + np.random.default_rng(6).normal(0, 1e-3, (240, 6, 3))
    assert free_flight(caps, time) is None
    found = find_vertical(caps, time)
    assert found is not None and found.axis == "z"


def test_an_export_cut_short_in_its_header_is_named_as_such(tmp_path: Path) -> None:
    """A row-format export that ends among its comment rows is not taken for a plain CSV."""
    export(tmp_path, np.random.default_rng(5))
    lines = (tmp_path / "take.csv").read_text().splitlines()
    info = next(i for i, line in enumerate(lines) if line.startswith("info,"))
    header = ['comment,"OptiTrack Export Data"', 'comment,"== Data is formatted in rows."']
    (tmp_path / "cut.csv").write_text("\n".join([*header, *lines[:info]]) + "\n")
    with pytest.raises(InputError) as e:
        read_recording(tmp_path / "cut.csv")
    text = str(e.value)
    assert "cut.csv" in text and "row-format export ends in its comment header" in text and "\n" not in text
    (tmp_path / "plain.csv").write_text("comment,x\n1,2\n")  # not every row a row type: plain CSV
    with pytest.raises(InputError, match="first column must be 'time'"):
        read_recording(tmp_path / "plain.csv")
