"""Property-based bad input: every reader gives a valid result or one clear line.

Starting from a valid dataset, params document, MJCF file or action, hypothesis
mutates one part (a missing or replaced entry, NaN/inf values, wrong shapes, junk
text, a truncated file) and the reader must either return something valid (finite,
consistent) or raise its documented one-line error, never another exception and
never a silent NaN. ``HYPOTHESIS_PROFILE=ci`` makes the examples deterministic.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from functools import cache
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from identification.data.dataset import Dataset, read_dataset, write_dataset
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.envs import IcosahedronMJEnv, IcosahedronSREnv
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import from_mjcf
from tensegrity_env.model import Model

ROOT = Path(__file__).resolve().parents[2]
PARAMS = ROOT / "tensegrity_env" / "assets" / "icosahedron_rolling_params.json"
MJCF = ROOT / "docs" / "examples" / "x_tensegrity.xml"

#: values a mutation writes: numbers of every kind, text, nothing, containers
junk = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, -1.0, 0.0, 1e308]),
    st.text(max_size=12),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=5),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)


def one_line(e: BaseException) -> str:
    text = str(e)
    assert text and "\n" not in text, repr(text)
    return text


# ---------------------------------------------------------------------- dataset reader
@cache
def valid_dataset_bytes(tmp: str) -> bytes:
    dataset, truth = generate_dataset(
        GenerateSpec(assembly="element", n_train=2, n_val=1, n_test=1, steps=12, seed=0)
    )
    path = Path(tmp) / "valid.h5"
    write_dataset(path, dataset, truth)
    return path.read_bytes()


def h5_items(path: Path) -> list[str]:
    names: list[str] = []
    with h5py.File(path, "r") as f:
        f.visit(names.append)
    return sorted(names)


def check_dataset(ds: Dataset) -> None:
    """A dataset that was read is finite and its splits are consistent."""
    assert ds.dt > 0 and math.isfinite(ds.dt)
    for split in ds.splits.values():
        for k in ("nodes", "control", "p", "v", "q", "omega"):
            arr = getattr(split, k)
            if arr is not None:
                assert np.all(np.isfinite(arr)), k
        assert split.nodes.shape[0] == split.control.shape[0]


@given(data=st.data())
def test_dataset_reader(tmp_path_factory: pytest.TempPathFactory, data: st.DataObject) -> None:
    tmp = tmp_path_factory.getbasetemp() / "datasets"
    tmp.mkdir(exist_ok=True)
    good = valid_dataset_bytes(str(tmp))
    path = tmp / "mutated.h5"
    path.write_bytes(good)
    items = h5_items(path)
    kind = data.draw(st.sampled_from(["truncate", "delete", "attribute", "values", "shape"]))
    if kind == "truncate":
        path.write_bytes(good[: data.draw(st.integers(0, len(good) - 1))])
    else:
        with h5py.File(path, "r+") as f:
            name = data.draw(st.sampled_from(items))
            if kind == "delete":
                del f[name]
            elif kind == "attribute":
                key = data.draw(st.sampled_from(["dt", "format", "version", "json"]))
                target = f["topology"] if key == "json" else f
                text = st.text(st.characters(exclude_characters="\x00"), max_size=20)  # HDF5: no NUL
                value = data.draw(st.one_of(st.floats(), st.integers(-5, 5), text))
                target.attrs[key] = value
            elif isinstance(f[name], h5py.Dataset):
                arr = f[name][()]
                if kind == "values":
                    flat = arr.reshape(-1)
                    i = data.draw(st.integers(0, flat.size - 1))
                    flat[i] = data.draw(st.sampled_from([math.nan, math.inf, -math.inf, 1e300]))
                    f[name][()] = flat.reshape(arr.shape)
                else:
                    del f[name]
                    shape = data.draw(st.lists(st.integers(0, 4), min_size=0, max_size=4))
                    f[name] = np.zeros(shape)
    try:
        ds = read_dataset(path)
    except InputError as e:
        assert str(path) in one_line(e)
    else:
        check_dataset(ds)


# ---------------------------------------------------------------------- params documents
def json_paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path to a value in a JSON tree (keys and list indices)."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += json_paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:3]):  # the first entries of long lists are enough
            out += json_paths(v, (*prefix, i))
    return out


@given(data=st.data())
def test_params_and_effects_loader(
    tmp_path_factory: pytest.TempPathFactory, data: st.DataObject
) -> None:
    doc = json.loads(PARAMS.read_text())
    where = data.draw(st.sampled_from(json_paths(doc)))
    parent = doc
    for key in where[:-1]:
        parent = parent[key]
    if data.draw(st.booleans()) and isinstance(parent, dict):
        del parent[where[-1]]
    else:
        parent[where[-1]] = data.draw(junk)
    path = tmp_path_factory.getbasetemp() / "mutated_params.json"
    path.write_text(json.dumps(doc))
    try:
        model = Model.load(path)
    except InputError as e:
        assert str(path) in one_line(e)
    else:
        for v in model.params.numpy().values():
            assert np.all(np.isfinite(v))
        for effect in model.effects:
            for k, v in effect.values.items():
                assert k in effect.allow_infinite or bool(np.all(np.isfinite(v.numpy()))), k


# ---------------------------------------------------------------------- MJCF importer
@given(data=st.data())
def test_mjcf_importer(tmp_path_factory: pytest.TempPathFactory, data: st.DataObject) -> None:
    text = re.sub(r"<!--.*?-->", "", MJCF.read_text(), flags=re.S)  # "--" in comments: not XML
    tree = ET.ElementTree(ET.fromstring(text))
    elements = [e for e in tree.getroot().iter() if e is not tree.getroot()]
    element = data.draw(st.sampled_from(elements))
    if data.draw(st.booleans()) or not element.attrib:
        for parent in tree.getroot().iter():
            if element in list(parent):
                parent.remove(element)
                break
    else:
        key = data.draw(st.sampled_from(sorted(element.attrib)))
        value = data.draw(st.one_of(
            st.sampled_from(["nan", "inf", "-1", "0", "", "1e300", "1 2", "junk"]),
            st.floats(allow_nan=True, allow_infinity=True).map(str),
        ))  # fmt: skip
        element.set(key, value)
    path = tmp_path_factory.getbasetemp() / "mutated.xml"
    tree.write(path)
    try:
        asm = from_mjcf(path)
    except InputError as e:
        assert str(path) in one_line(e)
    else:
        for v in asm.params.numpy().values():
            assert np.all(np.isfinite(v))


# ---------------------------------------------------------------------- env step
@cache
def env(kind: str) -> Any:
    e = IcosahedronSREnv() if kind == "SR" else IcosahedronMJEnv()
    e.reset(seed=0)
    return e


actions = st.one_of(
    st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=18, max_size=18),
    st.lists(st.floats(-10, 10, width=32), min_size=0, max_size=25),
).map(lambda a: np.array(a, dtype=np.float32))


@pytest.mark.parametrize("kind", ["SR", "MJ"])
@given(action=actions)
def test_env_step(kind: str, action: np.ndarray) -> None:
    e = env(kind)
    try:
        obs, reward, terminated, truncated, _ = e.step(action)
    except ValueError as err:
        text = one_line(err)
        assert text.startswith("action has shape") or text.endswith("are NaN or infinite")
        assert action.shape != (18,) or not np.all(np.isfinite(action))
    else:
        assert action.shape == (18,) and np.all(np.isfinite(action))
        assert np.all(np.isfinite(obs)) and math.isfinite(reward)
        if terminated or truncated:
            e.reset(seed=0)


# ---------------------------------------------------------------------- motion-capture readers
#: one valid take per reader: plain CSV, Motive CSV, Vicon CSV, Qualisys TSV, C3D
MOCAP_FILES = ("plain.csv", "motive.csv", "vicon.csv", "qtm.tsv", "take.c3d")
#: what a mutation writes into a cell: numbers of every kind, text, nothing
cells = st.one_of(
    st.sampled_from(["", " ", "nan", "NaN", "inf", "-inf", "1e400", "abc", "1,5", "0", "-1e30"]),
    st.text(st.characters(exclude_characters="\x00\r\n", exclude_categories=("Cs",)), max_size=8),
    st.floats(allow_nan=True, allow_infinity=True).map(str),
)


@cache
def valid_take_bytes(name: str, tmp: str) -> bytes:
    from identification.data.mocap.c3d_files import write_c3d
    from identification.data.mocap.csv_files import (
        write_motive_csv,
        write_plain_csv,
        write_vicon_csv,
    )
    from identification.data.mocap.tsv_files import write_qtm_tsv

    rng = np.random.default_rng(1)
    t = np.arange(15) / 100.0
    x = 1.0 + rng.normal(0, 1e-2, (15, 3, 3))
    x[5, 1] = np.nan  # an unseen marker
    names = ["m0", "m1", "m2"]
    path = Path(tmp) / name
    writers = {
        "plain.csv": lambda: write_plain_csv(path, t, x, names, units="mm"),
        "motive.csv": lambda: write_motive_csv(path, t, x, names, 100.0),
        "vicon.csv": lambda: write_vicon_csv(path, x, names, 100.0),
        "qtm.tsv": lambda: write_qtm_tsv(path, x, names, 100.0),
        "take.c3d": lambda: write_c3d(path, x, names, 100.0),
    }
    writers[name]()
    return path.read_bytes()


def check_recording(rec: Any) -> None:
    """A take that was read: finite or wholly unseen samples, increasing times, a rate."""
    assert rec.points.ndim == 3 and rec.points.shape[2] == 3 and rec.points.shape[0] >= 2
    assert not np.isinf(rec.points).any()
    unseen = np.isnan(rec.points)
    assert (unseen.any(-1) == unseen.all(-1)).all()  # a marker is seen in x, y, z or not at all
    assert np.isfinite(rec.time).all() and (np.diff(rec.time) > 0).all()
    assert math.isfinite(rec.rate) and rec.rate > 0
    assert len(rec.names) == rec.points.shape[1]


def mutated_text(text: str, sep: str, data: st.DataObject) -> str:
    """``text`` with one cell replaced, one row dropped, repeated or cut, or cut short."""
    lines = text.splitlines()
    kind = data.draw(st.sampled_from(["cell", "drop", "repeat", "cut row", "truncate"]))
    if kind == "truncate":
        return text[: data.draw(st.integers(0, len(text) - 1))]
    i = data.draw(st.integers(0, len(lines) - 1))
    cells_i = lines[i].split(sep)
    if kind == "cell":
        cells_i[data.draw(st.integers(0, len(cells_i) - 1))] = data.draw(cells)
        lines[i] = sep.join(cells_i)
    elif kind == "drop":
        del lines[i]
    elif kind == "repeat":
        lines.insert(i, lines[i])
    else:
        lines[i] = sep.join(cells_i[: data.draw(st.integers(0, len(cells_i)))])
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("name", MOCAP_FILES)
@given(data=st.data())
def test_mocap_readers(name: str, tmp_path_factory: pytest.TempPathFactory, data: st.DataObject) -> None:
    from identification.data.mocap.formats import read_recording

    tmp = tmp_path_factory.getbasetemp() / "takes"
    tmp.mkdir(exist_ok=True)
    good = valid_take_bytes(name, str(tmp))
    path = tmp / f"mutated_{name}"
    if name.endswith(".c3d"):
        raw = bytearray(good)
        if data.draw(st.booleans()):
            raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
        else:  # a byte of the point data, which starts at the block the header's word 9 names
            start = (int.from_bytes(good[16:18], "little") - 1) * 512
            i = data.draw(st.integers(start, len(raw) - 1))
            raw[i] = data.draw(st.integers(0, 255))
        path.write_bytes(bytes(raw))
    else:
        sep = "\t" if name.endswith(".tsv") else ","
        path.write_text(mutated_text(good.decode(), sep, data))
    try:
        rec = read_recording(path, units="mm")
    except InputError as e:
        assert str(path) in one_line(e)
    else:
        check_recording(rec)


# ---------------------------------------------------------------------- --plot names
picture_names = st.tuples(
    st.text(st.characters(exclude_characters="/\\", exclude_categories=("Cc", "Cs")),
            min_size=1, max_size=8),
    st.sampled_from(["", ".png", ".PNG", ".pdf", ".svg", ".jpg", ".txt", ".", ".png.", ".h5", ".docx"]),
).map("".join)


@given(name=picture_names)
def test_plot_names(tmp_path_factory: pytest.TempPathFactory, name: str) -> None:
    """A picture name is refused in one line or gives a readable picture of that format."""
    import matplotlib.pyplot as plt

    from identification.report.plots import check_figure_path
    from tensegrity_env.io_utils import atomic_path

    tmp = tmp_path_factory.getbasetemp() / "pictures"
    tmp.mkdir(exist_ok=True)
    path = tmp / name
    if name in (".", "..") or path.is_dir():
        return
    try:
        check_figure_path(path)
    except InputError as e:
        assert one_line(e).startswith(f"--plot {path}: ") and ".png" in str(e)
        return
    fig = plt.figure(figsize=(1, 1))
    try:
        with atomic_path(path, keep_extension=True) as out:  # as inspect --plot writes it
            fig.savefig(out, dpi=20)
    finally:
        plt.close(fig)
    assert path.stat().st_size > 0
    path.unlink()
