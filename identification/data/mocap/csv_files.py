"""CSV exports: OptiTrack Motive's layout and a plain ``time, <marker>_x, <marker>_y, <marker>_z`` table.

Motive (1.x-3.x "CSV export"): a first row of ``key,value`` pairs (``Capture Frame Rate``,
``Length Units``, ...), a blank row, then header rows naming each column's type
(``Marker``, ``Rigid Body``, ...), name, ID and quantity (``Position``), then a row
``Frame,Time (Seconds),X,Y,Z,...`` and one row per frame; empty cells are unseen
markers. Marker position columns are read; rigid bodies are ignored. Unlabelled
exports name their tracks ``Unlabeled <id>``.

Vicon Nexus ("Export CSV"): sections (``Devices``, ``Trajectories``, ``Model Outputs``,
...) separated by blank rows; the ``Trajectories`` section is a row ``Trajectories``, a
row with the frame rate [Hz], a row of marker names (``<subject>:<marker>``) above each
marker's first column, a row ``Frame,Sub Frame,X,Y,Z,...``, a row of units (``mm``),
then one row per frame; empty cells are unseen markers. Frame times are the frame
numbers over the rate.

Plain: a header ``time,<name>_x,<name>_y,<name>_z,...`` (time in seconds), one row per
frame, empty or ``nan`` cells for unseen markers; the length unit is ``--units``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from identification.data.mocap.optitrack_rows import (
    is_cut_row_export,
    is_optitrack_rows,
    read_optitrack_rows,
)
from identification.data.mocap.recording import MarkerRecording, unit_scale
from tensegrity_env.io_utils import InputError, atomic_write_text

AXES = ("x", "y", "z")


def _number(cell: str, path: Path, row: int, column: str = "") -> float:
    """A cell's value; NaN for an empty or ``nan`` cell (an unseen marker). ``row`` is the
    file's row number and ``column`` names the column, for the one-line error on text or
    an infinite value."""
    cell = cell.strip()
    if cell == "" or cell.lower() == "nan":
        return np.nan
    where = f"{path}: row {row}{', column ' + column if column else ''}"
    try:
        value = float(cell)
    except ValueError:
        raise InputError(f"{where}: {cell!r} is not a number") from None
    if not np.isfinite(value):
        raise InputError(f"{where}: {cell!r} is not a finite number")
    return value


def _semicolons(text: str) -> bool:
    """Whether a CSV's first line separates its cells by semicolons (the export of a
    spreadsheet in a locale whose decimal mark is a comma)."""
    first = text.split("\n", 1)[0]
    return first.count(";") > first.count(",")


def read_csv(path: Path, units: str | None = None) -> MarkerRecording:
    """An OptiTrack row-format export (:mod:`.optitrack_rows`, by its ``info,version``
    row), a Motive export (by its ``Format Version`` first cell), a Vicon Nexus export (by
    its ``Devices`` or ``Trajectories`` first cell) or a plain CSV; cells separated by
    commas, or by semicolons with decimal commas."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            text = f.read()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read it as text ({e})") from None
    semicolons = _semicolons(text)
    rows = list(csv.reader(text.splitlines(), delimiter=";" if semicolons else ","))
    if semicolons:  # a decimal comma goes with the semicolon (Excel's locales)
        rows = [[c.replace(",", ".") for c in r] for r in rows]
    if not rows:
        raise InputError(f"{path}: empty file")
    if is_optitrack_rows(rows):
        return read_optitrack_rows(path, rows, units)
    if is_cut_row_export(rows):
        raise InputError(f"{path}: row {len(rows)}: an OptiTrack row-format export ends in its "
                         "comment header, before its 'info,version' row and any 'frame' row "
                         "(a file cut short?)")  # fmt: skip
    if rows[0] and rows[0][0].strip().lower() == "format version":
        return _read_motive(path, rows, units)
    if rows[0] and rows[0][0].strip().lower() in ("devices", "trajectories"):
        return _read_vicon(path, rows, units)
    return _read_plain(path, rows, units)


def _column(j: int, header: list[str] | None) -> str:
    """Column ``j`` (0-based) of a file as a message names it: its number and heading."""
    name = header[j].strip() if header is not None and j < len(header) else ""
    return f"{j + 1} ({name!r})" if name else str(j + 1)


