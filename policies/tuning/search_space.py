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
import math
from collections.abc import Callable
from typing import Any

import optuna

Entry = dict[str, Any]

#: network sizes by name (rl-zoo3's)
PPO_NETS: dict[str, list[int]] = {"tiny": [64], "small": [64, 64], "medium": [256, 256]}
SAC_NETS: dict[str, list[int]] = {"small": [64, 64], "medium": [256, 256], "big": [400, 300]}


def sample_ppo(trial: optuna.trial.BaseTrial, base: Entry) -> Entry:
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


def sample_sac(trial: optuna.trial.BaseTrial, base: Entry) -> Entry:
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
SAMPLERS: dict[str, Callable[[optuna.trial.BaseTrial, Entry], Entry]] = {
    "ppo": sample_ppo,
    "sac": sample_sac,
}


def search_distributions(
    algo: str, base: Entry
) -> dict[str, optuna.distributions.BaseDistribution]:
    """The parameters ``algo``'s sampler draws over ``base``, with their distributions."""
    verbosity = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)  # no "new study created" line
    try:
        study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    finally:
        optuna.logging.set_verbosity(verbosity)
    trial = study.ask()
    SAMPLERS[algo](trial, base)
    return dict(trial.distributions)


def power_of_two(name: str, value: Any) -> int:
    """``log2(value)`` of a positive integer power of two; :class:`ValueError` otherwise."""
    if not isinstance(value, int) or value < 1 or value & (value - 1):
        raise ValueError(f"{name} {value!r} is not a power of two")
    return value.bit_length() - 1


def net_name(nets: dict[str, list[int]], arch: Any) -> str:
    """The size name of a network ``arch`` (``[64, 64]`` or ``{"pi": [..], "vf": [..]}``)."""
    if isinstance(arch, dict):
        pi, vf = arch.get("pi"), arch.get("vf")
        if pi != vf:
            raise ValueError(f"net_arch {arch!r}: pi and vf differ (the search draws one size)")
        arch = pi
    for name, layers in nets.items():
        if list(arch or []) == layers:
            return name
    raise ValueError(f"net_arch {arch!r} is none of {nets}")


def raw_params_ppo(entry: Entry) -> dict[str, Any]:
    """The search parameters a PPO entry was drawn with (before any range check)."""
    pk = entry.get("policy_kwargs") or {}
    return {
        "n_steps_pow": power_of_two("n_steps", entry.get("n_steps")),
        "batch_size_pow": power_of_two("batch_size", entry.get("batch_size")),
        "one_minus_gamma": 1.0 - float(entry["gamma"]),
        "one_minus_gae_lambda": 1.0 - float(entry["gae_lambda"]),
        "net_arch": net_name(PPO_NETS, pk.get("net_arch")),
        "learning_rate": float(entry["learning_rate"]),
        "ent_coef": float(entry["ent_coef"]),
        "clip_range": entry["clip_range"],
        "n_epochs": entry["n_epochs"],
        "max_grad_norm": float(entry["max_grad_norm"]),
        "activation_fn": pk.get("activation_fn"),
    }


def raw_params_sac(entry: Entry) -> dict[str, Any]:
    """The search parameters a SAC entry was drawn with (before any range check)."""
    pk = entry.get("policy_kwargs") or {}
    return {
        "train_freq": entry["train_freq"],
        "net_arch": net_name(SAC_NETS, pk.get("net_arch")),
        "one_minus_gamma": 1.0 - float(entry["gamma"]),
        "batch_size_pow": power_of_two("batch_size", entry.get("batch_size")),
        "learning_rate": float(entry["learning_rate"]),
        "tau": float(entry["tau"]),
    }


#: inverse samplers by algorithm name
RAW_PARAMS: dict[str, Callable[[Entry], dict[str, Any]]] = {
    "ppo": raw_params_ppo,
    "sac": raw_params_sac,
}


def same_value(a: Any, b: Any) -> bool:
    """Equal data, floats to 1e-9 relative."""
    if isinstance(a, float) or isinstance(b, float):
        return (
            isinstance(a, int | float)
            and isinstance(b, int | float)
            and math.isclose(a, b, rel_tol=1e-9)
        )
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_value(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


def params_of(algo: str, entry: Entry, base: Entry) -> tuple[dict[str, Any], list[str]]:
    """The search parameters that make ``algo``'s sampler return ``entry`` over ``base``.

    For enqueuing a known recipe as a trial of a study (``optuna.Study.enqueue_trial``).
    A float outside its search range is moved to the nearest bound (e.g. ``ent_coef``
    0.0 to the log range's 1e-8) and said so in the returned notes (one line each);
    anything else the search cannot draw (a ``n_steps`` that is no power of two, a
    network size it does not know, a key it does not draw that differs from ``base``)
    raises :class:`ValueError` naming it.

    Returns:
        (params, notes): parameter name -> value, and the notes on moved values.
    """
    params = RAW_PARAMS[algo](entry)
    notes: list[str] = []
    moved_keys: set[str] = set()  # entry keys of the moved parameters
    for name, dist in search_distributions(algo, base).items():
        value = params[name]
        if isinstance(dist, optuna.distributions.FloatDistribution):
            moved = min(max(value, dist.low), dist.high)
            if not math.isclose(moved, value, rel_tol=1e-9):  # not a rounding error
                notes.append(
                    f"{name} {value:g} is outside the search range "
                    f"[{dist.low:g}, {dist.high:g}]: enqueued as {moved:g}"
                )
                moved_keys.add(name.removeprefix("one_minus_"))
            params[name] = moved
        elif isinstance(dist, optuna.distributions.IntDistribution):
            if not dist.low <= value <= dist.high:
                raise ValueError(
                    f"{name} {value} is outside the search range [{dist.low}, {dist.high}]"
                )
        elif isinstance(dist, optuna.distributions.CategoricalDistribution):
            if value not in dist.choices:
                raise ValueError(f"{name} {value!r} is none of the search's {list(dist.choices)}")
    drawn = SAMPLERS[algo](optuna.trial.FixedTrial(params), base)
    differ = sorted(
        k for k in set(entry) | set(drawn)
        if k not in moved_keys and not same_value(entry.get(k), drawn.get(k))
    )  # fmt: skip
    if differ:
        raise ValueError(
            "the search cannot draw these settings (or they differ from the base "
            f"hyperparameters): {', '.join(differ)}"
        )
    return params, notes
