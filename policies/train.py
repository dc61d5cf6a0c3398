"""Train PPO or SAC on a (batched) environment, with checkpoints and resuming.

A run folder holds everything one training run writes::

    OUT/model.zip, model_vecnormalize.pkl, model.json    the final policy (artifacts)
    OUT/checkpoints/ckpt_<steps>.zip (+ _vecnormalize.pkl, .json, SAC: _replay_buffer.pkl)
    OUT/tb/<ALGO>_1/                                    TensorBoard event files

``train(..., resume=True)`` continues from the newest checkpoint (or the final model)
in ``OUT``: weights, optimizer, normalization statistics (and SAC's replay buffer)
are restored and the timestep counter goes on from where it stopped, in the same
TensorBoard run. The environments' and sampler's random streams are not restored,
so a resumed run is a valid continuation, not a bitwise replay of an uninterrupted one.

``train(..., init="model.zip")`` fine-tunes: a new run that starts from a trained
policy's weights, optimizer and normalization statistics (and curriculum level), on
environment arguments that may differ from the ones it was trained with (e.g.
``tipped_starts``); the budget and timestep counter start from 0, the sampler is seeded
with ``seed``, and the record keeps the policy it started from (``init``,
``init_timesteps``).
"""

from __future__ import annotations

import re
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import HumanOutputFormat, KVWriter, Logger
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize
from tqdm import tqdm

from policies.artifacts import (
    ALGOS,
    LoadedPolicy,
    load_vecnormalize,
    read_record,
    save_policy,
    stats_path,
)
from policies.curriculum import CurriculumCallback, task_goal_distance
from policies.goal_frame import VecGoalFrame
from policies.hyperparams import Hyperparams, load_hyperparams
from policies.vec import make_training_env
from tensegrity_env.io_utils import InputError, atomic_path

CHECKPOINT_RE = re.compile(r"ckpt_(\d+)\.zip$")


@dataclass(frozen=True)
class TrainResult:
    """What a finished run wrote.

    Attributes:
        model_path: the final model zip.
        timesteps: env steps trained in all (across resumes).
        wall_s: training wall-clock time in all [s] (across resumes).
        cpu_s: CPU time of the training process in all [s] (every thread, across
            resumes): the cost of a run apart from what else the machine runs.
        record: the run record written beside the model.
        policy: the trained policy in memory (statistics frozen), as it was saved.
    """

    model_path: Path
    timesteps: int
    wall_s: float
    cpu_s: float
    record: dict[str, Any]
    policy: LoadedPolicy


# ---------------------------------------------------------------------- callbacks
class ProgressBar(BaseCallback):
    """A tqdm bar over env steps with the mean return of the last 100 episodes."""

    def _on_training_start(self) -> None:
        total = int(self.locals["total_timesteps"])
        self.bar = tqdm(total=total, initial=self.num_timesteps, unit="step", dynamic_ncols=True)

    def _on_step(self) -> bool:
        self.bar.update(self.num_timesteps - self.bar.n)
        buf = self.model.ep_info_buffer
        if buf and self.n_calls % 20 == 0:
            self.bar.set_postfix(ep_return=f"{np.mean([e['r'] for e in buf]):.1f}", refresh=False)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