def frame_rows(
    path: Path,
    rows: list[list[str]],
    first: int,
    width: int,
    *,
    header: list[str] | None = None,
    time_column: int | None = None,
    triples: list[int] | None = None,
) -> np.ndarray:
    """The numbers of the frame rows ``rows[first:]`` (blank rows skipped), (F, width).

    Checked before use, each error naming the file, the row and the column: a frame row
    with fewer than ``width`` cells (truncated or ragged) or with more that are not
    empty, a cell that is text or infinite, an empty ``time_column``, a marker whose x,
    y, z columns (starting at each of ``triples``) are partly empty. ``header`` names
    the columns in messages. No frame row at all is an error too.
    """
    body = [(first + i + 1, r) for i, r in enumerate(rows[first:]) if any(c.strip() for c in r)]
    if not body:
        raise InputError(f"{path}: no frame rows after the header (row {first}): the file "
                         "holds no data")  # fmt: skip
    out = np.full((len(body), width), np.nan)
    for i, (row, r) in enumerate(body):
        if len(r) < width:
            raise InputError(f"{path}: row {row} has {len(r)} of {width} columns (a truncated "
                             "or ragged row)")  # fmt: skip
        extra = next((j for j in range(width, len(r)) if r[j].strip()), None)
        if extra is not None:
            raise InputError(f"{path}: row {row}, column {extra + 1}: a value beyond the "
                             f"header's {width} columns (a ragged row)")  # fmt: skip
        for j, cell in enumerate(r[:width]):
            out[i, j] = _number(cell, path, row, _column(j, header))
        if time_column is not None and np.isnan(out[i, time_column]):
            raise InputError(f"{path}: row {row}, column {_column(time_column, header)}: "
                             "the frame has no time")  # fmt: skip
        for j in triples or ():
            seen = np.isnan(out[i, j : j + 3])
            if seen.any() and not seen.all():
                raise InputError(f"{path}: row {row}, columns {_column(j, header)}-"
                                 f"{_column(j + 2, header)}: a marker with some coordinates "
                                 "missing (empty or nan) and others not (an unseen marker is "
                                 "empty in x, y and z)")  # fmt: skip
    return out


def _read_plain(path: Path, rows: list[list[str]], units: str | None) -> MarkerRecording:
    header = [h.strip() for h in rows[0]]
    if not header or header[0].lower() not in ("time", "t", "time (seconds)"):
        raise InputError(f"{path}: first column must be 'time' (plain CSV: time, <m>_x, <m>_y, <m>_z, ...)")
    names: list[str] = []
    for k in range(1, len(header), 3):
        trio = header[k : k + 3]
        stems = {h.rsplit("_", 1)[0] for h in trio}
        if len(trio) < 3 or [h.rsplit("_", 1)[-1].lower() for h in trio] != list(AXES) or len(stems) != 1:
            raise InputError(
                f"{path}: columns {', '.join(trio)} are not one marker's x, y, z columns "
                "(a column missing or out of order)"
            )
        names.append(stems.pop())
    if not names:
        raise InputError(f"{path}: no marker columns after 'time'")
    data = frame_rows(path, rows, 1, len(header), header=header, time_column=0,
                   triples=list(range(1, len(header), 3)))  # fmt: skip
    scale = unit_scale(None, path, units)
    points = data[:, 1:].reshape(len(data), len(names), 3) * scale
    time = data[:, 0]
    dt = np.median(np.diff(time)) if len(time) > 1 else np.nan
    return MarkerRecording(path, time - time[0], points, names, float(1.0 / dt))


def _read_motive(path: Path, rows: list[list[str]], units: str | None) -> MarkerRecording:
    meta = {rows[0][i].strip(): rows[0][i + 1].strip() for i in range(0, len(rows[0]) - 1, 2)}
    head = next((i for i, r in enumerate(rows) if r and r[0].strip().lower() == "frame"), None)
    if head is None or head < 4:
        raise InputError(f"{path}: Motive export without its 'Frame,Time' header row")
    types, names, quantity = rows[head - 4], rows[head - 3], rows[head - 1]
    cols = [
        j for j in range(2, len(rows[head]))
        if j < len(types) and types[j].strip().lower() == "marker"
        and j < len(quantity) and quantity[j].strip().lower() == "position"
    ]  # fmt: skip
    if not cols or len(cols) % 3:
        raise InputError(f"{path}: no complete marker position columns (X, Y, Z) in the header")
    unnamed = next((j for j in cols[::3] if j >= len(names) or not names[j].strip()), None)
    if unnamed is not None:
        raise InputError(f"{path}: row {head - 2}, column {unnamed + 1}: a marker column without "
                         "its marker's name")  # fmt: skip
    labels = [names[j].strip() for j in cols[::3]]
    axes = [rows[head][j].strip().lower() for j in cols]
    if axes != list(AXES) * len(labels):
        raise InputError(f"{path}: marker columns are not X, Y, Z triples")
    data = frame_rows(path, rows, head + 1, len(rows[head]), header=rows[head], time_column=1,
                   triples=cols[::3])  # fmt: skip
    scale = unit_scale(meta.get("Length Units"), path, units)
    points = data[:, cols].reshape(len(data), len(labels), 3) * scale
    try:
        rate = float(meta.get("Export Frame Rate") or meta.get("Capture Frame Rate") or "nan")
    except ValueError:
        rate = np.nan
    if not np.isfinite(rate):
        rate = float(1.0 / np.median(np.diff(data[:, 1])))
    return MarkerRecording(path, data[:, 1] - data[0, 1], points, labels, rate)


