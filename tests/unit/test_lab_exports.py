"""Motion-capture exports as labs write them: placeholder positions, subject prefixes, Vicon CSV."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from identification.data.dataset import Dataset, Split, write_dataset
from identification.data.end_caps import check_caps_seen
from identification.data.mocap.csv_files import write_plain_csv
from identification.data.mocap.formats import read_recording
from identification.data.quality import placeholder_samples, sample_quality
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.io_utils import InputError


def noisy_walk(frames: int = 40, markers: int = 3, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return 1.0 + np.cumsum(rng.normal(0, 1e-3, (frames, markers, 3)), axis=0)


def test_held_runs_duplicated_frames_and_the_origin_are_placeholders_single_repeats_are_not() -> None:
    x = noisy_walk()
    x[10:14, 0] = x[10, 0]  # held over 4 frames: the 3 repeats are placeholders
    x[20:22, 1] = x[20, 1]  # one repeat (coarse quantisation can do that): kept
    x[30, 2] = 0.0  # an exporter's zero fill
    x[5, 2] = np.nan  # a gap stays a gap, not a placeholder
    mask = placeholder_samples(x)
    expected = np.zeros((40, 3), dtype=bool)
    expected[11:14, 0] = True
    expected[30, 2] = True
    np.testing.assert_array_equal(mask, expected)
    x[35] = x[34]  # a duplicated frame: every seen marker repeats the frame before
    expected[35] = True
    np.testing.assert_array_equal(placeholder_samples(x), expected)
    held = np.stack([x, x])  # leading (trajectory) axes
    np.testing.assert_array_equal(placeholder_samples(held), np.stack([expected, expected]))


def test_a_csv_with_zero_fills_and_held_markers_reads_them_as_unseen(tmp_path: Path) -> None:
    x = noisy_walk(frames=60, markers=2, seed=3)
    written = x.copy()
    written[20:30, 0] = written[19, 0]  # the tracker held marker a for 10 frames
    written[40:43, 1] = 0.0  # marker b zero-filled for 3 frames
    t = np.arange(60) / 120.0
    path = write_plain_csv(tmp_path / "take.csv", t, written, ["a", "b"])
    rec = read_recording(path, units="m")
    assert rec.placeholders == 13
    unseen = ~np.isfinite(rec.points).all(-1)
    assert unseen[20:30, 0].all() and unseen[40:43, 1].all() and unseen.sum() == 13
    np.testing.assert_allclose(rec.points[~unseen], x[~unseen], atol=1e-12)


def _dataset(nodes: np.ndarray) -> Dataset:
    asm = icosahedron()
    n, t1 = nodes.shape[:2]
    split = Split(nodes=nodes, control=np.zeros((n, t1 - 1, 6, 3)))
    return Dataset(topology=asm.topology, dt=1 / 120, splits={"train": split})


def test_identify_refuses_placeholders_in_a_dataset_by_name(tmp_path: Path) -> None:
    nodes = np.stack([noisy_walk(60, 12, seed=k) for k in range(2)])
    check_caps_seen(nodes, icosahedron().topology, "d.h5: split 'train'")
    nodes[1, 30:35, 7] = nodes[1, 29, 7]
    with pytest.raises(InputError, match=r"^d.h5: split 'train': 5 end-cap samples are "
                       r"placeholders .*rod3.1: 5\); write them as NaN"):  # fmt: skip
        check_caps_seen(nodes, icosahedron().topology, "d.h5: split 'train'")
    assert sample_quality(_dataset(nodes)).placeholders == 5
    write_dataset(tmp_path / "d.h5", _dataset(nodes))
    r = subprocess.run([sys.executable, "-m", "tensegrity_sr.cli", "identify", str(tmp_path / "d.h5"),
                        "-o", str(tmp_path / "p.json")], capture_output=True, text=True)  # fmt: skip
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert "5 end-cap samples are placeholders" in r.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "p.json").exists()


def test_marker_names_behind_a_subject_prefix_map_themselves() -> None:
    from identification.data.mocap.marker_map import default_map

    topo = icosahedron().topology
    names = [f"ico:{r.name}_{k}" for r in topo.rods for k in (0, 1)]
    mmap = default_map(["ico:origin", *names[::-1]], topo)
    assert mmap is not None
    assert {n: c for n, (c, _) in mmap.caps.items()} == {n: i for i, n in enumerate(names)}
    assert default_map(names[:-1], topo) is None  # an end cap unnamed: no implied map


VICON = """Devices
1000
,,Force Plate 1 - Force,,
Frame,Sub Frame,Fx,Fy,Fz
,,N,N,N
1,0,0.1,0.2,9.8
1,1,0.1,0.2,9.7

Trajectories
100
,,ico:rod0_0,,,ico:rod0_1,,
Frame,Sub Frame,X,Y,Z,X,Y,Z
,,mm,mm,mm,mm,mm,mm
7,0,1.0,2.0,3.0,4.0,5.0,6.0
8,0,1.5,2.5,3.5,,,
9,0,2.0,3.0,4.0,4.5,5.5,6.5

