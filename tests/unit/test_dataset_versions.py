"""The dataset format's versions: version 2 (times, gaps) is written, version 1 still read."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from identification.data.dataset import Split, read_dataset, write_dataset
from identification.data.end_caps import dataset_from_end_caps
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.io_utils import InputError


def caps(n: int = 2, t1: int = 20) -> np.ndarray:
    asm = icosahedron()
    x = asm.node_positions()[: 2 * asm.topology.n_rods]
    return np.broadcast_to(x, (n, t1, *x.shape)) + 1e-3 * np.arange(t1)[None, :, None, None]


def test_version_1_files_are_read_without_times(tmp_path: Path) -> None:
    ds = dataset_from_end_caps(icosahedron().topology, 0.01, {"train": caps()})
    path = write_dataset(tmp_path / "d.h5", ds)
    with h5py.File(path, "a") as f:
        assert f.attrs["version"] == 2
        f.attrs["version"] = 1
    back = read_dataset(path).split("train")
    assert back.time is None and not back.has_gaps
    np.testing.assert_array_equal(back.times(0.01)[0], 0.01 * np.arange(20))


def test_gaps_and_uneven_times_round_trip(tmp_path: Path) -> None:
    ds = dataset_from_end_caps(icosahedron().topology, 0.01, {"train": caps()})
    s = ds.split("train")
    nodes = s.nodes.copy()
    nodes[0, 5:8, 3] = np.nan
    time = np.cumsum(np.full((2, 20), 0.01) + 1e-4 * np.sin(np.arange(20)), axis=1)
    ds.splits["train"] = Split(nodes=nodes, control=s.control, time=time - time[:, :1])
    back = read_dataset(write_dataset(tmp_path / "d.h5", ds)).split("train")
    assert back.valid[0, 5:8, 3].sum() == 0 and back.valid.sum() == back.valid.size - 3
    np.testing.assert_array_equal(back.time, time - time[:, :1])


@pytest.mark.parametrize("bad", ["decreasing", "half_nan", "all_nan"])
def test_bad_times_and_gaps_are_refused(tmp_path: Path, bad: str) -> None:
    ds = dataset_from_end_caps(icosahedron().topology, 0.01, {"train": caps()})
    s = ds.split("train")
    nodes, time = s.nodes.copy(), np.tile(0.01 * np.arange(20), (2, 1))
    if bad == "decreasing":
        time[1, 10] = 0.0
    elif bad == "half_nan":
        nodes[0, 3, 0, 1] = np.nan
    else:
        nodes[1] = np.nan
    ds.splits["train"] = Split(nodes=nodes, control=s.control, time=time)
    with pytest.raises(InputError, match=r"'(time|nodes)'"):
        write_dataset(tmp_path / "d.h5", ds)
    assert not (tmp_path / "d.h5").exists()
