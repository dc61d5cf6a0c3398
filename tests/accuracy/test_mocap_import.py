"""Motion-capture import on real files written through ezc3d and as CSV."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from identification.data.dataset import read_dataset
from identification.data.mocap.c3d_files import write_c3d
from identification.data.mocap.csv_files import write_motive_csv, write_plain_csv, write_vicon_csv
from identification.data.mocap.importer import read_robot, take_end_caps
from identification.data.mocap.recording import MarkerRecording
from identification.data.mocap.tsv_files import write_qtm_tsv
from identification.simulation.mocap_takes import record_take, simulate_caps

ROBOT = Path(__file__).resolve().parents[2] / "tensegrity_env" / "assets" / "icosahedron_rolling.xml"


@pytest.fixture(scope="module")
def clean() -> tuple[np.ndarray, np.ndarray, list[str]]:
    return simulate_caps(ROBOT.read_text(), 120.0, 1.0, np.random.default_rng(4))


def cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tensegrity_sr.cli", *map(str, args)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip


@pytest.mark.parametrize("fmt", ["c3d", "qtm", "motive", "vicon", "plain"])
def test_round_trip_with_a_15_frame_gap(tmp_path: Path, clean, fmt: str) -> None:
    time, caps, names = clean
    pts = caps.copy()
    pts[40:55, 3] = np.nan  # marker 3 lost for 15 frames
    path = tmp_path / {"c3d": "take.c3d", "qtm": "take.tsv"}.get(fmt, "take.csv")
    if fmt == "c3d":
        write_c3d(path, pts, names, 120.0, units="mm")
    elif fmt == "motive":
        write_motive_csv(path, time, pts, names, 120.0)
    elif fmt == "qtm":  # the gap written as QTM does: 0.000 in every coordinate
        write_qtm_tsv(path, pts, names, 120.0)
    elif fmt == "vicon":
        write_vicon_csv(path, pts, [f"ico:{n}" for n in names], 120.0)
    else:
        write_plain_csv(path, time, pts, names, units="m")
    out = tmp_path / "data.h5"
    extra = ("--units", "m") if fmt == "plain" else ()
    r = cli("import-mocap", path, "--robot", ROBOT, "--split", "1,0,0", *extra, "-o", out)
    assert r.returncode == 0, r.stderr
    ds = read_dataset(out)
    nodes = ds.split("train").nodes[0]
    assert ds.split("train").time is not None and abs(1 / ds.dt - 120.0) < 1e-6
    gap = ~np.isfinite(nodes).all(-1)
    assert gap[:, 3].sum() == 15 and gap.sum() == 15  # the gap is NaN, nothing else is
    precision = {"c3d": 1e-7 * 1e3, "qtm": 1e-6, "motive": 1e-6, "vicon": 1e-8, "plain": 1e-12}[fmt]  # file precision [m]
    np.testing.assert_allclose(nodes[~gap], caps[~gap], atol=precision)


def test_a_timestamp_glitch_is_refused_at_import(tmp_path: Path, clean) -> None:
    """A frame stamped 1e6 s late (its grid would be 1e8 steps): one line naming the
    file and the pause, exit 2, nothing written, before any labelling."""
    time, caps, names = clean
    time = time.copy()
    time[100:] += 1e6
    path, out = tmp_path / "take.csv", tmp_path / "data.h5"
    write_plain_csv(path, time, caps, names, units="m")
    r = cli("import-mocap", path, "--robot", ROBOT, "--units", "m", "-o", out)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == [
        f"error: {path}: {len(time)} samples span {len(time) + 120_000_000} steps of "
        f"{1 / 120:g} s; the longest pause is 1e+06 s (between samples 99 and 100): check the "
        "sample times, or cut the take at the pause"
    ]
    assert not out.exists()


@pytest.mark.parametrize("fault", ["swapped labels", "millimetres as metres"])
def test_rods_off_the_robots_length_are_refused_at_import(tmp_path: Path, clean, fault) -> None:
    """Two markers of different rods swapped, or a file in millimetres read as metres:
    the rods' end caps are not the robot's distance apart; one line names the rod."""
    time, caps, names = clean
    pts = caps.copy()
    if fault == "swapped labels":
        pts[:, [1, 2]] = pts[:, [2, 1]]
    else:
        pts = pts * 1e3
    path, out = tmp_path / "take.csv", tmp_path / "data.h5"
    write_plain_csv(path, time, pts, names, units="m")
    r = cli("import-mocap", path, "--robot", ROBOT, "--units", "m", "-o", out)
    assert r.returncode == 2 and "Traceback" not in r.stderr and not out.exists()
    line = r.stderr.strip().splitlines()[-1]
    apart = "1040" if fault != "swapped labels" else "0.3432"
    assert line.startswith(f"error: {path}: the end caps of rod0 are {apart} m apart "
                           f"(median over {len(time)} frames), the robot's are 1.04 m apart")  # fmt: skip


def test_millimetres_and_metres_give_the_same_end_caps(tmp_path: Path, clean) -> None:
    time, caps, names = clean
    for units in ("mm", "m"):
        write_plain_csv(tmp_path / f"{units}.csv", time, caps, names, units=units)
        assert cli("import-mocap", tmp_path / f"{units}.csv", "--robot", ROBOT, "--units", units,
                   "--split", "1,0,0", "-o", tmp_path / f"{units}.h5").returncode == 0  # fmt: skip
    a, b = (read_dataset(tmp_path / f"{u}.h5").split("train").nodes for u in ("mm", "m"))
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_unlabelled_export_with_new_ids_and_ghosts_is_labelled_back(clean) -> None:
    time, caps, names = clean
    robot = read_robot(ROBOT)
    take = record_take(time, caps, names, np.random.default_rng(0), noise=1e-3, dropout=0.03,
                       unlabelled=True, ghosts=0.1)  # fmt: skip
    assert len(take.names) > len(names) and (take.cap_of_track < 0).any()  # new ids and ghosts
    rec = MarkerRecording(Path("cloud.c3d"), take.time, take.points, take.names, 120.0).check()
    imp = take_end_caps(rec, robot, None)
    ok = imp.track_of_cap >= 0
    assert (take.cap_of_track[imp.track_of_cap[ok]] == np.nonzero(ok)[1]).all()  # no mislabel
    visible = np.zeros_like(ok)
    for j, c in enumerate(take.cap_of_track):
        if c >= 0:
            visible[:, c] |= np.isfinite(take.points[:, j]).all(-1)
    assert (ok == visible).all()  # every seen end cap found, nothing invented
    assert imp.ghosts == (take.cap_of_track < 0).sum()
    assert imp.relabelled_frames > 0


@pytest.mark.parametrize(
    "case, message",
    [
        ("truncated", "not a readable C3D file"),
        ("missing_column", "not one marker's x, y, z columns"),
        ("unknown_marker", "which is not in the file"),
        ("wrong_robot", "end caps"),
        ("commands_without_actuators", "--commands given, but the robot has no cable actuators"),
    ],
)
def test_bad_files_are_one_line_errors_and_leave_nothing(tmp_path: Path, clean, case: str, message: str) -> None:
    time, caps, names = clean
    robot, extra = ROBOT, []
    path = tmp_path / "take.c3d"
    write_c3d(path, caps, names, 120.0)
    if case == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif case == "missing_column":
        path = tmp_path / "take.csv"
        write_plain_csv(path, time, caps, names)
        lines = path.read_text().splitlines()
        path.write_text("\n".join(",".join(ln.split(",")[:-1]) for ln in lines) + "\n")
        extra = ["--units", "m"]
    elif case == "unknown_marker":
        (tmp_path / "map.yaml").write_text("markers:\n  nosuch: {rod: rod0, end: 0}\n")
        extra = ["--map", str(tmp_path / "map.yaml")]
    elif case == "commands_without_actuators":
        (tmp_path / "take_commands.csv").write_text("time,a0\n0.0,1.0\n")
        extra = ["--commands", str(tmp_path / "take_commands.csv")]
    else:
        write_c3d(path, caps[:, :6], names[:6], 120.0)  # 6 markers for 12 end caps
    out = tmp_path / "data.h5"
    r = cli("import-mocap", path, "--robot", robot, *extra, "-o", out)
    assert r.returncode == 2
    named = "take_commands.csv" if case == "commands_without_actuators" else path.name
    assert message in r.stderr and named in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not out.exists() and not list(tmp_path.glob(".data.h5*"))


def test_inspect_reports_rate_gaps_and_noise_of_an_import(tmp_path: Path) -> None:
    time, caps, names = simulate_caps(ROBOT.read_text(), 120.0, 2.0, np.random.default_rng(9))
    take = record_take(time, caps, names, np.random.default_rng(2), noise=1e-3, dropout=0.02)
    write_c3d(tmp_path / "take.c3d", take.points, names, 120.0)
    data = tmp_path / "data.h5"
    assert cli("import-mocap", tmp_path / "take.c3d", "--robot", ROBOT, "-o", data).returncode == 0
    r = cli("inspect", data, "--plot", tmp_path / "quality.png")
    assert r.returncode == 0, r.stderr
    assert "120 Hz nominal" in r.stdout and (tmp_path / "quality.png").stat().st_size > 10_000
    from identification.data.quality import sample_quality

    q = sample_quality(read_dataset(data))
    truth = 1 - np.isfinite(take.points).all(-1).mean(0)
    np.testing.assert_allclose(q.dropout, truth, atol=1e-12)
    assert np.all(np.abs(q.noise - 1e-3) < 0.25e-3)  # 1 mm planted, per end cap


def test_a_y_up_export_is_found_y_up_and_a_contradicting_up_is_refused(tmp_path: Path, clean) -> None:
    """Motive's default export is y-up: the floor the robot rolls on says so, and the
    import turns it z-up without ``--up``; ``--up z`` (the floor read as a wall) is
    refused in one line naming the axis."""
    from identification.data.mocap.recording import TO_Z_UP

    time, caps, names = clean
    write_motive_csv(tmp_path / "z.csv", time, caps, names, 120.0)
    write_motive_csv(tmp_path / "y.csv", time, caps @ TO_Z_UP["y"], names, 120.0)  # y-up file
    r = cli("import-mocap", tmp_path / "y.csv", "--robot", ROBOT, "--split", "1,0,0", "--up", "z",
            "-o", tmp_path / "bad.h5")  # fmt: skip
    assert r.returncode != 0 and "Traceback" not in r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert "--up z contradicts the data" in last and last.endswith("the file is y-up")
    assert not (tmp_path / "bad.h5").exists()
    for name in ("z", "y"):
        r = cli("import-mocap", tmp_path / f"{name}.csv", "--robot", ROBOT, "--split", "1,0,0",
                "-o", tmp_path / f"{name}.h5")  # fmt: skip
        assert r.returncode == 0, r.stderr
        assert f"up is {name} (the lowest end caps rest on a plane normal to {name}" in r.stdout
    a, b = (read_dataset(tmp_path / f"{u}.h5").split("train").nodes for u in ("z", "y"))
    np.testing.assert_allclose(b, a, atol=1e-6)  # the CSV's precision
    np.testing.assert_allclose(a[0], caps, atol=1e-6)


def test_swapped_labels_are_swapped_back_within_a_rod_and_dropped_across_rods(tmp_path: Path, clean) -> None:
    """Labelling errors of a labelled export: a rod's two markers swapped for 11 frames
    come back in place (no rod turns half a turn in 1/120 s); markers of two rods
    swapped for 5 frames leave both rods off their length there, read as unseen."""
    _, caps, names = clean
    pts = caps.copy()
    pts[60:71, [0, 1]] = caps[60:71, [1, 0]]  # rod0's end caps swapped
    pts[30:35, [2, 4]] = caps[30:35, [4, 2]]  # rod1's end 0 and rod2's end 0 swapped
    write_c3d(tmp_path / "take.c3d", pts, names, 120.0, units="m")
    r = cli("import-mocap", tmp_path / "take.c3d", "--robot", ROBOT, "--split", "1,0,0",
            "-o", tmp_path / "d.h5")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "relabelled frames 11," in r.stdout and "read as unseen 20;" in r.stdout
    nodes = read_dataset(tmp_path / "d.h5").split("train").nodes[0]
    unseen = ~np.isfinite(nodes).all(-1)
    assert unseen[30:35][:, [2, 3, 4, 5]].all() and unseen.sum() == 20
    np.testing.assert_allclose(nodes[~unseen], caps[~unseen], atol=1e-6)  # float32 file


def test_unlabelled_tracking_starts_at_the_first_frame_that_shows_every_end_cap(clean) -> None:
    """A take whose first 10 frames miss a marker: tracking starts at frame 10, from
    the robot's shape, and labels every end cap right from there."""
    time, caps, names = clean
    take = record_take(time, caps, names, np.random.default_rng(1), noise=1e-3, unlabelled=True)
    points = take.points.copy()
    points[:10, np.flatnonzero(take.cap_of_track == 5)] = np.nan  # end cap 5 hidden at first
    rec = MarkerRecording(Path("late.c3d"), take.time, points, take.names, 120.0).check()
    imp = take_end_caps(rec, read_robot(ROBOT), None)
    assert len(imp.time) == len(time) - 10 and imp.time[0] == time[10]
    ok = imp.track_of_cap >= 0
    assert ok.all() and (take.cap_of_track[imp.track_of_cap] == np.arange(12)).all()
    np.testing.assert_allclose(imp.caps, caps[10:], atol=6e-3)  # 1 mm noise, 6 sigma