class Checkpoint(BaseCallback):
    """Saves model, statistics and run record every ``every`` env steps, atomically.

    SAC's replay buffer is saved too; only the newest one is kept (they are large).
    """

    def __init__(self, folder: Path, every: int, record: dict[str, Any], clock: Clock) -> None:
        super().__init__()
        self.folder, self.every, self.record, self.clock = folder, int(every), record, clock
        self._next = 0

    def _on_training_start(self) -> None:
        self._next = (self.num_timesteps // self.every + 1) * self.every

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._next = (self.num_timesteps // self.every + 1) * self.every
            save_checkpoint(self.model, self.folder, {**self.record, **self.clock.times()})
        return True


class Clock:
    """Wall and process CPU time of a run [s], carried over from the run it resumes."""

    def __init__(self, wall_before: float = 0.0, cpu_before: float = 0.0) -> None:
        self.wall_before, self.cpu_before = float(wall_before), float(cpu_before)
        self.wall_start, self.cpu_start = time.perf_counter(), time.process_time()

    def times(self) -> dict[str, float]:
        """``{"wall_s": ..., "cpu_s": ...}`` in all so far."""
        return {
            "wall_s": self.wall_before + time.perf_counter() - self.wall_start,
            "cpu_s": self.cpu_before + time.process_time() - self.cpu_start,
        }


def save_checkpoint(model: BaseAlgorithm, folder: Path, record: dict[str, Any]) -> Path:
    """Write ``ckpt_<steps>`` files into ``folder``; returns the zip's path."""
    path = folder / f"ckpt_{model.num_timesteps:010d}.zip"
    vecnorm = model.get_vec_normalize_env()
    save_policy(model, vecnorm, path, {**record, "timesteps": model.num_timesteps})
    if isinstance(model, OffPolicyAlgorithm):
        buffer = path.with_name(f"{path.stem}_replay_buffer.pkl")
        with atomic_path(buffer) as tmp:
            model.save_replay_buffer(tmp)
        for old in folder.glob("ckpt_*_replay_buffer.pkl"):
            if old != buffer:
                old.unlink()
    return path


def latest_checkpoint(out: Path) -> Path | None:
    """The model zip with the most timesteps in ``out`` (checkpoints or final), or None."""
    found: list[tuple[int, Path]] = []
    for p in (out / "checkpoints").glob("ckpt_*.zip"):
        m = CHECKPOINT_RE.search(p.name)
        if m:
            found.append((int(m.group(1)), p))
    final = out / "model.zip"
    if final.exists():
        found.append((int(read_record(final).get("timesteps", 0)), final))
    return max(found, key=lambda t: t[0])[1] if found else None


# ---------------------------------------------------------------------- training
def goal_frame_caps(venv: VecEnv) -> int | None:
    """The end caps a generic robot's goal-frame observation turns (None: the rolling
    task's layout); :class:`InputError` for a task without a goal (``shape``)."""
    from tensegrity_env.envs.robot_task import GoalTask, ShapeTask

    try:
        task = venv.get_attr("task", [0])[0]
    except AttributeError:
        return None
    if isinstance(task, ShapeTask):
        raise InputError("goal_frame: true needs a goal task (the shape task has no goal)")
    if isinstance(task, GoalTask):
        return 2 * task.sensors.topology.n_rods
    return None


def build_model(
    hp: Hyperparams,
    venv: VecEnv,
    seed: int,
    tb_dir: Path | None,
    verbose: int,
    caps: int | None = None,
) -> tuple[BaseAlgorithm, VecNormalize | None]:
    """A fresh model on ``venv`` (wrapped in VecNormalize if the settings say so);
    ``caps`` as :class:`~policies.goal_frame.VecGoalFrame`."""
    kwargs = hp.sb3_kwargs()
    vecnorm = None
    env: VecEnv = VecGoalFrame(venv, caps) if hp.goal_frame else venv
    if hp.normalize is not None:
        gamma = float(kwargs.get("gamma", 0.99))
        vecnorm = env = VecNormalize(env, gamma=gamma, **hp.normalize)
    tb = str(tb_dir) if tb_dir is not None else None
    model = ALGOS[hp.algo](
        hp.policy, env, seed=seed, device="cpu", tensorboard_log=tb, verbose=verbose, **kwargs
    )
    return model, vecnorm


def resume_model(
    ckpt: Path,
    algo: str,
    venv: VecEnv,
    tb_dir: Path | None,
    verbose: int,
    goal_frame: bool,
    caps: int | None = None,
) -> tuple[BaseAlgorithm, VecNormalize | None]:
    """The model, statistics (and replay buffer) of checkpoint ``ckpt`` on ``venv``."""
    vecnorm = None
    env: VecEnv = VecGoalFrame(venv, caps) if goal_frame else venv
    if stats_path(ckpt).exists():
        vecnorm = load_vecnormalize(stats_path(ckpt))
        vecnorm.set_venv(env)
        vecnorm.training = True
        env = vecnorm
    cls = ALGOS[algo]
    try:
        model = cls.load(ckpt, env=env, device="cpu", verbose=verbose)
    except Exception as e:
        raise InputError(
            f"{ckpt}: cannot resume from this checkpoint ({type(e).__name__})"
        ) from None
    model.tensorboard_log = str(tb_dir) if tb_dir is not None else None
    buffer = ckpt.with_name(f"{ckpt.stem}_replay_buffer.pkl")
    if isinstance(model, OffPolicyAlgorithm) and buffer.exists():
        model.load_replay_buffer(buffer)
    return model, vecnorm


def train(
    algo: str,
    env_id: str,
    out: str | Path,
    timesteps: int | None = None,
    seed: int = 0,
    n_envs: int | None = None,
    hyperparams: str | Path | None = None,
    checkpoint_every: int = 50_000,
    resume: bool = False,
    threads: int | None = 1,
    torch_threads: int = 1,
    progress: bool = True,
    tensorboard: bool = True,
    verbose: int = 0,
    command: str | None = None,
    callbacks: Sequence[BaseCallback] = (),
    env_kwargs: dict[str, Any] | None = None,
    init: str | Path | None = None,
) -> TrainResult:
    """Train ``algo`` on ``env_id`` into the run folder ``out``.

    Args:
        algo: ``"ppo"`` or ``"sac"``.
        env_id: a registered Gymnasium id (``IcosahedronSR-v0``, ``IcosahedronMJ-v0``).
        out: the run folder (see the module docstring).
        timesteps: budget in env steps (None: ``n_timesteps`` of the hyperparameters);
            PPO stops at the first whole rollout at or past it.
        seed: seeds the model, its sampler and environment ``i`` with ``seed + i``.
        n_envs: environments stepped together (None: the hyperparameters').
        hyperparams: YAML file keyed by env id (None: the shipped ``<algo>.yml``).
        checkpoint_every: checkpoint period [env steps].
        resume: continue the newest checkpoint in ``out`` instead of starting afresh.
        threads: physics threads of the batched env (None: every core).
        torch_threads: PyTorch CPU threads (1 suits these small networks).
        progress: show a progress bar.
        tensorboard: log to ``out/tb``.
        verbose: SB3 verbosity.
        command: the command line to record (default: ``sys.argv``).
        callbacks: more SB3 callbacks run during learning (one returning False stops
            it; the policy reached so far is saved as the final one).
        env_kwargs: the environment's own arguments (``TensegritySR-v0``: ``model``,
            ``robot``, ``task``, task options), over the hyperparameters' ``env_kwargs``;
            recorded with the run, so evaluation builds the same env.
        init: a trained policy (model zip) to fine-tune from (see the module
            docstring); a run in ``out`` with a checkpoint resumes that instead.
    """
    if algo not in ALGOS:
        raise InputError(f"unknown algorithm {algo!r} (choose from {', '.join(ALGOS)})")
    out = Path(out)
    hp = load_hyperparams(algo, env_id, hyperparams)
    n_envs = int(n_envs or hp.n_envs)
    total = int(timesteps or hp.n_timesteps)
    ckpt = latest_checkpoint(out) if out.exists() else None
    if ckpt is not None and not resume:
        raise InputError(
            f"{out}: already holds a run (pass --resume to continue it, or another -o)"
        )
    if resume and ckpt is None:
        raise InputError(f"{out}: no checkpoint to resume from")
    env_kw = {**hp.env_kwargs, **(env_kwargs or {})}
    env_kw = {k: str(v) if isinstance(v, Path) else v for k, v in env_kw.items()}
    torch.set_num_threads(torch_threads)
    venv = make_training_env(env_id, n_envs, seed, threads, env_kw)
    tb_dir = out / "tb" if tensorboard else None
    before = {"wall_s": 0.0, "cpu_s": 0.0}
    if ckpt is not None:
        prev = read_record(ckpt)
        if prev.get("algo", algo) != algo or prev.get("env_id", env_id) != env_id:
            raise InputError(
                f"{ckpt}: was trained with {prev.get('algo')} on {prev.get('env_id')}, "
                f"not {algo} on {env_id}"
            )
        before = {k: float(prev.get(k, 0.0)) for k in before}
        if prev.get("env_kwargs", env_kw) != env_kw:
            raise InputError(f"{ckpt}: was trained with env arguments {prev.get('env_kwargs')}, "
                             f"not {env_kw}")  # fmt: skip
        goal_frame = bool(prev.get("goal_frame", hp.goal_frame))
        caps = goal_frame_caps(venv) if goal_frame else None
        model, vecnorm = resume_model(ckpt, algo, venv, tb_dir, verbose, goal_frame, caps)
    elif init is not None:
        init = Path(init)
        start = read_record(init)
        if start.get("algo", algo) != algo or start.get("env_id", env_id) != env_id:
            raise InputError(f"{init}: was trained with {start.get('algo')} on "
                             f"{start.get('env_id')}, not {algo} on {env_id}")  # fmt: skip
        goal_frame = bool(start.get("goal_frame", hp.goal_frame))
        caps = goal_frame_caps(venv) if goal_frame else None
        model, vecnorm = resume_model(init, algo, venv, tb_dir, verbose, goal_frame, caps)
        model.num_timesteps = 0  # a new run: its budget counts from here
        model.set_random_seed(seed)
    else:
        goal_frame = hp.goal_frame
        caps = goal_frame_caps(venv) if goal_frame else None
        model, vecnorm = build_model(hp, venv, seed, tb_dir, verbose, caps)
    if tb_dir is None:
        # SB3's default logger makes a folder in the temp directory even when it only
        # prints; log to stdout alone instead
        writers: list[KVWriter] = [HumanOutputFormat(sys.stdout)] if verbose else []
        model.set_logger(Logger(folder=None, output_formats=writers))
    record: dict[str, Any] = {
        "algo": algo,
        "env_id": env_id,
        "seed": seed,
        "n_envs": n_envs,
        "target_timesteps": total,
        "hyperparams": hp.to_dict(),
        "hyperparams_file": hp.source,
        "vecnormalize": vecnorm is not None,
        "goal_frame": goal_frame,
        "goal_frame_caps": caps,
        "env_kwargs": env_kw,
        "torch_threads": torch_threads,
        "physics_threads": threads,
        "command": command if command is not None else " ".join(sys.argv),
    }
    if init is not None:
        first = read_record(Path(init))
        record.update(init=str(init), init_timesteps=int(first.get("timesteps", 0)))
    clock = Clock(before["wall_s"], before["cpu_s"])
    steps: list[BaseCallback] = [
        Checkpoint(out / "checkpoints", max(1, checkpoint_every), record, clock),
        *callbacks,
    ]
    if hp.curriculum is not None:  # near goals first (policies/curriculum.py)
        source = ckpt if ckpt is not None else (Path(init) if init is not None else None)
        level = int(read_record(source).get("curriculum_level", 0)) if source is not None else 0
        task = task_goal_distance(venv)
        # before learn()'s first reset, so that the first episodes draw this level's goals
        venv.env_method("set_goal_distance", *hp.curriculum.distance(level, task), indices=[0])
        steps.append(CurriculumCallback(hp.curriculum, task, record, level))
    if progress:
        steps.append(ProgressBar())
    remaining = total - model.num_timesteps
    if remaining > 0:
        model.learn(
            remaining,
            callback=CallbackList(steps),
            reset_num_timesteps=ckpt is None,
            tb_log_name=algo.upper(),
        )
    times = clock.times()
    record = {**record, "timesteps": int(model.num_timesteps), **times}
    path = save_policy(model, vecnorm, out / "model.zip", record)
    venv.close()
    policy = LoadedPolicy(model, vecnorm, path, record, goal_frame, caps)
    return TrainResult(
        path, int(model.num_timesteps), times["wall_s"], times["cpu_s"], record, policy
    )
