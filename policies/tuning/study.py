"""The study: storage, sampler and pruner, worker processes, resuming, failed workers.

Storage
    By default an Optuna journal file, ``OUT/study.journal``
    (:class:`optuna.storages.JournalStorage` on a ``JournalFileBackend``), shared by
    the worker processes of one machine through file locks. A database URL
    (``postgresql://user:pass@host/db``, any SQLAlchemy URL Optuna accepts) lets
    workers on several machines share one study: start ``tensegrity-sr tune`` with the
    same ``--storage`` and ``--study`` on each; every machine keeps its trials' run
    folders in its own ``OUT``.
Sampler and pruner
    As rl-zoo3: multivariate TPE (its first ``n_startup`` trials random) and a
    median pruner that waits ``n_startup`` trials and a third of each trial's
    evaluations before it prunes.
Trials counted
    ``n_trials`` counts complete, pruned and running trials (as rl-zoo3's
    ``--max-total-trials``), so W workers stop together; a failed trial does not
    count and is run again with new settings.
Resuming
    The study is created with ``load_if_exists``: running the same command again
    after a crash or Ctrl-C goes on with the trials it holds.
Failed workers
    A worker killed mid-trial leaves its trial RUNNING. Each worker, before every
    trial, marks FAIL the running trials of this machine whose process is gone
    (:func:`fail_orphaned_trials`); with a database storage Optuna's heartbeat does
    the same across machines (a trial whose worker has not beaten for
    ``grace_s`` seconds is failed by the next worker that starts a trial).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import socket
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import optuna
from optuna.storages import BaseStorage, JournalStorage, RDBStorage
from optuna.storages.journal import JournalFileBackend
from optuna.trial import TrialState

from policies.tuning.objective import Objective, TrialSettings
from tensegrity_env.io_utils import InputError

#: the states that count toward ``n_trials``
COUNTED = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.RUNNING)
#: database URL schemes (SQLAlchemy dialects Optuna's RDBStorage supports)
DB_SCHEMES = ("postgresql", "mysql", "sqlite")


@dataclass(frozen=True)
class StudyConfig:
    """One study and how its workers run.

    Attributes:
        trial: what every trial shares (algorithm, env, budget, output folder).
        study_name: the study's name in the storage.
        storage: a database URL, a journal file path, or None for ``OUT/study.journal``.
        n_trials: stop when the study holds this many complete + pruned + running trials.
        n_startup: random trials before TPE, and trials before the pruner acts.
        sampler_seed: worker ``i`` seeds its sampler with ``sampler_seed + i``
            (None: unseeded).
        heartbeat_s: heartbeat period of a database storage [s]; a trial is failed
            after ``2 * heartbeat_s`` without one.
    """

    trial: TrialSettings
    study_name: str
    storage: str | None = None
    n_trials: int = 20
    n_startup: int = 5
    sampler_seed: int | None = 0
    heartbeat_s: int = 60


def is_database_url(storage: str) -> bool:
    """True for a SQLAlchemy database URL (``postgresql://...``)."""
    scheme = storage.split("://", 1)[0].split("+", 1)[0] if "://" in storage else ""
    return scheme in DB_SCHEMES


def storage_label(cfg: StudyConfig) -> str:
    """The storage for messages and records, passwords hidden."""
    if cfg.storage is not None and is_database_url(cfg.storage):
        from sqlalchemy.engine import make_url

        return make_url(cfg.storage).render_as_string(hide_password=True)
    return str(journal_path(cfg))


def journal_path(cfg: StudyConfig) -> Path:
    """The journal file of a file-backed study."""
    return Path(cfg.storage) if cfg.storage else cfg.trial.out / "study.journal"


def open_storage(cfg: StudyConfig) -> BaseStorage:
    """The storage object of ``cfg`` (creates the journal file's folder).

    Raises :class:`InputError` for a URL with an unknown scheme or a database that
    cannot be reached.
    """
    if cfg.storage is not None and "://" in cfg.storage:
        if not is_database_url(cfg.storage):
            raise InputError(
                f"--storage {storage_label_raw(cfg.storage)}: not a database URL "
                f"({', '.join(DB_SCHEMES)}) nor a journal file path"
            )
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                return RDBStorage(
                    with_driver(cfg.storage),
                    heartbeat_interval=cfg.heartbeat_s,
                    grace_period=2 * cfg.heartbeat_s,
                    engine_kwargs={"pool_pre_ping": True},
                )
        except Exception as e:  # SQLAlchemy and the DB driver raise many types
            msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            if "DB access module" in msg:
                msg = "no database driver: pip install 'tensegrity-sr[distributed]' (psycopg2)"
            raise InputError(f"--storage {storage_label(cfg)}: cannot open ({msg})") from None
    path = journal_path(cfg)
    path.parent.mkdir(parents=True, exist_ok=True)
    return JournalStorage(JournalFileBackend(str(path)))


def with_driver(url: str) -> str:
    """``postgresql://`` as ``postgresql+psycopg2://`` where only psycopg2 is installed.

    SQLAlchemy 2.1 takes a bare ``postgresql://`` to mean psycopg 3; the
    ``distributed`` extra installs psycopg2.
    """
    if not url.startswith("postgresql://"):
        return url
    import importlib.util

    if importlib.util.find_spec("psycopg") is None and importlib.util.find_spec("psycopg2"):
        return "postgresql+psycopg2://" + url.removeprefix("postgresql://")
    return url


def storage_label_raw(url: str) -> str:
    """A URL with anything between ``://`` and ``@`` (user and password) hidden."""
    head, _, rest = url.partition("://")
    return f"{head}://***@{rest.split('@', 1)[1]}" if "@" in rest else url


def make_study(
    cfg: StudyConfig, worker: int = 0, storage: BaseStorage | None = None
) -> optuna.Study:
    """Create or load the study (maximizing), with this worker's sampler and pruner."""
    seed = None if cfg.sampler_seed is None else cfg.sampler_seed + worker
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        sampler = optuna.samplers.TPESampler(
            n_startup_trials=cfg.n_startup, seed=seed, multivariate=True
        )
    pruner = optuna.pruners.MedianPruner(
        n_startup_trials=cfg.n_startup, n_warmup_steps=cfg.trial.n_evaluations // 3
    )
    return optuna.create_study(
        storage=storage or open_storage(cfg), study_name=cfg.study_name, sampler=sampler,
        pruner=pruner,
        direction="maximize", load_if_exists=True,
    )  # fmt: skip


def counted(study: optuna.Study) -> int:
    """Trials that count toward ``n_trials`` (complete, pruned, running)."""
    return len(study.get_trials(deepcopy=False, states=COUNTED))


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def fail_orphaned_trials(study: optuna.Study, storage: BaseStorage) -> list[int]:
    """Mark FAIL this machine's running trials whose worker process is gone.

    Returns the numbers of the trials failed. Also runs Optuna's heartbeat check
    (:func:`optuna.storages.fail_stale_trials`), which acts on database storages.
    ``storage`` is the study's storage.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        optuna.storages.fail_stale_trials(study)
    host, failed = socket.gethostname(), []
    study_id = storage.get_study_id_from_name(study.study_name)
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        pid = t.user_attrs.get("pid")
        if t.user_attrs.get("host") == host and isinstance(pid, int) and not pid_alive(pid):
            try:
                trial_id = storage.get_trial_id_from_study_id_trial_number(study_id, t.number)
                storage.set_trial_state_values(trial_id, state=TrialState.FAIL)
                failed.append(t.number)
            except optuna.exceptions.UpdateFinishedTrialError:
                pass  # another worker failed it first
    return failed


def run_worker(cfg: StudyConfig, worker: int = 0) -> None:
    """Run trials until the study holds ``cfg.n_trials`` counted trials.

    One PyTorch thread and one physics thread per worker; meant as a process's target.
    """
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = open_storage(cfg)
    study = make_study(cfg, worker, storage)
    objective = Objective(cfg.trial)
    while True:
        fail_orphaned_trials(study, storage)
        if counted(study) >= cfg.n_trials:
            return
        study.optimize(objective, n_trials=1, gc_after_trial=True, catch=())


def start_workers(cfg: StudyConfig, n: int) -> list[mp.process.BaseProcess]:
    """``n`` worker processes (spawned: each imports torch afresh, one thread each)."""
    ctx = mp.get_context("spawn")
    procs: list[mp.process.BaseProcess] = [
        ctx.Process(target=run_worker, args=(cfg, i), daemon=False) for i in range(n)
    ]
    for p in procs:
        p.start()
    return procs


def watch(
    cfg: StudyConfig, procs: list[mp.process.BaseProcess], progress: bool = True,
    poll_s: float = 2.0,
) -> optuna.Study:  # fmt: skip
    """Wait for the workers, showing finished trials and the best value so far."""
    from tqdm import tqdm

    study = optuna.load_study(study_name=cfg.study_name, storage=open_storage(cfg))
    done_states = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
    bar = tqdm(total=cfg.n_trials, unit="trial", disable=not progress, dynamic_ncols=True)
    try:
        while True:
            trials = study.get_trials(deepcopy=False)
            done = sum(t.state in done_states for t in trials)
            bar.update(done - bar.n)
            complete = [t for t in trials if t.state == TrialState.COMPLETE]
            running = sum(t.state == TrialState.RUNNING for t in trials)
            post: dict[str, int | str] = {"running": running}
            if complete:
                post["best"] = f"{max(t.value for t in complete if t.value is not None):.2f}"
            bar.set_postfix(post, refresh=True)
            if not any(p.is_alive() for p in procs):
                break
            time.sleep(poll_s)
    finally:
        bar.close()
        for p in procs:
            p.join(timeout=30)
            if p.is_alive():
                p.terminate()
                p.join()
    bad = [p.exitcode for p in procs if p.exitcode not in (0, None)]
    if bad:
        print(f"{len(bad)} worker(s) exited with an error (exit codes {bad})")
    return study

