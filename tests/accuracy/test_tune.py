"""Hyperparameter search: worker processes sharing a journal file or a PostgreSQL study.

Trials train a few hundred env steps, so the values mean little; what is checked is
the bookkeeping: distinct trial numbers, one run folder per trial holding the settings
the trial reports, the trial count, failed workers' trials marked FAIL.
"""

from __future__ import annotations

import glob
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import optuna
import pytest
import yaml
from optuna.trial import TrialState

from policies.tuning.objective import TrialSettings, base_entry, trial_folder
from policies.tuning.study import (
    StudyConfig,
    counted,
    make_study,
    open_storage,
    run_worker,
    start_workers,
)
from tensegrity_env.io_utils import InputError

ENV = "IcosahedronSR-v0"


def config(
    out: Path, n_trials: int, storage: str | None = None, timesteps: int = 256
) -> StudyConfig:
    base = base_entry("ppo", ENV, None)
    base["n_envs"] = 4
    settings = TrialSettings(
        "ppo", ENV, base, out, timesteps, n_evaluations=2, eval_episodes=1, tensorboard=False
    )
    return StudyConfig(settings, "test", storage, n_trials, n_startup=1, heartbeat_s=1)


def check_trials(cfg: StudyConfig, worker_pids: set[int]) -> list[optuna.trial.FrozenTrial]:
    """Every finished trial ran in one of the workers, in its own folder, as reported."""
    study = optuna.load_study(study_name=cfg.study_name, storage=open_storage(cfg))
    done = study.get_trials(states=(TrialState.COMPLETE, TrialState.PRUNED))
    assert len(done) == cfg.n_trials == counted(study)
    assert len({t.number for t in done}) == len(done)
    for t in done:
        assert t.user_attrs["pid"] in worker_pids
        folder = trial_folder(cfg.trial.out, t.number)
        assert (folder / "model.zip").exists()
        on_disk = yaml.safe_load((folder / "hyperparams.yml").read_text())[ENV]
        assert on_disk == t.user_attrs["hyperparams"]
        # the sampled parameters are the ones trained with (rl-zoo3's names)
        assert on_disk["n_steps"] == 2 ** t.params["n_steps_pow"]
        assert on_disk["gamma"] == pytest.approx(1 - t.params["one_minus_gamma"])
        # each trial had its own seed: seed + number
        assert yaml.safe_load((folder / "model.json").read_text())["seed"] == t.number
        assert len(t.intermediate_values) >= 1
    return done


def run_two_workers(cfg: StudyConfig) -> None:
    make_study(cfg)
    procs = start_workers(cfg, 2)
    for p in procs:
        p.join()
    assert [p.exitcode for p in procs] == [0, 0]
    check_trials(cfg, {p.pid for p in procs})


def test_two_workers_share_a_journal_study(tmp_path: Path) -> None:
    cfg = config(tmp_path, n_trials=3)
    run_two_workers(cfg)
    assert (tmp_path / "study.journal").exists()
    # running again resumes: the study already holds its trials, no new one starts
    run_worker(cfg)
    study = optuna.load_study(study_name="test", storage=open_storage(cfg))
    assert len(study.trials) == 3


def test_killed_worker_trial_fails_and_the_study_goes_on(tmp_path: Path) -> None:
    slow = config(tmp_path, n_trials=2, timesteps=10_000_000)
    make_study(slow)
    (proc,) = start_workers(slow, 1)
    study = optuna.load_study(study_name="test", storage=open_storage(slow))
    while not any("pid" in t.user_attrs for t in study.get_trials(states=(TrialState.RUNNING,))):
        assert proc.is_alive()
        time.sleep(0.5)
    os.kill(proc.pid, signal.SIGKILL)
    proc.join()
    fast = config(tmp_path, n_trials=2)
    (proc2,) = start_workers(fast, 1)
    proc2.join()
    assert proc2.exitcode == 0
    states = [t.state for t in study.get_trials()]
    assert states[0] == TrialState.FAIL
    assert all(s in (TrialState.COMPLETE, TrialState.PRUNED) for s in states[1:])
    check_trials(fast, {proc2.pid})


def test_bad_storage_is_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not a database URL"):
        open_storage(config(tmp_path, 1, storage="redis://localhost/0"))
    with pytest.raises(InputError, match="cannot open"):
        make_study(config(tmp_path, 1, storage="postgresql://u:secret@127.0.0.1:1/none"))


# ---------------------------------------------------------------------- PostgreSQL
def pg_bin() -> Path | None:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    return Path(found[-1]).parent if found else None


