"""OptiTrack's legacy row-format CSV export (``info,version,1.1``).

Rows are typed by their first cell: ``comment`` (ignored), ``righthanded`` /
``lefthanded``, ``info`` (``version``, ``framecount``, ``rigidbodycount``),
``rigidbody`` (a rigid-body definition, or a rigid body's extended data for one frame:
ignored), and one ``frame`` row per frame::

    frame, <index>, <time [s]>, <rigid body count B>, B x (id, x, y, z, qx, qy, qz, qw,
           yaw, pitch, roll), <marker count N>, N x (x, y, z, <id>, <name>)

Each reconstructed marker carries an id and a name. Unlabelled markers are named
``Marker-<id>``; the camera system issues a new id whenever it loses a marker and finds
it again. Such a take becomes a point cloud per frame: the ids are packed into as many
columns as markers are ever seen at once (an id keeps its column while it lives; a
column is reused by an id that appears after the last one ended), and the id of every
sample is kept (:attr:`~identification.data.mocap.recording.MarkerRecording.ids`).
Markers with other names are labelled: one column per name. Positions are in metres
(the format states no unit; ``--units`` overrides).
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from identification.data.mocap.recording import MarkerRecording, unit_scale
from tensegrity_env.io_utils import InputError, atomic_write_text

#: first cells of the rows this format holds
ROW_TYPES = ("comment", "info", "righthanded", "lefthanded", "rigidbody", "frame")
#: cells per rigid body in a frame row: id, position (3), quaternion (4), Euler angles (3)
RIGID_BODY_CELLS = 11
#: cells per marker in a frame row: x, y, z, id, name
MARKER_CELLS = 5
#: the name OptiTrack gives an unlabelled marker
UNLABELLED_NAME = re.compile(r"^Marker-\d+$")
#: one frame row: time [s], markers (x, y, z [file units], id, name), the file line
Frame = tuple[float, list[tuple[float, float, float, int, str]], int]


def _row_type_head(rows: list[list[str]]) -> list[list[str]]:
    """The first 50 non-empty CSV ``rows`` where every one starts with one of
    :data:`ROW_TYPES` (a row-format export's look), else []."""
    head = [r for r in rows[:50] if r and any(c.strip() for c in r)]
    return head if all(r[0].strip().lower() in ROW_TYPES for r in head) else []


def _has_version(head: list[list[str]]) -> bool:
    return any(r[0].strip().lower() == "info" and len(r) > 1 and r[1].strip().lower() == "version"
               for r in head)  # fmt: skip


def is_optitrack_rows(rows: list[list[str]]) -> bool:
    """Whether CSV ``rows`` are a row-format export: an ``info,version,...`` row among
    rows that all start with one of :data:`ROW_TYPES` (the first 50 looked at)."""
    return _has_version(_row_type_head(rows))


def is_cut_row_export(rows: list[list[str]]) -> bool:
    """Whether CSV ``rows`` begin as a row-format export (every row of the first 50
    starts with one of :data:`ROW_TYPES`, the first a ``comment``) but hold no
    ``info,version`` row there: a file cut short in its header."""
    head = _row_type_head(rows)
    return bool(head) and head[0][0].strip().lower() == "comment" and not _has_version(head)


def _cell(path: Path, line: int, row: list[str], col: int, kind: type, what: str) -> float | int:
    """Cell ``col`` (0-based) of file line ``line`` as ``kind``; a one-line error naming
    the row, the column (1-based) and the problem."""
    if col >= len(row):
        raise InputError(f"{path}: row {line}, column {col + 1}: {what} missing (the row ends after "
                         f"{len(row)} cells)")  # fmt: skip
    text = row[col].strip()
    try:
        return kind(text)
    except ValueError:
        raise InputError(f"{path}: row {line}, column {col + 1}: {what} {text!r} is not "
                         f"{'an integer' if kind is int else 'a number'}") from None  # fmt: skip


def read_optitrack_rows(path: Path, rows: list[list[str]], units: str | None = None) -> MarkerRecording:
    """The markers of a row-format export whose CSV ``rows`` are given (file lines in
    order). Every frame row is checked before it is used: its counts, its length and
    each cell, with one-line errors naming the file, the row and the column."""
    frames: list[Frame] = []
    declared: int | None = None
    for line, row in enumerate(rows, start=1):
        if not row or not row[0].strip():
            continue
        kind = row[0].strip().lower()
        if kind == "info" and len(row) > 2 and row[1].strip().lower() == "framecount":
            declared = int(_cell(path, line, row, 2, int, "frame count"))
        if kind != "frame":
            continue
        while row and not row[-1].strip():
            row = row[:-1]  # trailing empty cells of a spreadsheet's save
        _cell(path, line, row, 1, int, "frame index")
        time = float(_cell(path, line, row, 2, float, "time"))
        n_bodies = int(_cell(path, line, row, 3, int, "rigid body count"))
        if n_bodies < 0:
            raise InputError(f"{path}: row {line}, column 4: rigid body count {n_bodies} is negative")
        at = 4 + RIGID_BODY_CELLS * n_bodies
        n_markers = int(_cell(path, line, row, at, int, "marker count"))
        if n_markers < 0:
            raise InputError(f"{path}: row {line}, column {at + 1}: marker count {n_markers} is negative")
        want = at + 1 + MARKER_CELLS * n_markers
        if len(row) != want:
            raise InputError(f"{path}: row {line}: {len(row)} cells, but {n_bodies} rigid bodies and "
                             f"{n_markers} markers make {want}")  # fmt: skip
        markers = []
        for k in range(n_markers):
            c = at + 1 + MARKER_CELLS * k
            xyz = [float(_cell(path, line, row, c + a, float, f"marker {k + 1} {'xyz'[a]}")) for a in range(3)]
            if np.isinf(xyz).any():
                raise InputError(f"{path}: row {line}, column {c + 1}: marker {k + 1} position is infinite")
            ident = int(_cell(path, line, row, c + 3, int, f"marker {k + 1} id"))
            markers.append((xyz[0], xyz[1], xyz[2], ident, row[c + 4].strip()))
        frames.append((time, markers, line))
    if not frames:
        raise InputError(f"{path}: OptiTrack row-format export without 'frame' rows")
    if declared is not None and declared != len(frames):
        raise InputError(f"{path}: 'info,framecount' declares {declared} frames, the file holds "
                         f"{len(frames)} frame rows (truncated?)")  # fmt: skip
    times = np.array([t for t, _, _ in frames])
    names = {m[4] for _, ms, _ in frames for m in ms}
    unlabelled = all(UNLABELLED_NAME.match(n) for n in names)
    points, ids, columns = _pack(path, frames) if unlabelled else _by_name(path, frames)
    scale = unit_scale("m" if units is None else units, path, None)
    dt = np.diff(times)
    rate = float(1.0 / np.median(dt)) if len(dt) else np.nan
    return MarkerRecording(path, times - times[0], points * scale, columns, rate, ids=ids)


def _pack(path: Path, frames: list[Frame]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Unlabelled markers packed into columns by id lifetime: points (F, M, 3), ids (F, M)
    (-1: empty), column names (``Marker-<first id>``)."""
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    for f, (_, ms, line) in enumerate(frames):
        seen: set[int] = set()
        for m in ms:
            if m[3] in seen:
                raise InputError(f"{path}: row {line}: marker id {m[3]} appears twice in one frame")
            seen.add(m[3])
            first.setdefault(m[3], f)
            last[m[3]] = f
    column_of: dict[int, int] = {}
    ends: list[int] = []  # last frame of each column's current id
    names: list[str] = []
    for ident in sorted(first, key=lambda i: (first[i], i)):  # interval colouring, by start
        free = next((c for c, e in enumerate(ends) if e < first[ident]), None)
        if free is None:
            free = len(ends)
            ends.append(-1)
            names.append(f"Marker-{ident}")
        column_of[ident] = free
        ends[free] = last[ident]
    points = np.full((len(frames), max(len(ends), 1), 3), np.nan)
    ids = np.full((len(frames), max(len(ends), 1)), -1)
    for f, (_, ms, _) in enumerate(frames):
        for x, y, z, ident, _ in ms:
            points[f, column_of[ident]] = (x, y, z)
            ids[f, column_of[ident]] = ident
    return points, ids, names or ["Marker-0"]


def _by_name(path: Path, frames: list[Frame]) -> tuple[np.ndarray, None, list[str]]:
    """Labelled markers: one column per name, in order of first appearance."""
    names: dict[str, int] = {}
    for _, ms, _ in frames:
        for m in ms:
            names.setdefault(m[4], len(names))
    points = np.full((len(frames), len(names), 3), np.nan)
    for f, (_, ms, line) in enumerate(frames):
        for x, y, z, _, name in ms:
            if np.isfinite(points[f, names[name]]).any():
                raise InputError(f"{path}: row {line}: marker {name!r} appears twice in one frame")
            points[f, names[name]] = (x, y, z)
    return points, None, list(names)


def write_optitrack_rows(
    path: str | Path, time: np.ndarray, points: np.ndarray, ids: np.ndarray
) -> Path:
    """Write marker positions ``points`` (F, M, 3) [m] (NaN: not seen) with each
    sample's id ``ids`` (F, M) (-1: none) as a row-format export, unlabelled markers
    named ``Marker-<id>``, frames at ``time`` (F,) [s]."""
    rows = ['comment,"OptiTrack Export Data"', "righthanded", "info,version,1.1",
            f"info,framecount,{len(time)}", "info,rigidbodycount,0"]  # fmt: skip
    for f, t in enumerate(time):
        seen = [m for m in range(points.shape[1]) if ids[f, m] >= 0 and np.isfinite(points[f, m]).all()]
        cells = [f"{v:.8f}" for m in seen for v in points[f, m]]
        markers = [",".join([*cells[3 * k : 3 * k + 3], str(ids[f, m]), f"Marker-{ids[f, m]}"])
                   for k, m in enumerate(seen)]  # fmt: skip
        rows.append(",".join(["frame", str(f), f"{t:.8f}", "0", str(len(seen)), *markers]))
    return atomic_write_text(path, "\n".join(rows) + "\n")


def read_rows(path: Path) -> list[list[str]]:
    """A file's CSV rows (for :func:`read_optitrack_rows` called on its own)."""
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.reader(f))
