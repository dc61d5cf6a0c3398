"""One trial of a search: train with sampled settings, evaluate, report, maybe prune.

Following rl-zoo3, a trial trains for a fixed budget and evaluates the policy
deterministically ``n_evaluations`` times along the way (:class:`TrialEval`, an SB3
callback); each evaluation's mean return is reported to Optuna at step ``k``
(the k-th evaluation) and the pruner may stop the trial there. The trial's value is
the last evaluation's mean return. Unlike rl-zoo3, every trial is an ordinary
training run (:func:`policies.train.train`) with its own folder::

    OUT/trials/trial_<number>/hyperparams.yml    the sampled settings (hyperparams format)
    OUT/trials/trial_<number>/model.zip, ...     as ``tensegrity-sr train`` writes them
    OUT/trials/trial_<number>/tb/                TensorBoard (training and eval/ curves)

Evaluation episodes are the seeded starts of :func:`policies.evaluate.episode_starts`
(the same for every trial), run in the study's environment.
"""

from __future__ import annotations

import copy
import json
import os
import socket
from dataclasses import dataclass
from pathlib import Path

import optuna
import yaml
from stable_baselines3.common.callbacks import BaseCallback

from policies.artifacts import LoadedPolicy
from policies.evaluate import EpisodeStart, episode_starts, evaluate
from policies.tuning.search_space import SAMPLERS, Entry
from tensegrity_env.io_utils import atomic_write_text


@dataclass(frozen=True)
class TrialSettings:
    """What every trial of a study shares.

    Attributes:
        algo: ``"ppo"`` or ``"sac"``.
        env_id: the environment searched on.
        base: the base hyperparameter entry the sampler draws over.
        out: the study's output folder (trials go to ``out/trials``).
        timesteps: training budget per trial [env steps].
        n_evaluations: evaluations per trial (pruning points).
        eval_episodes: episodes per evaluation.
        eval_seed: episode ``k`` of every evaluation starts from ``reset(seed=eval_seed + k)``.
        seed: trial ``n`` trains with seed ``seed + n``.
        tensorboard: write TensorBoard logs per trial.
    """

    algo: str
    env_id: str
    base: Entry
    out: Path
    timesteps: int
    n_evaluations: int = 4
    eval_episodes: int = 10
    eval_seed: int = 10_000
    seed: int = 0
    tensorboard: bool = True


class TrialEval(BaseCallback):
    """Evaluates every ``every`` env steps, reports to the trial, stops it if pruned.

    Logs ``eval/mean_return`` and ``eval/success_rate`` to the run's TensorBoard.
    """

    def __init__(
        self, trial: optuna.Trial, env_id: str, starts: list[EpisodeStart], every: int,
        goal_frame: bool,
    ) -> None:  # fmt: skip
        super().__init__()
        self.trial, self.env_id, self.starts = trial, env_id, starts
        self.every, self.goal_frame = max(1, int(every)), goal_frame
        self.n_done = 0
        self.pruned = False
        self.last: tuple[float, float] | None = None  # (mean return, success rate)

    def _on_step(self) -> bool:
        if self.num_timesteps < (self.n_done + 1) * self.every:
            return True
        self.n_done += 1
        vecnorm = self.model.get_vec_normalize_env()
        # a shallow copy shares the running statistics but freezes them for evaluation
        frozen = copy.copy(vecnorm) if vecnorm is not None else None
        policy = LoadedPolicy(self.model, frozen, Path("."), {}, self.goal_frame)
        result = evaluate(policy, self.env_id, self.starts)
        self.last = (result.mean_return, result.success_rate)
        self.logger.record("eval/mean_return", result.mean_return)
        self.logger.record("eval/success_rate", result.success_rate)
        self.trial.report(result.mean_return, self.n_done)
        if self.trial.should_prune():
            self.pruned = True
            return False
        return True


def trial_folder(out: Path, number: int) -> Path:
    """The run folder of trial ``number``."""
    return out / "trials" / f"trial_{number:04d}"


def write_hyperparams(path: Path, env_id: str, entry: Entry, header: str = "") -> None:
    """Write ``{env_id: entry}`` as a hyperparameter YAML file (atomically)."""
    body = yaml.safe_dump({env_id: entry}, sort_keys=False)
    comment = "".join(f"# {line}\n" for line in header.splitlines())
    atomic_write_text(path, comment + body)


class Objective:
    """The callable Optuna optimizes: one trial in, the last mean return out."""

    def __init__(self, settings: TrialSettings) -> None:
        self.s = settings
        self.starts = episode_starts(settings.env_id, settings.eval_episodes, settings.eval_seed)

    def __call__(self, trial: optuna.Trial) -> float:
        from policies.train import train  # SB3 and the env import late, in the worker

        s = self.s
        entry = SAMPLERS[s.algo](trial, s.base)
        folder = trial_folder(s.out, trial.number)
        folder.mkdir(parents=True, exist_ok=True)
        write_hyperparams(folder / "hyperparams.yml", s.env_id, entry)
        trial.set_user_attr("hyperparams", json.loads(json.dumps(entry)))
        trial.set_user_attr("run_folder", str(folder.resolve()))
        trial.set_user_attr("host", socket.gethostname())
        trial.set_user_attr("pid", os.getpid())
        goal_frame = bool(entry.get("goal_frame", False))
        cb = TrialEval(trial, s.env_id, self.starts, s.timesteps // s.n_evaluations, goal_frame)
        try:
            result = train(
                s.algo, s.env_id, folder, timesteps=s.timesteps, seed=s.seed + trial.number,
                hyperparams=folder / "hyperparams.yml", checkpoint_every=s.timesteps,
                progress=False, tensorboard=s.tensorboard, callbacks=[cb],
                command=f"tune trial {trial.number} of study {trial.study.study_name}",
            )  # fmt: skip
        except (AssertionError, ValueError) as e:
            # sampled settings that make NaNs (as in rl-zoo3): pruned, not failed
            trial.set_user_attr("error", f"{type(e).__name__}: {e}")
            raise optuna.TrialPruned() from None
        trial.set_user_attr("wall_s", result.wall_s)
        trial.set_user_attr("timesteps", result.timesteps)
        if cb.last is not None:
            trial.set_user_attr("success_rate", cb.last[1])
        if cb.pruned:
            raise optuna.TrialPruned()
        if cb.last is None:
            raise RuntimeError(f"trial {trial.number}: trained without an evaluation")
        return cb.last[0]


def base_entry(algo: str, env_id: str, path: str | Path | None) -> Entry:
    """The entry of ``env_id`` in a hyperparameter file (default: the shipped one) as data."""
    from policies.hyperparams import load_hyperparams

    hp = load_hyperparams(algo, env_id, path)
    return json.loads(json.dumps(hp.to_dict()))
