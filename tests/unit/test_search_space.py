"""Search spaces read backwards: a recipe as the parameters that draw it (for enqueuing)."""

from __future__ import annotations

import copy

import optuna
import pytest

from policies.tuning.objective import base_entry
from policies.tuning.search_space import SAMPLERS, params_of, same_value

ENV = "IcosahedronSR-v0"


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_sampled_entries_give_back_their_parameters(algo: str) -> None:
    base = base_entry(algo, ENV, None)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=3))
    for _ in range(20):
        trial = study.ask()
        entry = SAMPLERS[algo](trial, base)
        params, notes = params_of(algo, entry, base)
        assert notes == []
        assert params.keys() == trial.params.keys()
        # PPO's batch_size is clipped to the rollout: several powers draw the same entry
        assert same_value({**params, "batch_size_pow": 0}, {**trial.params, "batch_size_pow": 0})
        assert 2 ** params["batch_size_pow"] == entry["batch_size"]
        # the parameters draw the same entry again
        assert same_value(SAMPLERS[algo](optuna.trial.FixedTrial(params), base), entry)


def test_shipped_ppo_recipe_is_drawable_with_ent_coef_at_its_bound() -> None:
    base = base_entry("ppo", ENV, None)
    params, notes = params_of("ppo", base, base)
    assert params["n_steps_pow"] == 7  # 128
    assert params["batch_size_pow"] == 9  # 512
    assert params["one_minus_gamma"] == pytest.approx(0.01)
    assert params["one_minus_gae_lambda"] == pytest.approx(0.05)
    assert (params["net_arch"], params["activation_fn"], params["n_epochs"]) == (
        "small",
        "tanh",
        10,
    )
    # ent_coef 0 lies below the log range [1e-8, 0.1]: moved to its bound, and said so
    assert params["ent_coef"] == 1e-8
    assert len(notes) == 1 and notes[0].startswith("ent_coef 0 is outside the search range")
    drawn = SAMPLERS["ppo"](optuna.trial.FixedTrial(params), base)
    assert drawn["ent_coef"] == 1e-8
    assert same_value({**drawn, "ent_coef": 0.0}, base)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"n_steps": 100}, "n_steps 100 is not a power of two"),
        ({"n_steps": 2048}, "n_steps_pow 11 is outside the search range [4, 9]"),
        ({"n_epochs": 3}, "n_epochs 3 is none of the search's [1, 5, 10, 20]"),
        ({"n_envs": 16}, "differ from the base hyperparameters): n_envs"),
        ({"policy_kwargs": {"net_arch": {"pi": [32], "vf": [32]}}}, "net_arch [32] is none of"),
    ],
)
def test_settings_the_search_cannot_draw_are_named(change: dict, message: str) -> None:
    base = base_entry("ppo", ENV, None)
    entry = copy.deepcopy(base)
    if "policy_kwargs" in change:
        entry["policy_kwargs"].update(change["policy_kwargs"])
    else:
        entry.update(change)
    with pytest.raises(ValueError) as e:
        params_of("ppo", entry, base)
    assert message in str(e.value)
