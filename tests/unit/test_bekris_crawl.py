"""The 3-bar crawl's converter (``benchmarks/bekris_crawl.py``) on a tiny take in the
lab's JSON layout the test writes: end caps and command log in the general formats,
the robot at physical scale with winch cables, and import-mocap reading them with each
sample's own time and the winch commands."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from bekris_crawl import LENGTH, MASS, MOTOR_TOP_SPEED, convert, main

from identification.data.dataset import read_dataset
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import from_mjcf
from tensegrity_sr.cli import main as cli

#: the prism's end caps in the lab's units (x10 m): rod r joins caps 2r and 2r + 1
CAPS = np.array([[-1.62, 0.07, 0.175], [0.92, 0.41, 2.17], [-0.41, -1.83, 0.86],
                 [0.06, 1.31, 0.175], [-1.04, -0.17, 2.42], [1.24, -0.74, 0.175]])  # fmt: skip
RODS = ("rod_01", "rod_23", "rod_45")
#: actuated cables (sites) then passive ones, as the lab's config lists them
WOUND = (("s_3", "s_5"), ("s_1", "s_3"), ("s_1", "s_5"), ("s_0", "s_2"), ("s_0", "s_4"), ("s_2", "s_4"))
PASSIVE = (("s_2", "s_5"), ("s_0", "s_3"), ("s_1", "s_4"))
#: uneven record times [s] (Unix), as the robot logs its messages
TIMES = (1677021256.856, 1677021256.963, 1677021256.965, 1677021257.05, 1677021258.056)


def lab_config() -> dict:
    rods = [{"name": n, "end_pts": CAPS[2 * r : 2 * r + 2].tolist(), "radius": 0.016, "sphere_radius": 0.175,
             "sphere_mass": 10.5, "mass": 41.8, "sites": [f"s_{2 * r}", f"s_{2 * r + 1}"]}
            for r, n in enumerate(RODS)]  # fmt: skip
    springs = [{"name": f"spring_{k}", "type": "actuated_cable", "winch_r": 0.035, "motor_speed": 0.8,
                "stiffness": 100000, "damping": 1000, "rest_length": 2.7, "init_act_length": 0.6,
                "end_pts": list(e)} for k, e in enumerate(WOUND)]  # fmt: skip
    springs += [{"name": f"spring_{6 + k}", "type": "cable", "stiffness": 10000, "damping": 1000,
                 "rest_length": 1.65, "end_pts": list(e)} for k, e in enumerate(PASSIVE)]  # fmt: skip
    return {"gravity": [0, 0, -9.81], "contact_params": {"friction": 0.92},
            "tensegrity_robot_config": {"rods": rods, "springs": springs}}  # fmt: skip


def lab_take(folder: Path, records: list[dict] | None = None) -> Path:
    """The lab's folder layout with its config and a take of :data:`TIMES`."""
    (folder / "raw").mkdir(parents=True)
    (folder / "robot" / "configs").mkdir(parents=True)
    (folder / "robot" / "configs" / "3_bar_tensegrity_upscaled_5d.json").write_text(json.dumps(lab_config()))
    if records is None:
        records = []
        for k, t in enumerate(TIMES):
            rec: dict = {"time": t, "controls": [1.0, 1.0, 0.0, -1.0, 0.0, 1.0 if k < 3 else 0.0]}
            for r, n in enumerate(RODS):
                rec[f"{n}_end_pt1"] = (CAPS[2 * r] + [0.01 * k, 0, 0]).tolist()
                rec[f"{n}_end_pt2"] = (CAPS[2 * r + 1] + [0.01 * k, 0, 0]).tolist()
            records.append(rec)
    (folder / "raw" / "5d_processed_data.json").write_text(json.dumps(records))
    return folder


def test_the_take_becomes_a_plain_csv_a_command_log_and_a_winch_robot(tmp_path: Path) -> None:
    files = convert(lab_take(tmp_path / "lab"), tmp_path / "out")
    rows = files.caps.read_text().splitlines()
    assert rows[0].startswith("time,rod_01_0_x,rod_01_0_y,rod_01_0_z,rod_01_1_x")
    table = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    assert np.allclose(table[:, 0], np.array(TIMES) - TIMES[0], atol=1e-6)  # uneven, as logged
    assert np.allclose(table[0, 1:].reshape(6, 3), CAPS * LENGTH)  # x10 units to metres
    log = files.commands.read_text().splitlines()
    assert log[0] == "time," + ",".join(f"spring_{k}" for k in range(6))
    # the lab's +1 winds a cable in (shorter): a winch command here lengthens at +1
    assert [float(x) for x in log[1].split(",")[1:]] == [-1.0, -1.0, 0.0, 1.0, 0.0, -1.0]
    robot = from_mjcf(files.robot)
    topo, p = robot.topology, robot.params
    assert [r.name for r in topo.rods] == list(RODS)
    assert topo.n_winches == 6 and [topo.springs[s].name for s in topo.winches] == [f"spring_{k}" for k in range(6)]
    assert np.allclose(p.winch_speed.numpy(), 0.8 * MOTOR_TOP_SPEED * 0.035 * LENGTH)
    assert math.isclose(float(p.winch_speed[0]), 0.0645, rel_tol=1e-3)  # m/s
    assert np.allclose(p.winch_max.numpy(), 0.27) and np.allclose(p.winch_min.numpy(), 0.0)
    assert np.allclose(p.rest_length.numpy(), [0.21] * 6 + [0.165] * 3)  # wound in by 0.06 m at the start
    assert np.allclose(p.stiffness.numpy(), [100000 * MASS] * 6 + [10000 * MASS] * 3)
    assert np.allclose(p.mass.numpy(), 41.8 * MASS)
    ends = np.stack([topo.end_offsets[r, 1] - topo.end_offsets[r, 0] for r in range(3)])
    assert np.allclose(np.linalg.norm(ends, axis=1), np.linalg.norm(CAPS[1::2] - CAPS[0::2], axis=1) * LENGTH)
    h5 = tmp_path / "take.h5"
    assert cli(["import-mocap", str(files.caps), "--robot", str(files.robot), "--units", "m", "--up", "z",
                "--commands", str(files.commands), "--split", "1,0,0", "-o", str(h5)]) == 0  # fmt: skip
    split = read_dataset(h5).split("train")
    assert np.allclose(split.time[0], np.array(TIMES) - TIMES[0], atol=1e-6)
    assert np.allclose(split.winch_control[0, :, 5], [-1, -1, -1, 0])  # held from each record on


def test_a_broken_record_is_named(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    folder = lab_take(tmp_path / "lab", records=[{"time": 1.0, "controls": [0] * 6}])
    with pytest.raises(InputError, match=r"record 0: missing or not numeric: 'rod_01_end_pt1'"):
        convert(folder, tmp_path / "out")
    assert main([str(folder), "-o", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.startswith("error: ")
