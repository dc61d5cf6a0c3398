"""rl-zoo3's PPO and SAC search spaces, as hyperparameter-file entries.

A sampler draws one trial's settings and returns them as an entry of a
``policies/hyperparams/<algo>.yml`` file (plain data: ``activation_fn`` by name),
laid over the base entry of the environment, so the best trial can be written back
as a YAML file that ``tensegrity-sr train --hyperparams`` reads.

The parameters, their names and ranges follow rl-zoo3's ``hyperparams_opt.py``
(``one_minus_gamma``, ``*_pow`` powers of two, ``net_arch`` by size name) with two
changes where its ranges do not fit a natively batched env of ``n_envs``
environments: PPO's rollout length per env ``n_steps`` spans 2**4..2**9 (rl-zoo3:
2**5..2**12 for a handful of envs; here a rollout is ``n_envs * n_steps`` steps) and
the minibatch ``batch_size`` 2**6..2**12, clipped to the rollout size. SAC keeps
rl-zoo3's space (``gradient_steps = train_freq``). Keys the spaces do not draw
(``n_envs``, ``normalize``, ``goal_frame``, ``log_std_init``, ...) keep the base
entry's values.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import optuna

Entry = dict[str, Any]

#: network sizes by name (rl-zoo3's)
PPO_NETS: dict[str, list[int]] = {"tiny": [64], "small": [64, 64], "medium": [256, 256]}
SAC_NETS: dict[str, list[int]] = {"small": [64, 64], "medium": [256, 256], "big": [400, 300]}


def sample_ppo(trial: optuna.Trial, base: Entry) -> Entry:
    """One PPO trial's settings over ``base`` (an entry of ``ppo.yml``)."""
    n_envs = int(base.get("n_envs", 1))
    n_steps = 2 ** trial.suggest_int("n_steps_pow", 4, 9)
    batch_size = min(2 ** trial.suggest_int("batch_size_pow", 6, 12), n_envs * n_steps)
    gamma = 1.0 - trial.suggest_float("one_minus_gamma", 0.0001, 0.03, log=True)
    gae_lambda = 1.0 - trial.suggest_float("one_minus_gae_lambda", 0.0001, 0.1, log=True)
    net = PPO_NETS[trial.suggest_categorical("net_arch", list(PPO_NETS))]
    entry = copy.deepcopy(base)
    entry.update(
        n_steps=n_steps,
        batch_size=batch_size,
        gamma=gamma,
        gae_lambda=gae_lambda,
        learning_rate=trial.suggest_float("learning_rate", 1e-5, 0.002, log=True),
        ent_coef=trial.suggest_float("ent_coef", 1e-8, 0.1, log=True),
        clip_range=trial.suggest_categorical("clip_range", [0.1, 0.2, 0.3, 0.4]),
        n_epochs=trial.suggest_categorical("n_epochs", [1, 5, 10, 20]),
        max_grad_norm=trial.suggest_float("max_grad_norm", 0.3, 2.0),
    )
    pk = dict(entry.get("policy_kwargs") or {})
    pk["net_arch"] = {"pi": list(net), "vf": list(net)}
    pk["activation_fn"] = trial.suggest_categorical("activation_fn", ["tanh", "relu"])
    entry["policy_kwargs"] = pk
    return entry


def sample_sac(trial: optuna.Trial, base: Entry) -> Entry:
    """One SAC trial's settings over ``base`` (an entry of ``sac.yml``)."""
    train_freq = trial.suggest_int("train_freq", 1, 10)
    net = SAC_NETS[trial.suggest_categorical("net_arch", list(SAC_NETS))]
    entry = copy.deepcopy(base)
    entry.update(
        gamma=1.0 - trial.suggest_float("one_minus_gamma", 0.0001, 0.03, log=True),
        batch_size=2 ** trial.suggest_int("batch_size_pow", 5, 11),
        learning_rate=trial.suggest_float("learning_rate", 1e-5, 0.002, log=True),
        train_freq=train_freq,
        gradient_steps=train_freq,
        tau=trial.suggest_float("tau", 0.001, 0.08, log=True),
    )
    pk = dict(entry.get("policy_kwargs") or {})
    pk["net_arch"] = list(net)
    entry["policy_kwargs"] = pk
    return entry


#: samplers by algorithm name
SAMPLERS: dict[str, Callable[[optuna.Trial, Entry], Entry]] = {
    "ppo": sample_ppo,
    "sac": sample_sac,
}
