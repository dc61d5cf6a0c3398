"""Small I/O helpers shared by every command: user-facing errors, output checks, atomic writes.

The rules every command that writes follows:

* **Outputs are checked before any work starts** (:func:`check_output_file`,
  :func:`check_output_dir`): the path is not inside a file, a file output is not a
  folder (and a folder output not a file), and files can be created where it goes.
  A failed check is an :class:`InputError` (one line, exit 2).
* **Existing outputs are never replaced silently**: an existing output file, or an
  output folder that already holds files, is refused with its path unless the
  command's ``--force`` (:func:`add_force_option`) is given; with ``--force`` the
  files of the same name are replaced.
* **Outputs are never inputs**: an output that is (by resolved path, symbolic or
  hard link) one of the command's input files (:func:`protect_inputs`, or the
  ``inputs`` of the output checks) is refused, ``--force`` or not, before any work
  and again just before the rename.
* **Nothing half-written is left under a final name**: files are written beside
  their final path and renamed only when complete (:func:`atomic_path`); report
  folders are assembled in a temporary folder and moved into place
  (:func:`atomic_dir`). While a file is written, Ctrl-C and SIGTERM are held: the
  temporary file is removed and the signal then ends the run (130 / 143), so that
  no writer (HDF5's C code, a finalizer) can swallow it. Outside writes SIGTERM
  raises :class:`Terminated` in the main thread (:func:`sigterm_raises`) so that, as
  for Ctrl-C, every temporary file and folder is removed on the way out.
* **Params files are standard JSON** (:func:`atomic_write_json`, used by
  ``Model.save``): a value that is not finite (an infinite standard error, a diverged
  error) is written as ``null``, never as the ``NaN`` / ``Infinity`` that other JSON
  readers refuse.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

#: exit status of a run ended by SIGTERM (128 + 15, as a shell reports it)
TERMINATED_EXIT = 128 + signal.SIGTERM


class InputError(Exception):
    """Bad user input: the CLI prints ``error: <message>`` on one line and exits 2."""


class StageError(Exception):
    """A stage of a pipeline ended without a usable result (diverged, implausible).

    The message names the stage, the cause and what to try; the CLI prints
    ``error: <message>`` on one line and exits 1.
    """

    def __init__(self, stage: str, cause: str, advice: str) -> None:
        super().__init__(f"{stage} failed: {cause}; try {advice}")
        self.stage, self.cause, self.advice = stage, cause, advice


class Terminated(BaseException):
    """SIGTERM, raised in the main thread so that ``finally`` blocks and context managers run."""


@contextmanager
def sigterm_raises() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` (main thread only; else a no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        raise Terminated(signum)

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def one_line(e: BaseException) -> str:
    """An error's message on one line: a line break (in a file name, say) written as ``\\n``."""
    return str(e).replace("\r", "\\r").replace("\n", "\\n")


def parse_error(e: Exception) -> str:
    """A parser's error (YAML's ``MarkedYAMLError``, ...) on one line, led by the place it
    names: ``line L, column C: <problem>``; else its first line."""
    mark = getattr(e, "problem_mark", None)
    first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    problem = getattr(e, "problem", None) or first
    if mark is None:
        return problem
    return f"line {mark.line + 1}, column {mark.column + 1}: {problem}"


def run_reporting(work: Callable[[], int]) -> int:
    """Run ``work`` with SIGTERM raising (:func:`sigterm_raises`) and turn the ways a run
    ends into one line on stderr and an exit status: bad input 2, a failed stage 1,
    Ctrl-C 130, SIGTERM 143, a closed standard output (``| head``) 141, quietly;
    otherwise ``work``'s own status."""
    _INPUTS.clear()
    try:
        with sigterm_raises():
            code = work()
            sys.stdout.flush()
            return code
    except BrokenPipeError:
        # the reader went away: later writes (and the flush at exit) go nowhere, as
        # Unix tools stop when their output is closed
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + 13
    except InputError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        return 2
    except StageError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("terminated", file=sys.stderr)
        return TERMINATED_EXIT
    finally:
        _INPUTS.clear()


def add_force_option(parser: argparse.ArgumentParser) -> None:
    """Add the ``--force`` flag every writing command shares."""
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace existing outputs (without it an existing output file, or an output "
        "folder that holds files, is refused)",
    )


