"""Build and load small C kernels once per machine, with the system C compiler.

Used by the spring-rod kernel (:mod:`tensegrity_env.native.kernel`) and the
identification's normal equations (:mod:`identification.linear.native_normal`). A kernel is
compiled with ``$CC`` (else ``cc``/``gcc``) into a cache folder
(``$TENSEGRITY_SR_CACHE``, else ``$XDG_CACHE_HOME/tensegrity-sr`` or
``~/.cache/tensegrity-sr``), keyed by the source, the flags and the CPU, and loaded
with :mod:`ctypes`. A kernel may be several files: its ``.c`` files are compiled
together into one library, and every file given (headers included) enters the key.
When no compiler works, :func:`build_and_load` raises
:class:`NativeUnavailable` and callers fall back to PyTorch.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

#: compiler flag sets tried in order (OpenMP and -march=native are optional)
FLAG_SETS: tuple[tuple[str, ...], ...] = (
    ("-O3", "-march=native", "-fno-math-errno", "-fopenmp"),
    ("-O3", "-fno-math-errno", "-fopenmp"),
    ("-O3", "-fno-math-errno"),
)


class NativeUnavailable(RuntimeError):
    """A C kernel cannot be built or loaded here (no working C compiler)."""


def cache_dir() -> Path:
    """Where compiled kernels are kept."""
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


def _compile(cc: str, sources: list[Path], flags: tuple[str, ...], out: Path) -> bool:
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=out.parent)
    os.close(fd)
    cmd = [cc, *flags, "-shared", "-fPIC", *map(str, sources), "-o", tmp, "-lm"]
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


def build_and_load(
    source: Path | Sequence[Path], defines: Sequence[str] = ()
) -> tuple[ctypes.CDLL, bool]:
    """Compile ``source`` (cached) and load it: the library and whether it has OpenMP.

    ``source`` is one C file or a kernel's files (its ``.c`` files compiled together,
    its headers found beside them); the library is named after the first. ``defines``:
    preprocessor definitions (``"NAME=VALUE"``, passed as ``-D``), part of the key.

    Raises:
        NativeUnavailable: no compiler, or no flag set builds and loads.
    """
    files = [source] if isinstance(source, Path) else list(source)
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc:
        raise NativeUnavailable("no C compiler found (set CC)")
    text = b"".join(f.name.encode() + b"\0" + f.read_bytes() for f in files)
    units = [f for f in files if f.suffix == ".c"]
    for flag_set in FLAG_SETS:
        flags = (*flag_set, *(f"-D{d}" for d in defines))
        key = hashlib.sha256(
            text + " ".join((cc, *flags)).encode() + _cpu_signature().encode()
        ).hexdigest()[:16]
        lib_path = cache_dir() / f"{files[0].stem}_{key}.so"
        if not lib_path.is_file() and not _compile(cc, units, flags, lib_path):
            continue
        try:
            return ctypes.CDLL(str(lib_path)), "-fopenmp" in flags
        except OSError:
            continue
    raise NativeUnavailable(f"could not build {files[0].name} with {cc}")
