"""Hyperparameters from YAML files keyed by environment id (the rl-zoo3 convention).

``policies/hyperparams/<algo>.yml`` maps an environment id to one algorithm's
settings. This module reads these keys itself and passes every other one to the SB3
constructor unchanged:

==================  =========================================================
``n_envs``          environments stepped together (one batched env)
``n_timesteps``     default training budget [env steps, summed over the envs]
``policy``          SB3 policy name (``MlpPolicy``)
``normalize``       VecNormalize arguments (``norm_obs``, ``norm_reward``, ...)
                    in training, or ``false`` for none
``policy_kwargs``   a mapping; ``activation_fn`` is a name (``tanh``, ``relu``)
``goal_frame``      the policy sees the scene turned so that the goal is on +x
                    (:mod:`policies.goal_frame`; default false)
``env_kwargs``      a mapping of the environment's own arguments (``task``,
                    task options such as ``goal_distance``)
``curriculum``      near goals first, widened to the task's ``goal_distance`` as
                    the training episodes succeed (:mod:`policies.curriculum`;
                    default none)
==================  =========================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch.nn as nn
import yaml

from policies.curriculum import GoalCurriculum
from tensegrity_env.io_utils import InputError, parse_error

#: the YAML files that ship with the package, one per algorithm
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"
ACTIVATIONS: dict[str, type[nn.Module]] = {
    "tanh": nn.Tanh,
    "relu": nn.ReLU,
    "elu": nn.ELU,
    "leaky_relu": nn.LeakyReLU,
}


@dataclass(frozen=True)
class Hyperparams:
    """One algorithm's settings for one environment.

    Attributes:
        algo: ``"ppo"`` or ``"sac"``.
        env_id: the Gymnasium id the settings are for.
        n_envs: environments stepped together.
        n_timesteps: default budget [env steps].
        policy: SB3 policy name.
        normalize: VecNormalize keyword arguments for training, None for no normalization.
        algo_kwargs: every other key, for the SB3 constructor (policy_kwargs as in the file).
        source: the file they came from.
        goal_frame: the policy acts in the goal frame (:mod:`policies.goal_frame`).
        env_kwargs: the environment's own arguments (passed to ``gym.make``).
        curriculum: the goal-distance curriculum of training, None for none.
    """

    algo: str
    env_id: str
    n_envs: int
    n_timesteps: int
    policy: str
    normalize: dict[str, Any] | None
    algo_kwargs: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    goal_frame: bool = False
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    curriculum: GoalCurriculum | None = None

    def sb3_kwargs(self) -> dict[str, Any]:
        """Constructor kwargs with ``policy_kwargs.activation_fn`` turned into a class."""
        kwargs = dict(self.algo_kwargs)
        pk = dict(kwargs.get("policy_kwargs") or {})
        if "activation_fn" in pk:
            pk["activation_fn"] = ACTIVATIONS[pk["activation_fn"]]
        if pk:
            kwargs["policy_kwargs"] = pk
        return kwargs

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the run record (JSON)."""
        return {
            "n_envs": self.n_envs,
            "n_timesteps": self.n_timesteps,
            "policy": self.policy,
            "normalize": self.normalize,
            "goal_frame": self.goal_frame,
            **({"env_kwargs": self.env_kwargs} if self.env_kwargs else {}),
            **({"curriculum": self.curriculum.to_dict()} if self.curriculum else {}),
            **self.algo_kwargs,
        }


def hyperparams_path(algo: str) -> Path:
    """The shipped YAML file of ``algo``."""
    return HYPERPARAMS_DIR / f"{algo}.yml"


def load_hyperparams(algo: str, env_id: str, path: str | Path | None = None) -> Hyperparams:
    """Read ``env_id``'s entry from ``path`` (default: the shipped ``<algo>.yml``).

    Raises :class:`InputError` (one line naming the file) if the file is missing, is not
    YAML, has no entry for ``env_id`` or an entry with a bad value.
    """
    path = Path(path) if path is not None else hyperparams_path(algo)
    try:
        doc = yaml.safe_load(path.read_text())
    except OSError as e:
        raise InputError(f"{path}: cannot read hyperparameters ({e.strerror})") from None
    except yaml.YAMLError as e:
        raise InputError(f"{path}: not valid YAML ({parse_error(e)})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a mapping of environment ids to settings")
    if env_id not in doc:
        known = ", ".join(sorted(map(str, doc))) or "none"
        raise InputError(f"{path}: no entry for {env_id!r} (has: {known})")
    entry = dict(doc[env_id] or {})
    try:
        n_envs = int(entry.pop("n_envs", 1))
        n_timesteps = int(entry.pop("n_timesteps", 100_000))
    except (TypeError, ValueError):
        raise InputError(f"{path}: {env_id}: n_envs and n_timesteps must be integers") from None
    if n_envs < 1 or n_timesteps < 1:
        raise InputError(f"{path}: {env_id}: n_envs and n_timesteps must be >= 1")
    policy = str(entry.pop("policy", "MlpPolicy"))
    goal_frame = entry.pop("goal_frame", False)
    if not isinstance(goal_frame, bool):
        raise InputError(f"{path}: {env_id}: goal_frame must be true or false")
    env_kwargs = entry.pop("env_kwargs", None) or {}
    if not isinstance(env_kwargs, dict):
        raise InputError(f"{path}: {env_id}: env_kwargs must be a mapping")
    curriculum = entry.pop("curriculum", None)
    if curriculum is not None:
        curriculum = GoalCurriculum.from_config(curriculum, f"{path}: {env_id}")
    normalize = entry.pop("normalize", None)
    if normalize is True:
        normalize = {}
    if normalize is False:
        normalize = None
    if normalize is not None and not isinstance(normalize, dict):
        raise InputError(f"{path}: {env_id}: normalize must be true, false or a mapping")
    pk = entry.get("policy_kwargs")
    if pk is not None and not isinstance(pk, dict):
        raise InputError(f"{path}: {env_id}: policy_kwargs must be a mapping")
    act = (pk or {}).get("activation_fn")
    if act is not None and act not in ACTIVATIONS:
        raise InputError(
            f"{path}: {env_id}: activation_fn {act!r} is not one of {', '.join(ACTIVATIONS)}"
        )
    return Hyperparams(
        algo, env_id, n_envs, n_timesteps, policy, normalize, entry, str(path), goal_frame,
        env_kwargs, curriculum,
    )  # fmt: skip