def check_number(
    option: str,
    value: float | None,
    low: float | None = None,
    *,
    strict: bool = False,
    high: float | None = None,
) -> None:
    """Raise :class:`InputError` naming ``option`` unless ``value`` is finite and in range.

    ``None`` (an option left unset) passes. The range is ``value >= low`` (``> low``
    with ``strict``) and ``value <= high``; either bound may be None.
    """
    if value is None:
        return
    bounds = []
    if low is not None:
        bounds.append(f"{'>' if strict else '>='} {low:g}")
    if high is not None:
        bounds.append(f"<= {high:g}")
    ok = math.isfinite(value) and (
        low is None or (value > low if strict else value >= low)
    ) and (high is None or value <= high)
    if not ok:
        raise InputError(
            f"{option} must be a finite number{' ' if bounds else ''}{' and '.join(bounds)}, "
            f"got {value!r}"
        )


#: the input files of the running command (as given); no output may replace one.
#: :func:`run_reporting` empties it before and after each command.
_INPUTS: list[Path] = []


def protect_inputs(*paths: str | Path | Iterable[str | Path | None] | None) -> None:
    """Record input files of the running command (paths, lists of paths; None is
    skipped): :func:`check_output_file`, :func:`check_output_dir`, :func:`atomic_path`
    and :func:`atomic_dir` refuse to write over any of them."""
    for p in paths:
        if p is None:
            continue
        if isinstance(p, (str, Path)):
            _INPUTS.append(Path(p))
        else:
            protect_inputs(*p)


def input_behind(path: str | Path) -> Path | None:
    """The recorded input file that ``path`` is (same resolved path, or the same file
    through a symbolic or hard link), or None."""
    p = Path(path)
    resolved = p.resolve()
    for inp in _INPUTS:
        if inp.resolve() == resolved:
            return inp
        try:
            if os.path.samefile(p, inp):
                return inp
        except OSError:  # either does not exist: not the same file
            continue
    return None


def refuse_input(path: str | Path, option: str | None = None) -> None:
    """Raise :class:`InputError` if ``path`` is one of the command's input files
    (:func:`input_behind`); ``option`` (e.g. ``"-o"``) names where it was given."""
    inp = input_behind(path)
    if inp is not None:
        where = f"{option} {path}" if option else str(path)
        same = "" if str(inp) == str(path) else f" ({inp})"
        raise InputError(f"{where}: is an input file of this command{same}; an output never "
                         "replaces an input, --force or not: name another output")