Model Outputs
100
"""


def test_a_vicon_nexus_export_reads_its_trajectories_section(tmp_path: Path) -> None:
    """Devices (force plates) before and model outputs after are not markers; times are
    the frame numbers over the rate, from the first exported frame."""
    path = tmp_path / "nexus.csv"
    path.write_text(VICON)
    rec = read_recording(path)
    assert rec.names == ["ico:rod0_0", "ico:rod0_1"] and rec.rate == 100.0
    np.testing.assert_allclose(rec.time, [0.0, 0.01, 0.02])
    np.testing.assert_allclose(rec.points[2, 1], [4.5e-3, 5.5e-3, 6.5e-3])
    assert np.isnan(rec.points[1, 1]).all() and np.isfinite(rec.points[1, 0]).all()
    path.write_text(VICON.replace("Frame,Sub Frame,X,Y,Z,X,Y,Z", "Frame,Sub Frame,X,Y,Z,X,Z,Y"))
    with pytest.raises(InputError, match=r"nexus.csv: marker columns are not X, Y, Z triples"):
        read_recording(path)


QTM = """NO_OF_FRAMES\t3
NO_OF_CAMERAS\t8
NO_OF_MARKERS\t2
FREQUENCY\t200
NO_OF_ANALOG\t0
DATA_INCLUDED\t3D
MARKER_NAMES\trod0_0\trod0_1
TRAJECTORY_TYPES\tMeasured\tMeasured
1.000\t2.000\t3.000\t4.000\t5.000\t6.000
1.500\t2.500\t3.500\t0.000\t0.000\t0.000
2.000\t3.000\t4.000\t4.500\t5.500\t6.500
"""


def test_a_qtm_tsv_export_without_frame_columns_reads_its_zero_fills_as_gaps(tmp_path: Path) -> None:
    path = tmp_path / "take.tsv"
    path.write_text(QTM)
    rec = read_recording(path)
    assert rec.names == ["rod0_0", "rod0_1"] and rec.rate == 200.0 and rec.placeholders == 1
    np.testing.assert_allclose(rec.time, [0.0, 0.005, 0.01])
    np.testing.assert_allclose(rec.points[2, 1], [4.5e-3, 5.5e-3, 6.5e-3])  # millimetres
    assert np.isnan(rec.points[1, 1]).all()
    path.write_text(QTM.replace("4.500\t5.500\t6.500", "4.500\t5.500"))
    with pytest.raises(InputError, match=r"take.tsv: row 11 has 5 of 6 columns"):
        read_recording(path)
    path.write_text(QTM.replace("FREQUENCY\t200\n", ""))
    with pytest.raises(InputError, match=r"take.tsv: not a QTM 3-D export"):
        read_recording(path)


def test_commands_hold_from_their_log_time_and_bad_logs_are_one_line_errors(tmp_path: Path) -> None:
    from identification.data.mocap.commands import hold_commands, read_commands, write_commands

    path = write_commands(tmp_path / "u.csv", np.array([0.0, 0.025, 0.07]),
                          np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]), ["a0", "a1"])  # fmt: skip
    t, u = read_commands(path, 2)
    frames = np.arange(10) / 120.0  # 0, 8.3, 16.7, 25.0 (the second command, to round-off), ...
    held = hold_commands(t, u, frames, "u.csv")
    np.testing.assert_array_equal(held[:, 0], [1, 1, 1, 3, 3, 3, 3, 3, 3, 5])
    with pytest.raises(InputError, match=r"^late.csv: the first command is logged at 0.01 s"):
        hold_commands(t + 0.01, u, frames, "late.csv")
    with pytest.raises(InputError, match=r"u.csv: 2 command columns, the robot has 3 cable actuators"):
        read_commands(path, 3)
    path.write_text("time,a0\n0.0,1\n0.0,2\n")
    with pytest.raises(InputError, match=r"u.csv: row 3, column 1: command times do not increase"):
        read_commands(path, 1)
    path.write_text("time,a0\n0.0,1\n\n0.1,up\n")  # a blank row still counts
    with pytest.raises(InputError, match=r"u.csv: row 4, column 2 \('a0'\): 'up' is not a number"):
        read_commands(path, 1)
    path.write_text("time,a0\n0.0,1\n0.1,inf\n")
    with pytest.raises(InputError, match=r"u.csv: row 3, column 2 \('a0'\): 'inf' is not a finite"):
        read_commands(path, 1)
    path.write_text("t,a0\n0.0,1\n")
    with pytest.raises(InputError, match=r"u.csv: command file must start with a header"):
        read_commands(path, 1)


def test_a_semicolon_csv_with_decimal_commas_reads_as_its_comma_twin(tmp_path: Path) -> None:
    x = noisy_walk(frames=20, markers=2, seed=5)
    t = np.arange(20) / 100.0
    plain = write_plain_csv(tmp_path / "plain.csv", t, x, ["rod0_0", "rod0_1"], units="mm")
    text = plain.read_text().replace(",", ";").replace(".", ",")  # a German spreadsheet's export
    (tmp_path / "excel.csv").write_text(text)
    a, b = read_recording(plain, units="mm"), read_recording(tmp_path / "excel.csv", units="mm")
    assert b.names == a.names and b.rate == a.rate
    np.testing.assert_array_equal(b.points, a.points)
    np.testing.assert_array_equal(b.time, a.time)


def test_inspect_looks_at_a_take_before_import_and_stops_quietly_when_piped_to_head(
    tmp_path: Path,
) -> None:
    t = np.arange(200) / 100.0
    smooth = np.stack([np.sin(t), np.cos(t), 1 + 0.5 * t**2], -1)  # (200, 3) [m]
    x = smooth[:, None] + np.random.default_rng(7).normal(0, 1e-3, (200, 60, 3))
    x[50:90, 3] = np.nan  # marker 3 lost for 40 frames (0.4 s)
    x[120:125, 5] = x[119, 5]  # marker 5 held
    path = write_plain_csv(tmp_path / "take.csv", t, x,
                           [f"m{k}" for k in range(60)], units="mm")  # fmt: skip
    cli = [sys.executable, "-m", "tensegrity_sr.cli", "inspect", str(path), "--units", "mm"]
    r = subprocess.run(cli, capture_output=True, text=True, check=True)
    lines = r.stdout.splitlines()
    assert lines[0].endswith("200 frames at 100 Hz (1.99 s), 60 labelled markers, 0.38 % of samples unseen")  # 40 + 5
    assert "placeholder samples read as unseen: 5" in lines
    m3 = next(ln for ln in lines if ln.split()[0] == "m3").split()
    assert m3[1:3] == ["80.00", "%"] and m3[3] == "400.0"
    noise = float(next(ln for ln in lines if ln.split()[0] == "m0").split()[5])
    assert 0.8 < noise < 1.2  # 1 mm white noise on a smooth path
    assert lines[-1] == "  ... and 20 more"
    piped = subprocess.run(" ".join(cli) + " | head -n 1", shell=True, capture_output=True, text=True)
    assert piped.stdout.count("\n") == 1 and piped.stderr == ""


def test_markers_a_constant_distance_off_the_caps_are_not_read_as_labelling_errors() -> None:
    """Markers 3.5 cm beyond both end caps of a 1 m rod (a map without offsets) sit 7 %
    off the rod's length in every frame: its usual distance, nothing rejected; a frame
    in which one marker is another rod's is."""
    from identification.data.mocap.importer import checked_labels

    rng = np.random.default_rng(2)
    t = np.arange(100) / 120.0
    axis = np.stack([np.cos(t), np.sin(t), 0 * t], -1)  # (F, 3), turning slowly
    centre = np.array([0.0, 0.0, 0.5]) + rng.normal(0, 1e-3, (100, 3))
    caps = np.stack([centre - 0.535 * axis, centre + 0.535 * axis], 1)  # 1.07 m apart
    caps += rng.normal(0, 1e-3, caps.shape)
    out, swapped, rejected = checked_labels(caps, np.array([1.0]))
    assert swapped == [] and rejected == 0
    caps[40, 1] = caps[40, 0] + [0.0, 0.0, 0.6]  # another rod's marker
    out, swapped, rejected = checked_labels(caps, np.array([1.0]))
    assert swapped == [] and rejected == 2 and np.isnan(out[40]).all()


