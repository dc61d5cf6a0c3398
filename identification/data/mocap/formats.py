"""Read a motion-capture file of any supported format, chosen by its extension: the
readers (:mod:`~identification.data.mocap.c3d_files`,
:mod:`~identification.data.mocap.csv_files`, :mod:`~identification.data.mocap.tsv_files`)
return a :class:`~identification.data.mocap.recording.MarkerRecording`."""

from __future__ import annotations

from pathlib import Path

from identification.data.mocap.c3d_files import read_c3d
from identification.data.mocap.csv_files import read_csv
from identification.data.mocap.recording import MarkerRecording
from identification.data.mocap.tsv_files import read_qtm_tsv
from tensegrity_env.io_utils import InputError

#: file extensions :func:`read_recording` reads
MOCAP_SUFFIXES = (".c3d", ".csv", ".txt", ".tsv")


def read_recording(path: str | Path, units: str | None = None, up: str = "z") -> MarkerRecording:
    """Read a C3D file, a Qualisys TSV export, an OptiTrack Motive or Vicon Nexus CSV
    export or a plain CSV, by content; placeholder samples for unseen markers are read
    as NaN.

    ``units`` (``"m"``/``"mm"``) is used only where the file does not say; ``up``: the
    file's vertical axis (``x``, ``y`` or ``z``), rotated to z.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such motion-capture file")
    if p.suffix.lower() == ".c3d":
        return read_c3d(p, units).check().without_placeholders().z_up(up)
    if p.suffix.lower() in (".csv", ".txt"):
        return read_csv(p, units).check().without_placeholders().z_up(up)
    if p.suffix.lower() == ".tsv":
        return read_qtm_tsv(p, units).check().without_placeholders().z_up(up)
    raise InputError(f"{p}: unknown motion-capture format (expected .c3d, .csv or .tsv)")