def _nearest_existing(path: Path) -> Path:
    """``path`` or its closest ancestor that exists."""
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_creatable(path: Path, option: str) -> None:
    """Raise unless files (and missing folders) can be created at ``path``'s location."""
    anchor = _nearest_existing(path.parent)
    if not anchor.is_dir():
        raise InputError(f"{option} {path}: {anchor} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".write-check.", dir=anchor)
    except OSError as e:
        raise InputError(f"{option} {path}: cannot create files in {anchor} ({e.strerror})") from None
    os.close(fd)
    os.unlink(probe)


def check_output_file(
    path: str | Path,
    force: bool = False,
    option: str = "-o",
    inputs: Iterable[str | Path | None] = (),
) -> Path:
    """Check an output file before any work: not an input, creatable, not a folder, not
    replaced unasked.

    Args:
        path: the file the command will write.
        force: allow replacing an existing file (never an input).
        option: the option that named it, for the message (e.g. ``"-o"``).
        inputs: the command's input files, recorded (:func:`protect_inputs`) and
            refused as outputs.

    Returns:
        ``path`` as a :class:`~pathlib.Path`. Raises :class:`InputError` otherwise.
    """
    p = Path(path)
    protect_inputs(inputs)
    refuse_input(p, option)
    if p.is_dir():
        raise InputError(f"{option} {p}: is a folder; name a file")
    _check_creatable(p, option)
    if (p.exists() or p.is_symlink()) and not force:
        raise InputError(f"{option} {p}: exists (pass --force to replace it)")
    return p


def check_output_dir(
    path: str | Path,
    force: bool = False,
    option: str = "-o",
    inputs: Iterable[str | Path | None] = (),
) -> Path:
    """Check an output folder before any work: not an input, creatable, not a file, not
    reused unasked.

    A folder that already holds files is refused unless ``force`` (then files of the
    same name are replaced, never an input; others are left). ``inputs``: the command's
    input files (:func:`protect_inputs`). Returns ``path`` as a Path.
    """
    p = Path(path)
    protect_inputs(inputs)
    refuse_input(p, option)
    if p.exists() and not p.is_dir():
        raise InputError(f"{option} {p}: is a file; name a folder")
    if p.is_dir():
        if not force and any(p.iterdir()):
            raise InputError(f"{option} {p}: folder exists and holds files (pass --force to "
                             "replace them)")  # fmt: skip
        _check_creatable(p / "x", option)
    else:
        _check_creatable(p, option)
    return p


#: the signals held while a file is written: Ctrl-C and SIGTERM
HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def held_signals() -> Iterator[list[int]]:
    """Within the block, Ctrl-C and SIGTERM are recorded, not acted on; on the way out
    the handlers are restored and the first recorded signal is raised again (Ctrl-C:
    ``KeyboardInterrupt``; SIGTERM: :class:`Terminated` under :func:`sigterm_raises`).

    Yields the list of recorded signal numbers, so that a long writer can stop early
    (``if held: raise ...``); the exception leaves the block and the signal follows.
    Main thread only; elsewhere a no-op.
    """
    held: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield held
        return

    # a handler installed outside Python (None) could not be put back: left as it is
    previous: dict[int, Any] = {
        s: h for s in HELD_SIGNALS if (h := signal.getsignal(s)) is not None
    }

    def record(signum: int, frame: FrameType | None) -> None:
        if previous[signum] is not signal.SIG_IGN:  # an ignored signal stays ignored
            held.append(signum)

    for s in previous:
        signal.signal(s, record)
    try:
        yield held
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if held:
            signal.raise_signal(held[0])  # the restored handler acts on it now


def _make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing ancestors; returns those created, deepest first."""
    created = []
    p = folder.absolute()
    while not p.exists():
        created.append(p)
        p = p.parent
    folder.mkdir(parents=True, exist_ok=True)
    return created


def _remove_empty(folders: list[Path]) -> None:
    """Remove each folder of ``folders`` (deepest first) that is empty."""
    for d in folders:
        try:
            d.rmdir()
        except OSError:  # not empty, or already gone
            break


@contextmanager
def atomic_path(
    path: str | Path, suffix: str = "", keep_extension: bool = False
) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success.

    The temporary file is ``.<name>.<random><suffix>.tmp``, or with ``keep_extension``
    ``.<name>.<random>.tmp<extension of path>`` (for writers that pick the format from
    the extension). Ctrl-C and SIGTERM are held while the block runs
    (:func:`held_signals`): one that arrives removes the temporary file and then ends
    the run. An interrupted or failed writer leaves neither the temporary file, nor a
    file under the final name, nor a folder it created. ``path`` is checked against
    the command's input files (:func:`refuse_input`) before and just before the rename.
    """
    final = Path(path)
    refuse_input(final)
    tail = ".tmp" + final.suffix if keep_extension else suffix + ".tmp"
    with held_signals() as held:
        created = _make_parents(final.parent)
        tmp_path: Path | None = None
        done = False
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{final.name}.", suffix=tail, dir=final.parent)
            tmp_path = Path(tmp)
            os.close(fd)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp's 0600 would make outputs private
            yield tmp_path
            if not held:  # the final check: no signal came, the target is no input
                refuse_input(final)
                os.replace(tmp_path, final)
                done = True
        finally:
            if tmp_path is not None:
                tmp_path.unlink(missing_ok=True)
            if not done:
                _remove_empty(created)


@contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``path`` to assemble a report in; on success move
    it into place, on any failure or signal remove it.

    If ``path`` does not exist (or is empty) the folder is renamed onto it; otherwise
    (an existing folder, ``--force``) each file is moved in, replacing files of the same
    name and never an input file (:func:`refuse_input`, checked for every file before
    the first is moved). Folders created for it are removed on failure.
    """
    final = Path(path)
    refuse_input(final)
    created = _make_parents(final.parent)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent))
    except OSError:
        _remove_empty(created)
        raise
    done = False
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp's 0700 would make the report private
        yield tmp
        with held_signals() as held:
            files = sorted(p.relative_to(tmp) for p in tmp.rglob("*") if not p.is_dir())
            for rel in files:
                refuse_input(final / rel)
            if not held:
                if not final.exists() or (final.is_dir() and not any(final.iterdir())):
                    os.replace(tmp, final)
                else:
                    _merge_into(tmp, final)
                done = True
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        if not done:
            _remove_empty(created)


def _merge_into(source: Path, target: Path) -> None:
    """Move every file under ``source`` into ``target`` (same relative paths), replacing
    files of the same name."""
    for p in sorted(source.rglob("*")):
        dest = target / p.relative_to(source)
        if p.is_dir():
            dest.mkdir(exist_ok=True)
        else:
            os.replace(p, dest)


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns the final path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def strict_json(value: Any) -> Any:
    """``value`` with every float that is not finite replaced by ``None`` (JSON ``null``),
    through dicts, lists and tuples (tuples become lists)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    return value


def atomic_write_json(path: str | Path, doc: Any, indent: int = 2) -> Path:
    """Write ``doc`` as standard JSON (:func:`strict_json`) to ``path`` atomically."""
    text = json.dumps(strict_json(doc), indent=indent, allow_nan=False)
    return atomic_write_text(path, text + "\n")
