"""Every reader validates before it indexes, and its one-line error says where.

Each malformed file (no rows, ragged, truncated, text, NaN/inf, no time, a marker
partly seen) is read through the command line as a user would, and the error names
the input file, the row and the column.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from identification.data.mocap.csv_files import write_motive_csv, write_plain_csv, write_vicon_csv
from identification.data.mocap.formats import read_recording
from identification.data.mocap.recording import MarkerRecording
from identification.data.mocap.tsv_files import write_qtm_tsv
from identification.report.plots import check_figure_path
from tensegrity_env.io_utils import InputError
from tensegrity_sr.cli import main

ASSETS = Path(__file__).resolve().parents[2] / "tensegrity_env" / "assets"
NAMES = ["a", "b"]


def _points(frames: int = 12) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    return np.arange(frames) / 100.0, 1.0 + rng.normal(0, 1e-3, (frames, len(NAMES), 3))


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def plain(tmp_path: Path) -> Path:
    t, x = _points()
    return write_plain_csv(tmp_path / "take.csv", t, x, NAMES)


def _cells(line: str, sep: str = ",") -> list[str]:
    return line.split(sep)


def _with_cell(lines: list[str], row: int, col: int, value: str, sep: str = ",") -> list[str]:
    """``lines`` with the cell at file row ``row`` (1-based) and column ``col`` (1-based)
    replaced."""
    out = list(lines)
    cells = _cells(out[row - 1], sep)
    cells[col - 1] = value
    out[row - 1] = sep.join(cells)
    return out


@pytest.mark.parametrize(
    ("mutate", "words"),
    [
        (lambda L: L[:1], ("no frame rows after the header (row 1)",)),
        (lambda L: _with_cell(L, 5, 3, "abc"), ("row 5, column 3 ('a_y')", "'abc' is not a number")),
        (lambda L: _with_cell(L, 6, 4, "inf"), ("row 6, column 4 ('a_z')", "'inf' is not a finite")),
        (lambda L: _with_cell(L, 7, 1, ""), ("row 7, column 1 ('time')", "no time")),
        (lambda L: _with_cell(L, 8, 5, "nan"), ("row 8, columns 5 ('b_x')-7 ('b_z')",
                                                "some coordinates missing")),
        (lambda L: [*L[:9], ",".join(_cells(L[9])[:4]), *L[10:]], ("row 10 has 4 of 7 columns",)),
        (lambda L: [*L[:-1], L[-1].rsplit(",", 2)[0]], ("row 13 has 5 of 7 columns",)),
        (lambda L: [*L[:3], L[3] + ",1.0", *L[4:]], ("row 4, column 8", "beyond the header")),
    ],
    ids=["header-only", "text", "inf", "no-time", "partly-nan", "ragged", "truncated", "extra"],
)
@pytest.mark.parametrize("command", ["inspect", "import-mocap"])
def test_a_plain_csv_error_names_the_file_row_and_column(
    command: str, mutate, words: tuple[str, ...], plain: Path, tmp_path: Path, one_line_error
) -> None:
    bad = _write(tmp_path / "bad.csv", mutate(_lines(plain)))
    out = tmp_path / "out.h5"
    argv = (["inspect", str(bad), "--units", "m"] if command == "inspect" else
            ["import-mocap", str(bad), "--robot", str(ASSETS / "lab_prism.xml"), "--units", "m",
             "-o", str(out)])  # fmt: skip
    assert main(argv) == 2
    line = one_line_error(str(bad), *words)
    assert str(out) not in line  # the input is named, never the output
    assert not out.exists()


def test_motive_vicon_and_qtm_exports_name_the_row_and_column(tmp_path: Path) -> None:
    t, x = _points()
    motive = _lines(write_motive_csv(tmp_path / "m.csv", t, x, NAMES, 100.0))
    head = next(i for i, line in enumerate(motive) if line.startswith("Frame,")) + 1  # 1-based
    cases = {
        "motive_text.csv": (_with_cell(motive, head + 3, 4, "x"), f"row {head + 3}, column 4 ('Y')"),
        "motive_time.csv": (_with_cell(motive, head + 2, 2, ""), f"row {head + 2}, column 2 "
                            "('Time (Seconds)'): the frame has no time"),
        "motive_rows.csv": (motive[:head], f"no frame rows after the header (row {head})"),
    }
    vicon = _lines(write_vicon_csv(tmp_path / "v.csv", x, NAMES, 100.0))
    first = next(i for i, line in enumerate(vicon) if line.strip() == "mm,mm,mm,mm,mm,mm" or
                 line.startswith(",,mm")) + 2  # fmt: skip
    cases["vicon_inf.csv"] = (_with_cell(vicon, first + 1, 6, "-inf"),
                              f"row {first + 1}, column 6 ('X'): '-inf' is not a finite number")
    qtm = _lines(write_qtm_tsv(tmp_path / "q.tsv", x, NAMES, 100.0))
    qhead = next(i for i, line in enumerate(qtm) if line.startswith("Frame\t")) + 1
    cases["qtm_text.tsv"] = (_with_cell(qtm, qhead + 2, 5, "n/a", "\t"),
                             f"row {qhead + 2}, column 5 ('a Z'): 'n/a' is not a number")
    cases["qtm_ragged.tsv"] = ([*qtm[:-1], "\t".join(qtm[-1].split("\t")[:5])],
                               f"row {len(qtm)} has 5 of 8 columns")
    for name, (lines, words) in cases.items():
        path = _write(tmp_path / name, lines)
        with pytest.raises(InputError) as e:
            read_recording(path, units="mm")
        text = str(e.value)
        assert "\n" not in text and text.startswith(f"{path}: "), text
        assert words in text, (name, text)


def test_a_recording_names_the_frame_and_marker_of_an_inf_or_a_partial_sample() -> None:
    t, x = _points()
    x[4, 1, 2] = np.inf
    with pytest.raises(InputError, match=r"^take.c3d: marker positions contain inf \(frame 5, "
                       r"marker 'b'; 1 samples\)$"):  # fmt: skip
        MarkerRecording(Path("take.c3d"), t, x, NAMES, 100.0).check()
    x[4, 1, 2] = np.nan
    with pytest.raises(InputError, match=r"^take.c3d: frame 5, marker 'b': some coordinates NaN"):
        MarkerRecording(Path("take.c3d"), t, x, NAMES, 100.0).check()


@pytest.mark.parametrize("name", ["q.txt", "q", "q.png.", "picture.docx"])
def test_plot_names_that_are_no_picture_are_refused_in_one_line(
    name: str, tmp_path: Path, plain: Path, one_line_error
) -> None:
    out = tmp_path / name
    assert main(["inspect", str(plain), "--plot", str(out)]) == 2
    one_line_error(f"--plot {out}", ".png", ".pdf", ".svg")
    assert not out.exists()
    with pytest.raises(InputError):
        check_figure_path(out)
    assert check_figure_path(tmp_path / "q.PDF") == tmp_path / "q.PDF"


def test_a_malformed_mjcf_keeps_its_line_number(tmp_path: Path, one_line_error) -> None:
    lines = (ASSETS / "lab_prism.xml").read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if "<body" in line)
    lines[k] = lines[k].replace("<body", "<body <broken", 1)
    bad = _write(tmp_path / "bad.xml", lines)
    assert main(["generate", "--mjcf", str(bad), "-o", str(tmp_path / "x.h5")]) == 2
    one_line_error(f"{bad}: line {k + 1}: MuJoCo cannot load it")
    text = (ASSETS / "lab_prism.xml").read_text()
    attr = re.search(r'mass="[^"]*"', text)
    assert attr is not None
    k = text[: attr.start()].count("\n") + 1
    _write(bad, text.replace(attr.group(0), 'mass="heavy"', 1).splitlines())
    assert main(["generate", "--mjcf", str(bad), "-o", str(tmp_path / "x.h5")]) == 2
    one_line_error(f"{bad}: line {k}: MuJoCo cannot load it", "mass")


def test_a_zero_length_rod_on_a_floor_is_reported_as_such(tmp_path: Path, one_line_error) -> None:
    text = (ASSETS / "icosahedron_rolling.xml").read_text()
    assert 'name="floor"' in text
    for end in ("end0", "end1"):
        text = re.sub(rf'(<site name="rod0_{end}" pos=")[^"]*"', r'\g<1>0 0 0"', text)
    bad = tmp_path / "zero.xml"
    bad.write_text(text)
    assert main(["generate", "--mjcf", str(bad), "--ground", "-o", str(tmp_path / "x.h5")]) == 2
    one_line_error(f"{bad}: rod 'rod0': length must be positive", "'rod0_end0' and 'rod0_end1'")


def test_masses_written_as_text_are_refused(tmp_path: Path, one_line_error) -> None:
    doc = json.loads((ASSETS / "icosahedron_rolling_params.json").read_text())
    doc["params"]["mass"][2] = str(doc["params"]["mass"][2])
    bad = tmp_path / "params.json"
    bad.write_text(json.dumps(doc))
    from tensegrity_env.model import Model

    with pytest.raises(InputError, match=rf"^{re.escape(str(bad))}: 'mass'\[2\] is \"[0-9.]+\": "
                       "not numeric"):  # fmt: skip
        Model.load(bad)
    doc["params"]["mass"][2] = True
    bad.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"'mass'\[2\] is true: not numeric"):
        Model.load(bad)


@pytest.mark.parametrize("keep", [0, 10, 511, 520, 600, 700, 800, 1100, 1600, 1800])
def test_a_truncated_c3d_is_refused_in_one_line(keep: int, tmp_path: Path) -> None:
    """Cut in its header, its parameters (where ezc3d crashes or loops forever: 520, 700,
    800 bytes) or its point data."""
    from identification.data.mocap.c3d_files import write_c3d

    _, x = _points()
    good = write_c3d(tmp_path / "good.c3d", x, NAMES, 100.0).read_bytes()
    bad = tmp_path / "cut.c3d"
    bad.write_bytes(good[:keep])
    with pytest.raises(InputError) as e:
        read_recording(bad)
    text = str(e.value)
    assert "\n" not in text and text.startswith(f"{bad}: not a readable C3D file"), text


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("markers:\n  a: {rod: rod0, end: 0, offset: \"0.1\"}\n", "offset '0.1' is not a finite"),
        ("markers:\n  a: {rod: rod0, end: 0, offset: .nan}\n", "offset nan is not a finite"),
        ("markers:\n  a: {rod: rod0\n  b: [\n", "not valid YAML (line 3, column 4: "),
    ],
    ids=["text", "nan", "yaml"],
)
def test_a_marker_map_error_says_where(text: str, words: str, tmp_path: Path) -> None:
    from identification.data.mocap.marker_map import read_marker_map
    from tensegrity_env.assemblies import icosahedron

    path = tmp_path / "map.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as e:
        read_marker_map(path, icosahedron().topology)
    assert str(e.value).startswith(f"{path}: ") and words in str(e.value), str(e.value)
