"""Ctrl-C and SIGTERM during a file's write end the run, every time, and leave nothing.

A child process writes a dataset (the HDF5 writer that ``generate`` uses) several
times; each trial is stopped at one point of the write (the file just opened, the
first, a middle and the last array, the close) by a signal that arrives either from
outside (this test, while the writer waits on its standard input) or while Python
runs a finalizer inside the writer, where an exception raised by a signal handler is
printed as ``Exception ignored`` and lost. Each trial must return 130 (Ctrl-C) or 143
(SIGTERM) and leave no temporary file and no output; the process's own exit status is
that of its last trial.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tensegrity_sr.cli import main

ROOT = Path(__file__).resolve().parents[2]
GENERATE = ["generate", "--n-train", "2", "--n-val", "1", "--n-test", "1", "--steps", "10",
            "--no-progress"]  # fmt: skip
#: the points of the write where a trial is stopped: ("open", 0), ("array", k), ("close", 0)
POINTS = [("open", 0), ("array", 1), ("array", 6), ("array", -1), ("close", 0)]

CHILD = textwrap.dedent(
    """
    import json, os, signal, sys
    import h5py
    from identification.data.dataset import STATE_KEYS, read_dataset, read_ground_truth, write_dataset
    from tensegrity_env.io_utils import run_reporting

    source, out_dir, sig, trials = sys.argv[1], sys.argv[2], int(sys.argv[3]), json.loads(sys.argv[4])
    dataset, truth = read_dataset(source), read_ground_truth(source)
    state = {}

    class SignalInFinalizer:
        def __del__(self):
            os.kill(os.getpid(), sig)
            for _ in range(1000):  # the handler runs here, inside the finalizer
                pass

    def stop(point):
        if (point, state["count"]) != state["at"] and (point, -1) != state["at"]:
            return
        if state["how"] == "finalizer":
            SignalInFinalizer()  # dropped at once: its __del__ runs
        else:
            print("ready", flush=True)
            sys.stdin.readline()  # the signal arrives while this waits

    real_file, real_create, real_close = h5py.File.__init__, h5py.Group.create_dataset, h5py.File.close

    def file_init(self, *args, **kwargs):
        real_file(self, *args, **kwargs)
        if self.mode == "r+":
            state["count"] = 0
            stop("open")

    def create(self, *args, **kwargs):
        state["count"] += 1
        last = state["count"] == state["arrays"]
        d = real_create(self, *args, **kwargs)
        if last and state["at"] == ("array", -1):
            state["count"] = -1
        stop("array")
        return d

    def close(self):
        if self.id.valid and self.mode == "r+" and state.get("count") is not None:
            state["count"] = 0
            stop("close")
            state["count"] = None
        real_close(self)

    h5py.File.__init__, h5py.Group.create_dataset, h5py.File.close = file_init, create, close
    state["arrays"] = sum(getattr(s, k) is not None for s in dataset.splits.values()
                          for k in ("nodes", "control", *STATE_KEYS, "time", "cable_control"))
    code = 0
    for k, (how, point, n) in enumerate(trials):
        state.update(how=how, at=(point, n), count=None)
        out = os.path.join(out_dir, f"trial{k}.h5")

        def write():
            write_dataset(out, dataset, truth)
            return 0

        code = run_reporting(write)
        print(f"trial {k} {code} {sorted(os.listdir(out_dir))}", flush=True)
    sys.exit(code)
    """
)


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("source") / "data.h5"
    assert main([*GENERATE, "-o", str(path)]) == 0
    return path


def interactive() -> None:
    """The child's Ctrl-C as a terminal's foreground job has it: whatever started the
    tests (a CI runner, a background shell, an xdist worker) may ignore SIGINT, and an
    ignored signal is inherited and stays ignored (the test below)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize(("sig", "code", "said"), [(signal.SIGINT, 130, "interrupted"),
                                                   (signal.SIGTERM, 143, "terminated")])  # fmt: skip
def test_a_signal_at_any_point_of_the_write_ends_the_run_and_leaves_nothing(
    sig: int, code: int, said: str, source: Path, tmp_path: Path
) -> None:
    import json

    trials = [(how, point, n) for point, n in POINTS for how in ("finalizer", "outside")]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(source), str(tmp_path), str(int(sig)),
         json.dumps(trials)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=env, preexec_fn=interactive,
    )  # fmt: skip
    assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
    results = []
    for line in proc.stdout:
        if line.strip() == "ready":
            proc.send_signal(sig)
            proc.stdin.write("go\n")
            proc.stdin.flush()
        else:
            results.append(line.split(" ", 3))
    proc.wait()
    err = proc.stderr.read()
    assert [r[:3] for r in results] == [["trial", str(k), str(code)] for k in range(len(trials))], err
    assert all(r[3].strip() == "[]" for r in results), results  # no temporary, no output
    assert proc.returncode == code, err
    assert err.splitlines() == [said] * len(trials), err  # no "Exception ignored", no traceback


def test_an_ignored_signal_stays_ignored_and_the_file_is_written(tmp_path: Path) -> None:
    """A process that ignores Ctrl-C (started in the background by a shell) writes on."""
    from tensegrity_env.io_utils import atomic_path

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with atomic_path(tmp_path / "x.txt") as tmp:
            tmp.write_text("whole")
            signal.raise_signal(signal.SIGINT)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert [p.name for p in tmp_path.iterdir()] == ["x.txt"]
    assert (tmp_path / "x.txt").read_text() == "whole"
    assert signal.getsignal(signal.SIGINT) is previous
