"""Sim-to-sim transfer: a policy in the identified env and in the MuJoCo twin.

:func:`transfer` evaluates one policy over the same seeded episodes (see
:mod:`policies.evaluate`) in a source env (the one it was trained in,
``IcosahedronSR-v0``) and a target env (``IcosahedronMJ-v0``, the ground truth) and
reports mean return, success rate and time to goal in each and the transfer ratio
``target return / source return``. :func:`reference_table` sets it beside a policy of
the same algorithm trained directly on the target with the same step budget.
:func:`side_by_side_video` renders one episode in both envs under the policy.

A generic robot's policy (``TensegritySR-v0`` on an identified ``model``) transfers to
``TensegrityMJ-v0`` on the robot file: :func:`env_kwargs_of` reads the source env's
arguments from the policy's run record and :func:`twin_kwargs` gives the twin's (the
same robot, task and options, without the identified model).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from policies.evaluate import EvalResult, Policy, episode_starts, evaluate

if TYPE_CHECKING:
    from policies.train import TrainResult

SOURCE_ENV = "IcosahedronSR-v0"
TARGET_ENV = "IcosahedronMJ-v0"
#: each identified env and its MuJoCo twin
TWINS = {"IcosahedronSR-v0": "IcosahedronMJ-v0", "TensegritySR-v0": "TensegrityMJ-v0"}
#: arguments of an identified env that its twin does not take
SOURCE_ONLY = ("model",)
#: env arguments that shape training only: evaluation keeps the task's own starts
TRAINING_ONLY = ("tipped_starts",)


def env_kwargs_of(record: dict[str, Any]) -> dict[str, Any]:
    """The environment arguments a policy is evaluated with: those it was trained with
    (its run record's) but the training-only ones (:data:`TRAINING_ONLY`), or {}."""
    kw = record.get("env_kwargs") or {}
    return {k: v for k, v in kw.items() if k not in TRAINING_ONLY}


def twin_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
    """The twin's arguments for an identified env's ``kwargs``: all but ``model``."""
    return {k: v for k, v in kwargs.items() if k not in SOURCE_ONLY}


@dataclass(frozen=True)
class TransferResult:
    """One policy in the source and the target env over the same episodes."""

    source: EvalResult
    target: EvalResult

    @property
    def ratio(self) -> float:
        """Transfer ratio: mean target return / mean source return."""
        return self.target.mean_return / self.source.mean_return

    def to_dict(self) -> dict[str, Any]:
        def one(r: EvalResult) -> dict[str, Any]:
            return {
                "env_id": r.env_id,
                "mean_return": r.mean_return,
                "std_return": r.std_return,
                "success_rate": r.success_rate,
                "time_to_goal_s": r.time_to_goal,
                "returns": r.returns.tolist(),
                "steps": r.steps.tolist(),
            }

        return {"source": one(self.source), "target": one(self.target), "ratio": self.ratio}


def transfer(
    policy: Policy,
    episodes: int = 20,
    seed: int = 1000,
    source: str = SOURCE_ENV,
    target: str = TARGET_ENV,
    env_kwargs: dict[str, Any] | None = None,
) -> TransferResult:
    """``policy`` over ``episodes`` seeded starts (drawn by ``source``) in both envs.

    ``env_kwargs``: the source env's arguments; the target gets :func:`twin_kwargs` of them.
    """
    kw = dict(env_kwargs or {})
    starts = episode_starts(source, episodes, seed, kw)
    return TransferResult(
        evaluate(policy, source, starts, kw), evaluate(policy, target, starts, twin_kwargs(kw))
    )


def _fmt(x: float, spec: str) -> str:
    return "-" if not np.isfinite(x) else format(x, spec)


def row(label: str, r: EvalResult) -> str:
    """One markdown table row: return (mean ± std), success, time to goal."""
    return (
        f"| {label} | {r.env_id} | {r.mean_return:.2f} ± {r.std_return:.2f} | "
        f"{100 * r.success_rate:.0f}% | {_fmt(r.time_to_goal, '.2f')} |"
    )


HEADER = (
    "| policy | evaluated in | mean return ± std | success | time to goal [s] |\n"
    "| --- | --- | --- | --- | --- |"
)


def transfer_table(result: TransferResult, label: str = "policy") -> str:
    """Markdown: the policy in both envs, then the transfer ratio."""
    n = len(result.source.returns)
    return "\n".join(
        [
            HEADER,
            row(label, result.source),
            row(label, result.target),
            "",
            f"transfer ratio (return in {result.target.env_id} / return in "
            f"{result.source.env_id}): **{result.ratio:.3f}** over {n} episodes",
        ]
    )


def reference_table(
    result: TransferResult,
    reference: EvalResult,
    label: str,
    reference_label: str,
    wall_s: float | None,
    reference_wall_s: float | None,
    timesteps: int | None,
    reference_timesteps: int | None,
) -> str:
    """Markdown: the transferred policy against one trained on the target directly."""

    def w(x: float | None) -> str:
        return "-" if x is None else f"{x:.0f}"

    def t(x: int | None) -> str:
        return "-" if x is None else f"{x:,}"

    lines = [
        "| policy | trained in | env steps | training wall time [s] | return in "
        f"{reference.env_id} | success | time to goal [s] |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        f"| {label} | {result.source.env_id} | {t(timesteps)} | {w(wall_s)} | "
        f"{result.target.mean_return:.2f} | {100 * result.target.success_rate:.0f}% | "
        f"{_fmt(result.target.time_to_goal, '.2f')} |",
        f"| {reference_label} | {reference.env_id} | {t(reference_timesteps)} | "
        f"{w(reference_wall_s)} | {reference.mean_return:.2f} | "
        f"{100 * reference.success_rate:.0f}% | {_fmt(reference.time_to_goal, '.2f')} |",
        "",
        f"return of the transferred policy / the reference's, both in {reference.env_id}: "
        f"**{result.target.mean_return / reference.mean_return:.3f}**",
    ]
    if wall_s is not None and reference_wall_s is not None:
        lines.append(
            f"training wall time, transferred / reference: **{wall_s / reference_wall_s:.3f}**"
        )
    return "\n".join(lines)


def side_by_side_video(
    policy: Policy,
    path: str | Path,
    seed: int = 1000,
    max_steps: int = 300,
    source: str = SOURCE_ENV,
    target: str = TARGET_ENV,
    width: int = 400,
    height: int = 300,
    env_kwargs: dict[str, Any] | None = None,
) -> Path:
    """One episode (seed ``seed``) in ``source`` (left) and ``target`` (right), to MP4/GIF.

    Both start from the source's seeded state and goal; the policy sees each env's own
    observation; each half is labelled with what it shows (identified model or MuJoCo).
    Written atomically (:func:`~tensegrity_env.envs.rendering.write_video`).
    ``env_kwargs``: the source env's arguments (the target gets :func:`twin_kwargs`).
    """
    from tensegrity_env.envs.rendering import env_label, side_by_side, write_video

    kw: dict[str, Any] = {"render_mode": "rgb_array", "width": width, "height": height}
    src_kw = dict(env_kwargs or {})
    left = gym.make(source, **kw, **src_kw)
    right = gym.make(target, **kw, **twin_kwargs(src_kw))
    try:
        obs_l, _ = left.reset(seed=seed)
        opts = left.unwrapped.start_options()  # type: ignore[attr-defined]  # goal-task envs (rolling or robot)
        obs_r, _ = right.reset(seed=seed, options=opts)
        names = env_label(left), env_label(right)
        frames = [side_by_side(left.render(), right.render(), *names)]  # type: ignore[arg-type]  # rgb_array: an image
        done_l = done_r = False
        for _ in range(max_steps):
            if not done_l:
                obs_l, _, t, u, _ = left.step(policy(obs_l))
                done_l = t or u
            if not done_r:
                obs_r, _, t, u, _ = right.step(policy(obs_r))
                done_r = t or u
            frames.append(side_by_side(left.render(), right.render(), *names))  # type: ignore[arg-type]  # rgb_array: an image
            if done_l and done_r:
                break
        return write_video(frames, path, fps=left.metadata.get("render_fps", 20))
    finally:
        left.close()
        right.close()


def train_reference(
    record: dict[str, Any],
    target: str,
    out: str | Path,
    threads: int | None = 1,
    command: str | None = None,
) -> TrainResult:
    """Train the reference: the run ``record`` describes, repeated on ``target``.

    Same algorithm, settings (the recorded hyperparameters, written to
    ``out/hyperparams.yml`` under ``target``), seed and env-step budget as the run
    that produced the policy; resumes an interrupted reference run in ``out``.
    """
    import yaml

    from policies.train import latest_checkpoint, train
    from tensegrity_env.io_utils import InputError, atomic_write_text

    missing = [k for k in ("algo", "timesteps", "seed", "hyperparams") if k not in record]
    if missing:
        raise InputError(f"the policy has no run record with {', '.join(missing)}: train it first")
    out = Path(out)
    settings_doc = {k: v for k, v in record["hyperparams"].items() if k != "env_kwargs"}
    settings = atomic_write_text(
        out / "hyperparams.yml", yaml.safe_dump({target: settings_doc}, sort_keys=False)
    )
    return train(
        record["algo"],
        target,
        out,
        timesteps=int(record["timesteps"]),
        seed=int(record["seed"]),
        n_envs=record.get("n_envs"),
        hyperparams=settings,
        resume=latest_checkpoint(out) is not None,
        threads=threads,
        command=command,
        env_kwargs=twin_kwargs(dict(record.get("env_kwargs") or {})),  # training's own
    )