@pytest.fixture
def postgres_url() -> Iterator[str]:
    """A PostgreSQL server in a temporary folder, reached by its Unix socket."""
    pytest.importorskip("psycopg2", reason="the PostgreSQL driver (dev extra psycopg2-binary)")
    bindir = pg_bin()
    if bindir is None:
        pytest.skip("PostgreSQL server binaries not installed (apt-get install postgresql)")
    root = Path(tempfile.mkdtemp(prefix="pg_"))
    os.chmod(root, 0o755)
    data, sock = root / "data", root / "sock"
    sock.mkdir()
    as_user: list[str] = []
    if os.geteuid() == 0:  # initdb refuses to run as root
        if shutil.which("runuser") is None:
            pytest.skip("running as root without runuser: cannot start PostgreSQL as another user")
        shutil.chown(root, "nobody")
        shutil.chown(sock, "nobody")
        as_user = ["runuser", "-u", "nobody", "--"]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    subprocess.run(
        [*as_user, str(bindir / "initdb"), "-D", str(data), "-A", "trust", "-U", "postgres"],
        check=True, capture_output=True,
    )  # fmt: skip
    opts = f"-k {sock} -p {port} -c listen_addresses=''"
    log = root / "server.log"
    start = [*as_user, str(bindir / "pg_ctl"), "-D", str(data), "-o", opts, "-l", str(log), "-w"]
    # the server inherits pg_ctl's output: no pipe, or waiting for pg_ctl never ends
    subprocess.run(
        [*start, "start"], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        yield f"postgresql://postgres@/postgres?host={sock}&port={port}"
    finally:
        stop = [*as_user, str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"]
        subprocess.run(stop, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        shutil.rmtree(root, ignore_errors=True)


def test_two_workers_share_a_postgresql_study(tmp_path: Path, postgres_url: str) -> None:
    cfg = config(tmp_path, n_trials=2, storage=postgres_url)
    run_two_workers(cfg)
    assert not (tmp_path / "study.journal").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--workers", "0"], "--workers must be >= 1"),
        (["--trials", "-1"], "--trials must be >= 0"),
        (["--timesteps", "2", "--evaluations", "4"], "--timesteps must be at least"),
        (["--env", "NoSuchEnv-v0"], "unknown environment id"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from tensegrity_sr.cli import main

    assert main(["tune", "ppo", "--out", str(tmp_path / "t"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and message in err and "\n" not in err
    assert not (tmp_path / "t").exists()


def test_trial_folders_of_another_study_are_not_overwritten(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from tensegrity_sr.cli import main

    (tmp_path / "trials" / "trial_0000").mkdir(parents=True)
    (tmp_path / "trials" / "trial_0000" / "model.zip").write_bytes(b"x")
    assert main(["tune", "ppo", "--out", str(tmp_path), "--study", "fresh"]) == 2
    assert "holds trials of another study" in capsys.readouterr().err
    assert (tmp_path / "trials" / "trial_0000" / "model.zip").read_bytes() == b"x"


def test_enqueued_recipe_runs_as_one_trial(tmp_path: Path) -> None:
    from policies.tuning.objective import write_hyperparams
    from tensegrity_sr.cli import main

    recipe = base_entry("ppo", ENV, None)
    recipe.update(n_envs=4, n_steps=16, batch_size=64, n_epochs=1, learning_rate=1e-3)
    write_hyperparams(tmp_path / "recipe.yml", ENV, recipe)
    argv = ["tune", "ppo", "--out", str(tmp_path / "t"), "--trials", "2", "--timesteps", "256",
            "--evaluations", "2", "--eval-episodes", "1", "--startup-trials", "1",
            "--n-envs", "4", "--no-tensorboard", "--no-progress",
            "--enqueue", str(tmp_path / "recipe.yml")]  # fmt: skip
    assert main(argv) == 0
    study = optuna.load_study(study_name=f"ppo_{ENV}", storage=open_storage(
        config(tmp_path / "t", 2)))  # fmt: skip
    first, second = study.trials
    assert first.user_attrs["enqueued"] == str(tmp_path / "recipe.yml")
    assert "enqueued" not in second.user_attrs
    # the enqueued trial trained with the recipe (ent_coef 0 moved to the range's 1e-8)
    trained = yaml.safe_load((trial_folder(tmp_path / "t", 0) / "hyperparams.yml").read_text())[ENV]
    assert trained == {**recipe, "ent_coef": 1e-8}
    summary = yaml.safe_load((tmp_path / "t" / "study.json").read_text())
    assert summary["trials"][0]["enqueued"] == str(tmp_path / "recipe.yml")
    assert "ent_coef 0 is outside" in summary["settings"]["enqueued"][0]["notes"][0]
    # running again resumes the study without queueing the recipe a second time
    assert main([*argv[:5], "3", *argv[6:]]) == 0
    study = optuna.load_study(study_name=f"ppo_{ENV}", storage=open_storage(
        config(tmp_path / "t", 3)))  # fmt: skip
    assert [("enqueued" in t.user_attrs) for t in study.trials] == [True, False, False]


def test_enqueued_file_the_search_cannot_draw_is_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from policies.tuning.objective import write_hyperparams
    from tensegrity_sr.cli import main

    recipe = base_entry("ppo", ENV, None)
    recipe["n_steps"] = 100
    write_hyperparams(tmp_path / "recipe.yml", ENV, recipe)
    for path, message in ((tmp_path / "recipe.yml", "n_steps 100 is not a power of two"),
                          (tmp_path / "none.yml", "no such file")):  # fmt: skip
        assert main(["tune", "ppo", "--out", str(tmp_path / "t"), "--enqueue", str(path)]) == 2
        err = capsys.readouterr().err.strip()
        assert err == f"error: --enqueue {path}: {message}"
    assert not (tmp_path / "t").exists()
