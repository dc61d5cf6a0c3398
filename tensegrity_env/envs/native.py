"""Build and load the C kernel of the identified model's control step (``native_step.c``).

The kernel is compiled once per machine with the system C compiler (``$CC``, else
``cc``) into a cache folder (``$TENSEGRITY_SR_CACHE``, else
``$XDG_CACHE_HOME/tensegrity-sr`` or ``~/.cache/tensegrity-sr``), keyed by the source,
the flags and the CPU, and loaded with :mod:`ctypes`. Building takes about a second;
when no compiler works, :func:`load_kernel` raises :class:`NativeUnavailable` and the
environments step the PyTorch engine instead.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path

SOURCE = Path(__file__).with_name("native_step.c")

#: compiler flag sets tried in order (OpenMP and -march=native are optional)
FLAG_SETS: tuple[tuple[str, ...], ...] = (
    ("-O3", "-march=native", "-fno-math-errno", "-fopenmp"),
    ("-O3", "-fno-math-errno", "-fopenmp"),
    ("-O3", "-fno-math-errno"),
)


class NativeUnavailable(RuntimeError):
    """The C kernel cannot be built or loaded here (no working C compiler)."""


def cache_dir() -> Path:
    env = os.environ.get("TENSEGRITY_SR_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "tensegrity-sr"


def _cpu_signature() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return line
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _compile(cc: str, flags: tuple[str, ...], out: Path) -> bool:
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=out.parent)
    os.close(fd)
    cmd = [cc, *flags, "-shared", "-fPIC", str(SOURCE), "-o", tmp, "-lm"]
    try:
        done = subprocess.run(cmd, capture_output=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired):
        Path(tmp).unlink(missing_ok=True)
        return False
    if done.returncode != 0:
        Path(tmp).unlink(missing_ok=True)
        return False
    os.replace(tmp, out)  # atomic: concurrent builders never see a partial library
    return True


@lru_cache(maxsize=1)
def load_kernel() -> tuple[ctypes.CDLL, bool]:
    """The loaded library and whether it has OpenMP. Raises :class:`NativeUnavailable`."""
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc:
        raise NativeUnavailable("no C compiler found (set CC)")
    source = SOURCE.read_bytes()
    for flags in FLAG_SETS:
        key = hashlib.sha256(
            source + " ".join((cc, *flags)).encode() + _cpu_signature().encode()
        ).hexdigest()[:16]
        lib_path = cache_dir() / f"native_step_{key}.so"
        if not lib_path.is_file() and not _compile(cc, flags, lib_path):
            continue
        try:
            lib = ctypes.CDLL(str(lib_path))
        except OSError:
            continue
        dbl, i32 = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int)
        c_int = ctypes.c_int
        lib.tsr_step.argtypes = [
            c_int, c_int, c_int, c_int, c_int, ctypes.c_double, c_int, dbl, dbl, dbl, i32, c_int
        ]  # fmt: skip
        lib.tsr_step.restype = c_int
        lib.tsr_max_rods.restype = c_int
        lib.tsr_max_nodes.restype = c_int
        return lib, "-fopenmp" in flags
    raise NativeUnavailable(f"could not build {SOURCE.name} with {cc}")
