"""Qualisys Track Manager (QTM) TSV exports of 3-D marker data.

A block of tab-separated ``KEY<TAB>value...`` header rows (``NO_OF_FRAMES``,
``FREQUENCY``, ``MARKER_NAMES``, ...), then, if the export included them, a row of
column names (``Frame``, ``Time``, ``<marker> X``, ``<marker> Y``, ``<marker> Z``, ...),
then one row per frame. Positions are in millimetres. QTM writes a marker it did not
see in a frame as ``0.000`` in all three coordinates: :func:`read_recording` reads those
as gaps (:func:`~identification.data.quality.placeholder_samples`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from identification.data.mocap.csv_files import frame_rows
from identification.data.mocap.recording import MarkerRecording, unit_scale
from tensegrity_env.io_utils import InputError, atomic_write_text

#: a header row's key
HEADER_KEY = re.compile(r"^[A-Z][A-Z0-9_]*$")


def read_qtm_tsv(path: Path, units: str | None = None) -> MarkerRecording:
    """The 3-D marker trajectories of a QTM TSV export (millimetres unless ``units``)."""
    try:
        rows = [line.split("\t") for line in path.read_text(encoding="utf-8-sig").splitlines()]
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read it as text ({e})") from None
    meta: dict[str, list[str]] = {}
    k = 0
    while k < len(rows) and rows[k] and HEADER_KEY.match(rows[k][0].strip()):
        meta[rows[k][0].strip()] = [c.strip() for c in rows[k][1:]]
        k += 1
    if "MARKER_NAMES" not in meta or "FREQUENCY" not in meta:
        raise InputError(f"{path}: not a QTM 3-D export (no MARKER_NAMES and FREQUENCY header rows)")
    names = [n for n in meta["MARKER_NAMES"] if n]
    try:
        rate = float(meta["FREQUENCY"][0])
    except (ValueError, IndexError):
        raise InputError(f"{path}: FREQUENCY {meta['FREQUENCY']} is not a number") from None
    columns: list[str] | None = None
    if k < len(rows) and rows[k] and rows[k][0].strip().lower() == "frame":
        columns = [c.strip() for c in rows[k]]
        k += 1
    body = [r for r in rows[k:] if any(c.strip() for c in r)]
    if not body:
        raise InputError(f"{path}: no frames after the header (row {k})")
    width = 3 * len(names)
    lead = len(columns) - width if columns else len(body[0]) - width
    if lead not in (0, 2):
        raise InputError(f"{path}: {len(names)} markers need {width} coordinate columns "
                         f"(after Frame and Time, if exported); found {width + lead}")  # fmt: skip
    if columns:
        want = [f"{n} {a}" for n in names for a in "XYZ"]
        if columns[lead:] != want:
            raise InputError(f"{path}: coordinate columns are not each marker's X, Y, Z")
    data = frame_rows(path, rows, k, width + lead, header=columns, time_column=1 if lead else None,
                   triples=list(range(lead, width + lead, 3)))  # fmt: skip
    time = data[:, 1] - data[0, 1] if lead else np.arange(len(data)) / rate
    scale = unit_scale("mm" if units is None else units, path, None)
    points = data[:, lead:].reshape(len(data), len(names), 3) * scale
    return MarkerRecording(path, time, points, names, rate)


def write_qtm_tsv(path: str | Path, points: np.ndarray, names: list[str], rate: float) -> Path:
    """Write ``points`` (F, M, 3) [m] as a QTM TSV export with Frame and Time columns;
    an unseen marker (NaN) is written as QTM does, ``0.000`` in every coordinate."""
    n = len(points)
    rows = [f"NO_OF_FRAMES\t{n}", "NO_OF_CAMERAS\t8", f"NO_OF_MARKERS\t{len(names)}",
            f"FREQUENCY\t{rate:g}", "NO_OF_ANALOG\t0", "ANALOG_FREQUENCY\t0",
            "DESCRIPTION\t--", "TIME_STAMP\t2026-01-01, 12:00:00.000", "DATA_INCLUDED\t3D",
            "MARKER_NAMES\t" + "\t".join(names),
            "TRAJECTORY_TYPES\t" + "\t".join("Measured" for _ in names),
            "Frame\tTime\t" + "\t".join(f"{m} {a}" for m in names for a in "XYZ")]  # fmt: skip
    flat = np.nan_to_num(points.reshape(n, -1) * 1e3, nan=0.0)
    for i, row in enumerate(flat):
        rows.append(f"{i + 1}\t{i / rate:.5f}\t" + "\t".join(f"{v:.3f}" for v in row))
    return atomic_write_text(path, "\n".join(rows) + "\n")
