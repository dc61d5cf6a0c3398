"""The generated policy results page: which trial won a search, and where it came from."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from policies.results import markdown, read_seeds


def trial(
    number: int, value: float | None, state: str = "COMPLETE", enqueued: str | None = None
) -> dict:
    return {"number": number, "state": state, "value": value, "success_rate": 0.5,
            "params": {"n_steps_pow": 7}, "wall_s": 10.0, "timesteps": 1000,
            "run_folder": f"t/{number}", "host": "h", "error": None, "enqueued": enqueued}  # fmt: skip


def test_search_section_names_the_winner_and_ranks_trials() -> None:
    trials = [trial(0, 40.0, enqueued="ppo.yml"), trial(1, 45.5), trial(2, 3.0, "PRUNED"),
              trial(3, None, "FAIL")]  # fmt: skip
    doc = {"study": {
        "study_name": "s", "counts": {"COMPLETE": 2, "PRUNED": 1, "FAIL": 1},
        "settings": {"env_id": "E", "timesteps": 1_000_000, "n_evaluations": 4,
                     "eval_episodes": 20, "eval_seed": 10000, "sampler": "TPE",
                     "pruner": "MedianPruner", "command": "tune ...",
                     "enqueued": [{"file": "ppo.yml", "params": {}, "notes": ["ent_coef moved"]}]},
        "best": trials[1], "trials": trials}}  # fmt: skip
    text = markdown(doc)
    assert "1,000,000 env steps per trial" in text
    assert "enqueued: `ppo.yml` (ent_coef moved)" in text
    assert "best: trial 1 (sampled), mean return 45.50" in text
    rows = [line for line in text.splitlines() if line[:3] in ("| 0", "| 1", "| 2", "| 3")]
    # complete trials best first, then pruned; failed trials are not ranked
    assert [r.split(" | ")[0] for r in rows] == ["| 1", "| 0", "| 2"]
    assert "enqueued `ppo.yml`" in rows[1] and "50%" in rows[1]


def test_seeds_section_names_the_recipe_of_its_runs() -> None:
    def run(seed: int) -> dict:
        env = {"mean_return": 50.0 + seed, "success_rate": 0.9}
        return {"seed": seed, "ratio": 1.0,
                "source": {**env, "env_id": "SR"}, "target": {**env, "env_id": "MJ"},
                "record": {"seed": seed, "timesteps": 3_002_368, "command": "train ...",
                           "hyperparams_file": "/somewhere/repo/policies/hyperparams/ppo.yml"}}  # fmt: skip

    cell = {"iqm": 0.9, "low": 0.8, "high": 1.0}
    agg = {"n_runs": 2, **{k: cell for k in ("source_return", "target_return", "source_success",
                                             "target_success", "ratio")}}  # fmt: skip
    group = {"episodes": 100, "runs": [run(0), run(1)], "aggregate": agg}
    text = markdown({"seeds": [group, group]})
    assert text.count("## Seeds of `policies/hyperparams/ppo.yml`") == 2
    assert "2 runs trained with `policies/hyperparams/ppo.yml` for 3,002,368 env steps" in text
    assert "| 1 | 51.00 | 90% | 51.00 | 90% | 1.000 |" in text


def test_robot_records_name_files_relative_to_the_working_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a run record names the files of the machine it ran on by absolute paths; the
    # results keep them as the reproduce line names them
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "runs" / "s0"
    run.mkdir(parents=True)
    record = {"algo": "ppo", "seed": 0, "env_kwargs": {"task": "goal",
              "model": str(tmp_path / "runs" / "params.json")},
              "hyperparams_file": "/somewhere/else/policies/hyperparams/ppo.yml"}  # fmt: skip
    (run / "model.json").write_text(json.dumps(record))
    transfer = tmp_path / "transfer.json"
    transfer.write_text(json.dumps({"runs": [{"policy": str(run / "model.zip"), "seed": 0}]}))
    doc = read_seeds(transfer)
    got = doc["runs"][0]
    assert got["policy"] == "runs/s0/model.zip"
    assert got["record"]["env_kwargs"] == {"task": "goal", "model": "runs/params.json"}
    assert got["record"]["hyperparams_file"] == "policies/hyperparams/ppo.yml"