def _read_vicon(path: Path, rows: list[list[str]], units: str | None) -> MarkerRecording:
    start = next((i for i, r in enumerate(rows) if r and r[0].strip().lower() == "trajectories"), None)
    if start is None:
        raise InputError(f"{path}: Vicon export without a 'Trajectories' section")
    end = next((i for i in range(start + 1, len(rows)) if not any(c.strip() for c in rows[i])),
               len(rows))  # fmt: skip
    section = rows[start:end]
    if len(section) < 6:
        raise InputError(f"{path}: 'Trajectories' section without its header rows and frames")
    try:
        rate = float(section[1][0])
    except (ValueError, IndexError):
        raise InputError(f"{path}: 'Trajectories' section without its frame rate row") from None
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(f"{path}: row {start + 2}, column 1: frame rate {rate:g} Hz is not a "
                         "positive number")  # fmt: skip
    names_row, axes_row, units_row = section[2], section[3], section[4]
    if [c.strip().lower() for c in axes_row[:2]] != ["frame", "sub frame"]:
        raise InputError(f"{path}: 'Trajectories' section without its 'Frame,Sub Frame' row")
    starts = [j for j in range(2, len(names_row)) if names_row[j].strip()]
    labels = [names_row[j].strip() for j in starts]
    if not labels:
        raise InputError(f"{path}: no marker names in the 'Trajectories' section")
    cols = [j + k for j in starts for k in range(3)]
    axes = [axes_row[j].strip().lower() if j < len(axes_row) else "" for j in cols]
    if axes != list(AXES) * len(labels):
        raise InputError(f"{path}: marker columns are not X, Y, Z triples")
    stated = {units_row[j].strip() for j in cols if j < len(units_row) and units_row[j].strip()}
    if len(stated) > 1:
        raise InputError(f"{path}: marker columns in different units ({', '.join(sorted(stated))})")
    width = max(len(axes_row), cols[-1] + 1)
    data = frame_rows(path, rows[:end], start + 5, width, header=axes_row, time_column=0,
                   triples=cols[::3])  # fmt: skip
    scale = unit_scale(stated.pop() if stated else None, path, units)
    points = data[:, cols].reshape(len(data), len(labels), 3) * scale
    time = (data[:, 0] - data[0, 0]) / rate
    return MarkerRecording(path, time, points, labels, rate)


def write_vicon_csv(
    path: str | Path, points: np.ndarray, names: list[str], rate: float, units: str = "mm"
) -> Path:
    """Write ``points`` (F, M, 3) [m] (NaN: not seen) as a Vicon Nexus CSV export: a
    ``Devices`` section without devices, then the ``Trajectories`` section."""
    scale = {"mm": 1e3, "m": 1.0}[units]
    rows = ["Devices", f"{rate * 10:g}", "", "Trajectories", f"{rate:g}",
            ",," + ",".join(f"{n},," for n in names).rstrip(","),
            "Frame,Sub Frame," + ",".join("X,Y,Z" for _ in names),
            ",," + ",".join(units for _ in range(3 * len(names)))]  # fmt: skip
    flat = points.reshape(len(points), -1) * scale
    for i, row in enumerate(flat):
        rows.append(f"{i + 1},0," + ",".join("" if np.isnan(v) else f"{v:.5f}" for v in row))
    return atomic_write_text(path, "\n".join(rows) + "\n")


def write_plain_csv(
    path: str | Path, time: np.ndarray, points: np.ndarray, names: list[str], units: str = "m"
) -> Path:
    """Write ``points`` (F, M, 3) [m] at ``time`` (F,) [s] as a plain CSV in ``units``."""
    scale = {"mm": 1e3, "m": 1.0}[units]
    head = ["time", *[f"{n}_{a}" for n in names for a in AXES]]
    lines = [",".join(head)]
    flat = points.reshape(len(time), -1) * scale
    for t, row in zip(time, flat, strict=True):
        lines.append(",".join([repr(float(t))] + ["" if np.isnan(v) else repr(float(v)) for v in row]))
    return atomic_write_text(path, "\n".join(lines) + "\n")


def write_motive_csv(
    path: str | Path, time: np.ndarray, points: np.ndarray, names: list[str], rate: float,
    units: str = "Millimeters",
) -> Path:  # fmt: skip
    """Write ``points`` (F, M, 3) [m] as a Motive CSV export (marker positions only)."""
    scale = 1e3 if units.lower().startswith("milli") else 1.0
    meta = ["Format Version", "1.23", "Take Name", Path(path).stem,
            "Capture Frame Rate", f"{rate:.6f}", "Export Frame Rate", f"{rate:.6f}",
            "Total Exported Frames", str(len(time)), "Length Units", units,
            "Coordinate Space", "Global"]  # fmt: skip
    cols = [n for n in names for _ in AXES]
    rows = [
        ",".join(meta),
        "",
        ",," + ",".join("Marker" for _ in cols),
        ",," + ",".join(cols),
        ",," + ",".join(str(1000 + i // 3) for i in range(len(cols))),
        ",," + ",".join("Position" for _ in cols),
        "Frame,Time (Seconds)," + ",".join(a.upper() for _ in names for a in AXES),
    ]
    flat = points.reshape(len(time), -1) * scale
    for i, (t, row) in enumerate(zip(time, flat, strict=True)):
        cells = ["" if np.isnan(v) else f"{v:.6f}" for v in row]
        rows.append(f"{i},{t:.6f}," + ",".join(cells))
    return atomic_write_text(path, "\n".join(rows) + "\n")
