"""The HDF5 dataset: round trip, hidden ground truth, measured data, and bad input."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from identification.data.dataset import (
    STATE_KEYS,
    Dataset,
    GroundTruth,
    read_dataset,
    read_ground_truth,
    write_dataset,
)
from identification.data.end_caps import dataset_from_end_caps
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import FIELDS
from tensegrity_sr.cli import main

EXAMPLE_MJCF = Path(__file__).resolve().parents[2] / "docs" / "examples" / "x_tensegrity.xml"


@cache
def _generated() -> tuple[Dataset, GroundTruth]:
    spec = GenerateSpec(n_train=3, n_val=2, n_test=1, steps=40, seed=7, control_std=0.5)
    return generate_dataset(spec)


def _write(tmp_path: Path, name: str = "data.h5") -> Path:
    ds, truth = _generated()
    return write_dataset(tmp_path / name, ds, truth)


def test_round_trip_keeps_every_array_bit_for_bit(tmp_path: Path) -> None:
    ds, _ = _generated()
    back = read_dataset(_write(tmp_path))
    assert back.topology.same_as(ds.topology)
    assert back.dt == ds.dt == 1e-3
    assert set(back.splits) == {"train", "val", "test"}
    for name, split in ds.splits.items():
        for k in ("nodes", "control", *STATE_KEYS):
            assert np.array_equal(getattr(back.splits[name], k), getattr(split, k)), (name, k)
    assert back.attrs["assembly"] == "icosahedron"
    assert back.attrs["seed"] == 7
    assert back.attrs["source"].startswith("mujoco ")
    assert back.n_steps == ds.n_steps == (3 + 2 + 1) * 40


def test_ground_truth_is_stored_apart_and_not_read_by_read_dataset(tmp_path: Path) -> None:
    _, truth = _generated()
    path = _write(tmp_path)
    back = read_dataset(path)
    assert not any("ground" in k or "params" in k for k in back.attrs)
    stored = read_ground_truth(path)
    assert stored is not None
    for f in FIELDS:
        assert torch.equal(getattr(stored.params, f), getattr(truth.params, f)), f
    assert stored.sim["timestep"] == 1e-3 and stored.sim["integrator"] == "Euler"
    assert "<mujoco" in stored.mjcf


def test_measured_end_caps_make_a_dataset_without_states(tmp_path: Path, capsys) -> None:
    ds, _ = _generated()
    train = ds.splits["train"].nodes
    measured = dataset_from_end_caps(
        ds.topology, ds.dt, {"train": train, "test": train[0]}, attrs={"source": "mocap"}
    )
    path = write_dataset(tmp_path / "mocap.h5", measured)
    back = read_dataset(path)
    assert not back.splits["train"].has_states
    assert back.splits["test"].n_trajectories == 1
    assert np.array_equal(back.splits["train"].nodes, train)
    assert np.all(back.splits["train"].control == 0)
    assert read_ground_truth(path) is None
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "end caps only" in out and "ground truth: none" in out


def test_end_cap_helper_rejects_bad_arrays() -> None:
    ds, _ = _generated()
    nodes = ds.splits["train"].nodes
    with pytest.raises(InputError, match="expected"):
        dataset_from_end_caps(ds.topology, ds.dt, {"train": nodes[..., :5, :]})
    with pytest.raises(InputError, match="NaN"):
        bad = nodes.copy()
        bad[0, 3, 2, 1] = np.nan
        dataset_from_end_caps(ds.topology, ds.dt, {"train": bad})
    with pytest.raises(InputError, match="train"):
        dataset_from_end_caps(ds.topology, ds.dt, {"val": nodes})


def test_inspect_hides_the_ground_truth_unless_asked(tmp_path: Path, capsys) -> None:
    path = _write(tmp_path)
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "6 rods, 24 springs, 0 world anchors" in out
    assert "dt = 1 ms" in out
    assert "train  N =     3  T =    40" in out
    assert "240 steps" in out
    assert "rod states (p, v, q, omega)" in out
    assert "ground truth: present" in out and "stiffness" not in out
    assert main(["inspect", str(path), "--ground-truth"]) == 0
    out = capsys.readouterr().out
    assert "stiffness [N/m]" in out and "control_gain" in out


# ---------------------------------------------------------------------- bad input
def _one_line_error(capsys, argv: list[str], *fragments: str) -> str:
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("error: "), lines[0]
    assert "Traceback" not in captured.err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def test_missing_file(tmp_path: Path, capsys) -> None:
    path = tmp_path / "nope.h5"
    _one_line_error(capsys, ["inspect", str(path)], str(path), "no such")


def test_truncated_file(tmp_path: Path, capsys) -> None:
    path = _write(tmp_path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    _one_line_error(capsys, ["inspect", str(path)], str(path))


def test_not_an_hdf5_file(tmp_path: Path, capsys) -> None:
    path = tmp_path / "notes.h5"
    path.write_text("these are not trajectories\n")
    _one_line_error(capsys, ["inspect", str(path)], str(path), "HDF5")


def test_hdf5_file_that_is_not_a_dataset(tmp_path: Path, capsys) -> None:
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.zeros(3)
    _one_line_error(capsys, ["inspect", str(path)], str(path), "not a tensegrity-sr dataset")


def test_nan_in_states(tmp_path: Path, capsys) -> None:
    path = _write(tmp_path)
    with h5py.File(path, "r+") as f:
        f["splits/val/omega"][1, 5, 2, 0] = np.nan
    _one_line_error(capsys, ["inspect", str(path)], str(path), "'omega'", "NaN")


def test_wrong_shapes(tmp_path: Path, capsys) -> None:
    path = _write(tmp_path)
    with h5py.File(path, "r+") as f:
        v = f["splits/train/v"][()]
        del f["splits/train/v"]
        f["splits/train/v"] = v[:, :, :5]
    _one_line_error(capsys, ["inspect", str(path)], str(path), "'v' has shape")
    with h5py.File(path, "r+") as f:
        del f["splits/train/v"]
        f["splits/train/v"] = v
        del f["splits/test/nodes"]
        f["splits/test/nodes"] = np.zeros((1, 41, 12, 2))
    _one_line_error(capsys, ["inspect", str(path)], str(path), "nodes have shape")


def _bad_mjcf(tmp_path: Path, old: str, new: str) -> Path:
    text = EXAMPLE_MJCF.read_text()
    assert old in text
    path = tmp_path / "robot.xml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("old", "new", "fragment"),
    [
        (  # a spring tied to a body that is neither a rod nor the world
            "  </worldbody>",
            '    <body name="bracket" pos="0 0 1"><site name="hook"/></body>\n  </worldbody>',
            "neither a rod nor the world",
        ),
        ('stiffness="200"', 'stiffness="0"', "non-positive stiffness"),
        ('stiffness="200"', 'stiffness="-50"', "stiffness"),
        ('<geom name="strut_A_tube"', '<geom density="0" name="strut_A_tube"', "mass"),
    ],
)
def test_bad_mjcf(tmp_path: Path, capsys, old: str, new: str, fragment: str) -> None:
    if "bracket" in new:
        path = _bad_mjcf(tmp_path, old, new)
        text = path.read_text().replace(
            "  </tendon>",
            '    <spatial name="tether" stiffness="50" springlength="0.5">\n'
            '      <site site="tipA_hi"/>\n      <site site="hook"/>\n    </spatial>\n'
            "  </tendon>",
        )
        path.write_text(text)
    else:
        path = _bad_mjcf(tmp_path, old, new)
    out = tmp_path / "out.h5"
    _one_line_error(capsys, ["generate", "--mjcf", str(path), "-o", str(out)], str(path), fragment)
    assert not out.exists()


def test_missing_mjcf_and_bad_options(tmp_path: Path, capsys) -> None:
    out = tmp_path / "out.h5"
    _one_line_error(
        capsys, ["generate", "--mjcf", str(tmp_path / "x.xml"), "-o", str(out)], "x.xml"
    )
    _one_line_error(capsys, ["generate", "--steps", "0", "-o", str(out)], "--steps")
    _one_line_error(capsys, ["generate", "--control-std", "-1", "-o", str(out)], "--control-std")
    # control asked for, but the model has no actuators
    _one_line_error(
        capsys,
        ["generate", "--mjcf", str(EXAMPLE_MJCF), "--control-std", "1", "-o", str(out)],
        "actuators",
    )
    assert not out.exists()