def test_diagnose_refuses_end_caps_with_cable_commands_before_any_fit(tmp_path: Path) -> None:
    import re

    from tensegrity_env.mjcf import from_mjcf

    asset = Path(__file__).resolve().parents[2] / "tensegrity_env/assets/icosahedron_rolling.xml"
    xml = re.sub(r"<actuator>.*</actuator>",
                 '<actuator><general name="a0" tendon="spring0" gainprm="-40"/></actuator>',
                 asset.read_text(), flags=re.S)  # fmt: skip
    (tmp_path / "robot.xml").write_text(xml)
    topo = from_mjcf(tmp_path / "robot.xml").topology
    nodes = np.stack([noisy_walk(60, 12, seed=k) for k in range(2)])
    split = Split(nodes=nodes, control=np.zeros((2, 59, 6, 3)), cable_control=np.ones((2, 59, 1)))
    write_dataset(tmp_path / "d.h5", Dataset(topology=topo, dt=1 / 120, splits={"train": split}))
    r = subprocess.run([sys.executable, "-m", "tensegrity_sr.cli", "diagnose", str(tmp_path / "d.h5"),
                        "--anchor", "mass[rod0]=2.0", "-o", str(tmp_path / "out")],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "cable actuator commands: the trajectory method of diagnose does not apply them" in r.stderr
    assert not (tmp_path / "out").exists()
