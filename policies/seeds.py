"""Several seeds of one training recipe, trained in parallel processes.

``tensegrity-sr train ppo --seeds 0-4 --workers 2 -o runs/ppo`` trains seeds 0..4,
two at a time, each into its own run folder ``runs/ppo/s<seed>`` (as a single
``train`` writes it). Each process trains on one PyTorch and one physics thread.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from pathlib import Path
from typing import Any

from tensegrity_env.io_utils import InputError


def parse_seeds(spec: str) -> list[int]:
    """Seeds from ``"0-4"``, ``"0,2,7"`` or a mix (``"0-2,10"``), in order, without repeats.

    Raises :class:`InputError` naming ``--seeds`` for anything else.
    """
    seeds: list[int] = []
    try:
        for part in spec.split(","):
            lo, sep, hi = part.strip().partition("-")
            first, last = int(lo), int(hi) if sep else int(lo)
            if last < first:
                raise ValueError
            seeds += range(first, last + 1)
    except ValueError:
        raise InputError(
            f"--seeds {spec!r}: expected seeds like 0-4 or 0,2,7 (non-negative)"
        ) from None
    return list(dict.fromkeys(seeds))


def seed_folder(out: Path, seed: int) -> Path:
    """The run folder of ``seed`` under ``out``."""
    return out / f"s{seed}"


def train_one(kwargs: dict[str, Any]) -> tuple[int, str, int, float]:
    """Train one seed (a pool task): (seed, model path, timesteps, wall time [s])."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from policies.train import train

    result = train(**kwargs)
    return kwargs["seed"], str(result.model_path), result.timesteps, result.wall_s


def train_seeds(
    algo: str, env_id: str, out: Path, seeds: list[int], workers: int, **train_kwargs: Any
) -> list[tuple[int, str, int, float]]:
    """Train ``seeds`` with ``workers`` processes into ``out/s<seed>``.

    ``train_kwargs`` go to :func:`policies.train.train` for every seed (not ``seed``,
    ``out``, ``progress``). Every folder is checked before any training starts; with
    ``resume=True`` the seeds that have a run continue it and the others start afresh.
    Returns one (seed, model path, timesteps, wall time) per seed, in seed order.
    """
    if workers < 1:
        raise InputError("--workers must be >= 1")
    from policies.train import latest_checkpoint

    resume = bool(train_kwargs.pop("resume", False))
    started = {
        s: seed_folder(out, s).exists() and latest_checkpoint(seed_folder(out, s)) is not None
        for s in seeds
    }
    if not resume:
        for s in seeds:
            if started[s]:
                raise InputError(
                    f"{seed_folder(out, s)}: already holds a run (pass --resume to continue it, or another -o)"
                )
    # with --resume, seeds that have a run continue it and the others start
    tasks = [
        {**train_kwargs, "algo": algo, "env_id": env_id, "out": seed_folder(out, s), "seed": s,
         "progress": False, "torch_threads": 1, "resume": started[s]}
        for s in seeds
    ]  # fmt: skip
    if workers == 1:
        return [train_one(t) for t in tasks]
    with mp.get_context("spawn").Pool(min(workers, len(tasks))) as pool:
        return pool.map(train_one, tasks, chunksize=1)
