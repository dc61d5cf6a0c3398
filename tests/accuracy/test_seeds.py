"""Several seeds: parallel training, IQM with bootstrap intervals, the shipped policy by name."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from policies.aggregate import aggregate
from policies.artifacts import pretrained_path, read_record
from policies.evaluate import EvalResult
from policies.seeds import parse_seeds
from policies.transfer import TransferResult
from tensegrity_env.io_utils import InputError
from tensegrity_sr.cli import main as cli


def test_seed_lists_parse() -> None:
    assert parse_seeds("0-4") == [0, 1, 2, 3, 4]
    assert parse_seeds("3,1,1-2") == [3, 1, 2]
    for bad in ("4-0", "a", "", "1-"):
        with pytest.raises(InputError, match="--seeds"):
            parse_seeds(bad)


def one_run(src: list[float], tgt: list[float], ok: list[bool]) -> TransferResult:
    n = len(src)
    steps = np.full(n, 10)
    return TransferResult(
        EvalResult("A", np.array(src), np.ones(n, dtype=bool), steps, 0.1),
        EvalResult("B", np.array(tgt), np.array(ok), steps, 0.1),
    )


def test_iqm_trims_the_outer_quarters_and_brackets_it() -> None:
    # eight runs: the IQM is the mean of the middle four whatever the outliers are
    src = [10.0, 20, 30, 40, 50, 60, 70, 1000]
    runs = [one_run([s], [0.9 * s], [s > 25]) for s in src]
    agg = aggregate(runs, reps=500)
    assert agg["source_return"]["iqm"] == pytest.approx(45.0)
    assert agg["target_return"]["iqm"] == pytest.approx(0.9 * 45.0)
    assert agg["ratio"]["iqm"] == pytest.approx(0.9)
    # rliable resamples the two score sets independently: an interval around 0.9
    assert agg["ratio"]["low"] < 0.9 < agg["ratio"]["high"]
    assert aggregate(runs, reps=500) == agg  # seeded: the same intervals again
    assert agg["target_success"]["iqm"] == pytest.approx(1.0)  # middle four all succeed
    for k, a in agg.items():
        assert a["low"] <= a["iqm"] + 1e-12 and a["iqm"] <= a["high"] + 1e-12, k
    assert agg["source_return"]["low"] < 45.0 < agg["source_return"]["high"]


def test_seeds_train_in_parallel_and_transfer_reports_their_iqm(tmp_path: Path) -> None:
    doc = yaml.safe_load(Path("policies/hyperparams/ppo.yml").read_text())
    small = {k: {**v, "n_steps": 32, "batch_size": 128, "n_epochs": 1} for k, v in doc.items()}
    hp = tmp_path / "ppo.yml"
    hp.write_text(yaml.safe_dump(small))
    out = tmp_path / "runs"
    code = cli(["train", "ppo", "--seeds", "0-1", "--workers", "2", "--timesteps", "256",
                "--n-envs", "4", "--hyperparams", str(hp), "-o", str(out), "--no-tensorboard"])  # fmt: skip
    assert code == 0
    a, b = read_record(out / "s0" / "model.zip"), read_record(out / "s1" / "model.zip")
    assert (a["seed"], b["seed"]) == (0, 1) and a["timesteps"] == b["timesteps"] == 256
    # a second start refuses to overwrite
    again = ["train", "ppo", "--seeds", "1", "--hyperparams", str(hp), "-o", str(out)]
    assert cli(again) == 2
    # --resume continues seed 1 to a larger budget and starts seed 2 afresh
    more = ["train", "ppo", "--seeds", "1-2", "--timesteps", "384", "--n-envs", "4", "--hyperparams",
            str(hp), "-o", str(out), "--no-tensorboard", "--resume"]  # fmt: skip
    assert cli(more) == 0
    assert read_record(out / "s1" / "model.zip")["timesteps"] == 384
    assert read_record(out / "s2" / "model.zip")["seed"] == 2
    code = cli(["transfer", str(out / "s0"), str(out / "s1"), "--episodes", "1",
                "-o", str(tmp_path / "tr"), "--no-video"])  # fmt: skip
    assert code == 0
    rep = json.loads((tmp_path / "tr" / "transfer.json").read_text())
    assert [r["seed"] for r in rep["runs"]] == [0, 1]
    agg = rep["aggregate"]
    assert agg["n_runs"] == 2
    per_run = [r["target"]["mean_return"] for r in rep["runs"]]
    # IQM of two runs is their mean; the interval spans the runs
    assert agg["target_return"]["iqm"] == pytest.approx(np.mean(per_run))
    assert (
        min(per_run) - 1e-9
        <= agg["target_return"]["low"]
        <= agg["target_return"]["high"]
        <= max(per_run) + 1e-9
    )


def test_shipped_policy_is_found_by_name() -> None:
    path = pretrained_path("ppo")
    assert path.is_file() and path.name == "ppo_IcosahedronSR-v0.zip"
    assert read_record(path)["algo"] == "ppo"
    with pytest.raises(InputError, match="no shipped sac policy"):
        pretrained_path("sac")


def test_transfer_needs_a_policy_or_pretrained(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli(["transfer", "-o", str(tmp_path / "t")]) == 2
    assert "POLICY" in capsys.readouterr().err
