"""A take placed on the robot model's end caps and floor: markers beyond the caps moved
onto them, heights measured from the floor the resting stretches show."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from identification.data.dataset import read_dataset
from identification.data.mocap.placement import markers_onto_caps, place_take
from identification.data.mocap.stretches import Stretch
from tests.unit.test_optitrack_rows import export


def rods_tumbling(
    rng: np.random.Generator, F: int = 200, R: int = 3, length: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """End caps (F, 2R, 3) [m] of ``R`` rods ``length`` apart turning at 1-2 rad/s, and the
    frame times (F,) [s] at 120 Hz."""
    time = np.arange(F) / 120.0
    caps = np.empty((F, 2 * R, 3))
    for r in range(R):
        w, phase, centre = rng.uniform(1.0, 2.0), rng.uniform(0, np.pi), rng.normal(0, 0.2, 3)
        a = phase + w * time
        u = np.stack([np.cos(a), np.sin(a) * np.cos(0.3 * a), np.sin(a) * np.sin(0.3 * a)], -1)
        caps[:, 2 * r] = centre - 0.5 * length * u
        caps[:, 2 * r + 1] = centre + 0.5 * length * u
    return caps, time


def test_markers_beyond_the_caps_are_moved_onto_them_a_lone_marker_too() -> None:
    rng = np.random.default_rng(0)
    caps, time = rods_tumbling(rng)
    u = caps[:, 1::2] - caps[:, 0::2]
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    beyond = np.array([0.004, 0.0025, 0.0003])  # the last within the half millimetre left as it is
    markers = caps.copy()
    markers[:, 0::2] -= beyond[None, :, None] * u
    markers[:, 1::2] += beyond[None, :, None] * u
    markers += rng.normal(0, 5e-5, markers.shape)
    markers[100:103, 0] = np.nan  # rod 0's end 1 seen alone for 3 frames (25 ms) ...
    markers[150:170, 2] = np.nan  # ... rod 1's for 20 (0.17 s)
    placed, found = markers_onto_caps(markers, np.full(3, 0.5), time)
    np.testing.assert_allclose(found[:2], beyond[:2], atol=1e-4)
    assert found[2] == 0.0
    np.testing.assert_allclose(placed[:, 4:], markers[:, 4:])  # left as recorded
    seen = np.isfinite(placed).all(-1)
    np.testing.assert_allclose(placed[:, :4][seen[:, :4]], caps[:, :4][seen[:, :4]], atol=3e-4)
    assert seen[
        100:103, 1
    ].all()  # alone near frames that see its rod whole: moved along their axis
    assert not seen[158:162, 3].any()  # alone for longer: where its cap lies is not known
    assert seen[150:155, 3].all()


def test_the_floor_height_comes_from_the_resting_stretches() -> None:
    """A robot resting with its lowest caps one radius above a floor at 17 mm, lifted in
    the middle: heights are measured from the floor; a floor at z = 0 is left alone."""
    rng = np.random.default_rng(1)
    rest = np.array([[0.0, 0.0, 0.0], [0.3, 0.3, 0.4], [0.4, 0.1, 0.0], [0.1, 0.4, 0.3],
                     [0.3, 0.2, 0.0], [0.5, 0.3, 0.25]])  # fmt: skip
    time = np.arange(600) / 120.0
    lift = 0.3 * np.clip(np.sin(np.pi * (time - 2.0)), 0, None) * ((time > 2.0) & (time < 3.0))
    radius = np.full(3, 0.006)
    for floor in (0.017, 0.0):
        caps = rest[None] + [0.0, 0.0, floor + 0.006] + lift[:, None, None] * [0, 0, 1.0]
        caps += rng.normal(0, 5e-5, caps.shape)
        stretches = [
            Stretch(0.0, 2.0, "rest"),
            Stretch(2.0, 3.2, "external"),
            Stretch(3.2, 5.0, "rest"),
        ]
        lengths = np.linalg.norm(rest[0::2] - rest[1::2], axis=-1)
        placed, how = place_take(caps, time, stretches, lengths, radius)
        assert abs(how.floor - floor) < 1e-4
        assert how.shifted == (floor > 0)
        np.testing.assert_allclose(
            placed[..., 2], caps[..., 2] - (how.floor if how.shifted else 0.0)
        )


def test_an_import_places_markers_on_the_caps_and_the_floor_at_zero(tmp_path: Path) -> None:
    planted = export(tmp_path, np.random.default_rng(7), floor=0.017)
    r = subprocess.run([sys.executable, "-m", "tensegrity_sr.cli", "import-mocap", tmp_path / "take.csv",
                        "--robot", tmp_path / "prism.yaml", "--split", "1,0,0", "--segments", "0-2",
                        "--piece", "0", "-o", tmp_path / "take.h5"],
                       capture_output=True, text=True, check=False)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "the floor lies at z = 17.0 mm" in r.stdout
    data = read_dataset(tmp_path / "take.h5")
    caps = data.split("train").nodes[0]
    truth = planted["caps"][1:] - [0.0, 0.0, 0.017]  # type: ignore[index]
    perm = np.array([int(np.argmin(np.linalg.norm(truth[0] - c, axis=-1))) for c in caps[0]])
    seen = np.isfinite(caps).all(-1)
    np.testing.assert_allclose(caps[seen], truth[:, perm][seen], atol=5e-4)
    placed = json.loads(data.attrs["placement"])["take.csv"]
    assert abs(placed["floor_height_m"] - 0.017) < 1e-4 and placed["floor_shifted"]


def test_a_lone_marker_at_rest_keeps_the_axis_its_rod_had_at_rest() -> None:
    """One marker of a resting rod hidden for 1 s: its partner is placed along the axis
    the rod had while both were seen in that resting stretch; outside it, not."""
    time = np.arange(360) / 120.0
    caps = np.tile([[0.0, 0.0, 0.006], [0.3, 0.4, 0.006]], (360, 1, 1)) + np.random.default_rng(
        2
    ).normal(0, 5e-5, (360, 2, 3))
    u = np.array([0.6, 0.8, 0.0])
    markers = caps.copy()
    markers[:, 0] -= 0.004 * u
    markers[:, 1] += 0.004 * u
    markers[100:220, 0] = np.nan
    placed, found = markers_onto_caps(markers, np.array([0.5]), time, [Stretch(0.0, 3.0, "rest")])
    assert abs(found[0] - 0.004) < 1e-4
    np.testing.assert_allclose(placed[100:220, 1], caps[100:220, 1], atol=3e-4)
    placed, _ = markers_onto_caps(markers, np.array([0.5]), time, [Stretch(0.0, 3.0, "free")])
    assert np.isnan(placed[120:200, 1]).all()


def test_a_lost_cap_found_again_keeps_its_new_marker_distance(tmp_path: Path) -> None:
    """The prism at rest; one marker lost for 0.2 s comes back 12 mm farther out along its
    rod (a marker shifted on its cap), beyond the tracker's 1 cm rod-length gate: it is
    re-acquired, and tracked from then on at the rod's new marker distance."""
    from identification.data.mocap.labelling import label_clouds
    from tensegrity_env.ntrt import EXAMPLE_PRISM, from_ntrt

    (tmp_path / "prism.yaml").write_text(EXAMPLE_PRISM)
    robot = from_ntrt(tmp_path / "prism.yaml")
    rest = robot.rest_caps
    time = np.arange(240) / 120.0
    rng = np.random.default_rng(3)
    points = np.repeat(rest[None], 240, axis=0) + rng.normal(0, 5e-5, (240, 6, 3))
    u = (rest[1] - rest[0]) / np.linalg.norm(rest[1] - rest[0])
    points[100:124, 1] = np.nan
    points[124:, 1] += 0.012 * u
    lengths = np.linalg.norm(rest[0::2] - rest[1::2], axis=-1)
    lab = label_clouds(points, time, points[0], lengths, built=rest)
    seen = np.isfinite(lab.caps).all(-1)
    assert seen[130:].all() and lab.reacquired[1] == 1
    np.testing.assert_allclose(lab.caps[130:, 1], points[130:, 1])
