"""C3D files through ezc3d (the pyomeco project's reader and writer).

ezc3d is maintained, reads and writes C3D (what the tests and the demo need to make
real files rather than byte strings), and gives the ``POINT`` parameters — labels,
units, rate — and marks unseen samples as NaN (negative residual in the file).
Positions are stored as 32-bit floats: the file's precision is ~6e-8 relative.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from identification.data.mocap.recording import MarkerRecording, unit_scale
from tensegrity_env.io_utils import InputError, atomic_path


def read_c3d(path: Path, units: str | None = None) -> MarkerRecording:
    """Read the 3-D points of a C3D file; ``units`` only if the file states none."""
    import ezc3d

    declared = _declared_frames(path)  # before ezc3d, which can loop on a truncated file
    try:
        c = ezc3d.c3d(str(path))
    except (OSError, RuntimeError, ValueError) as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(f"{path}: not a readable C3D file (truncated or corrupt: {first})") from None
    try:
        point = c["parameters"]["POINT"]
        labels = [str(s).strip() for s in point["LABELS"]["value"]]
        rate = float(np.asarray(point["RATE"]["value"]).ravel()[0])
        unit_values = point["UNITS"]["value"] if "UNITS" in point else []
        data = np.asarray(c["data"]["points"], dtype=float)  # (4, M, F)
        first_frame = int(c["header"]["points"]["first_frame"])
    except (KeyError, IndexError, TypeError) as e:
        raise InputError(f"{path}: C3D file without 3-D point data ({e})") from None
    if data.ndim != 3 or data.shape[1] == 0:
        raise InputError(f"{path}: C3D file holds no 3-D points")
    if declared is not None and declared > data.shape[2]:
        raise InputError(
            f"{path}: not a readable C3D file (truncated or corrupt: header declares {declared} "
            f"frames, data holds {data.shape[2]})"
        )
    labels = labels[: data.shape[1]]
    if len(labels) < data.shape[1]:
        labels += [f"*{i}" for i in range(len(labels), data.shape[1])]
    scale = unit_scale(str(unit_values[0]) if len(unit_values) else None, path, units)
    points = np.transpose(data[:3], (2, 1, 0)) * scale  # (F, M, 3) [m]
    n = points.shape[0]
    time = (first_frame + np.arange(n)) / rate
    return MarkerRecording(path, time - time[0], points, labels, rate)


#: C3D processor types whose header words this check reads: Intel (little-endian) and
#: MIPS (big-endian); DEC's floats differ and are left to ezc3d
BYTE_ORDER = {84: "<", 86: ">"}


def _declared_frames(path: Path) -> int | None:
    """Frame count the file's header declares (first/last frame words), after checking
    that the file holds the parameter blocks and point data its header declares; ezc3d
    reports only the frames it could read, and loops on some truncated files. None
    where the header cannot be read this way (left to ezc3d)."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(512)
        if len(head) < 10 or head[1] != 0x50:
            return None
        fh.seek(max(head[0] - 1, 0) * 512)
        params = fh.read(4)

    def truncated(what: str) -> InputError:
        return InputError(f"{path}: not a readable C3D file (truncated or corrupt: {what})")

    if len(head) < 512 or len(params) < 4:
        raise truncated(f"{size} bytes hold no complete header and parameter section")
    order = BYTE_ORDER.get(params[3])
    if order is None:
        return None
    points, analog, first, last = struct.unpack_from(order + "HHHH", head, 2)
    (scale,) = struct.unpack_from(order + "f", head, 12)
    (data_block,) = struct.unpack_from(order + "H", head, 16)
    param_end = (head[0] - 1 + params[2]) * 512
    if param_end > size:
        raise truncated(f"the header declares parameters up to byte {param_end}, the file has "
                        f"{size}")  # fmt: skip
    if last < first:
        return None
    frames = last - first + 1
    word = 4 if scale < 0 else 2  # a negative scale factor: 32-bit float samples
    need = max(data_block - 1, 0) * 512 + frames * (4 * points + analog) * word
    if need > size:
        held = max(size - max(data_block - 1, 0) * 512, 0) // max((4 * points + analog) * word, 1)
        raise truncated(f"header declares {frames} frames, data holds {held}")
    return frames


def write_c3d(
    path: str | Path, points: np.ndarray, names: list[str], rate: float, units: str = "mm"
) -> Path:
    """Write marker positions ``points`` (F, M, 3) [m] (NaN: not seen) as a C3D file.

    Uniform frames at ``rate`` [Hz] (C3D has no per-frame time); written atomically.
    """
    import ezc3d

    scale = {"mm": 1e3, "m": 1.0}[units]
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(rate)]
    c["parameters"]["POINT"]["LABELS"]["value"] = list(names)
    c["parameters"]["POINT"]["UNITS"]["value"] = [units]
    data = np.ones((4, points.shape[1], points.shape[0]))
    data[:3] = np.transpose(points, (2, 1, 0)) * scale
    c["data"]["points"] = data
    with atomic_path(path, keep_extension=True) as tmp:
        c.write(str(tmp))
    return Path(path)
