"""Policies on a generic winch-driven robot: train on TensegritySR-v0, transfer to its twin."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from policies.artifacts import load_policy
from policies.evaluate import episode_starts, evaluate
from policies.goal_frame import to_goal_frame
from policies.results import main as results
from policies.transfer import env_kwargs_of, transfer, twin_kwargs
from tensegrity_sr.cli import main as cli

#: the shipped lab 3-bar: 3 rods (6 end caps), 9 cables, 6 winches
CAPS, WINCHES = 6, 6


def still(obs: np.ndarray) -> np.ndarray:
    """A scripted policy that never winds: the robot rests where it starts."""
    return np.zeros(WINCHES, dtype=np.float32)


def test_evaluation_counts_the_successes_of_a_scripted_policy() -> None:
    # a goal inside the goal disc is reached on the first step without moving; one
    # outside it is never reached by a robot that does not move
    near = {"task": "goal", "goal_distance": (0.05, 0.05), "goal_radius": 0.2}
    far = {"task": "goal", "goal_distance": (0.6, 0.6), "goal_radius": 0.2}
    for kw, success, steps in ((near, 1.0, 1), (far, 0.0, 300)):
        starts = episode_starts("TensegritySR-v0", 2, seed=3, env_kwargs=kw)
        assert {"state", "winch", "target"} <= set(starts[0].options)
        for env_id, env_kw in (("TensegritySR-v0", kw), ("TensegrityMJ-v0", twin_kwargs(kw))):
            r = evaluate(still, env_id, starts, env_kw)
            assert r.success_rate == success, env_id
            assert np.all(r.steps == steps), env_id
    # both envs start from the same state and goal
    res = transfer(still, episodes=1, seed=3, source="TensegritySR-v0",
                   target="TensegrityMJ-v0", env_kwargs=far)  # fmt: skip
    assert res.source.success_rate == res.target.success_rate == 0.0


def test_goal_frame_of_a_robot_turns_end_caps_and_goal_only() -> None:
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(4, 3 * CAPS + 1 + 9 + WINCHES + 2)).astype(np.float32)
    seen = to_goal_frame(obs, CAPS)
    assert np.allclose(seen[:, -1], 0.0, atol=1e-6)  # the goal lies on +x
    assert np.allclose(seen[:, -2], np.linalg.norm(obs[:, -2:], axis=1), atol=1e-5)
    caps = obs[:, : 3 * CAPS].reshape(4, CAPS, 3)
    turned = seen[:, : 3 * CAPS].reshape(4, CAPS, 3)
    # lengths, heights and the cable/motor readings are unchanged
    assert np.allclose(np.linalg.norm(turned, axis=2), np.linalg.norm(caps, axis=2), atol=1e-5)
    assert np.allclose(turned[..., 2], caps[..., 2])
    assert np.array_equal(seen[:, 3 * CAPS : -2], obs[:, 3 * CAPS : -2])


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """PPO trained for 64 env steps on the 3-bar's identified env (the file's own model)."""
    tmp = tmp_path_factory.mktemp("robot")
    doc = yaml.safe_load((Path(__file__).parents[2] / "policies/hyperparams/ppo.yml").read_text())
    entry = {**doc["TensegritySR-v0"], "n_steps": 16, "batch_size": 32, "n_epochs": 1}
    hp = tmp / "ppo.yml"
    hp.write_text(yaml.safe_dump({"TensegritySR-v0": entry}))
    code = cli(["train", "ppo", "--env", "TensegritySR-v0", "--task", "goal", "--seeds", "0-1",
                "--timesteps", "64", "--n-envs", "2", "--hyperparams", str(hp),
                "--no-tensorboard", "-o", str(tmp / "runs")])  # fmt: skip
    assert code == 0
    return tmp


def test_fine_tuning_starts_from_a_policy_on_other_env_arguments(
    tiny_run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    start = tiny_run / "runs" / "s0" / "model.zip"
    doc = yaml.safe_load((tiny_run / "ppo.yml").read_text())
    doc["TensegritySR-v0"]["env_kwargs"]["tipped_starts"] = 0.5
    hp = tiny_run / "tipped.yml"
    hp.write_text(yaml.safe_dump(doc))
    args = ["train", "ppo", "--env", "TensegritySR-v0", "--task", "goal", "--timesteps", "32",
            "--n-envs", "2", "--hyperparams", str(hp), "--no-tensorboard"]  # fmt: skip
    assert cli([*args, "--init", str(start), "-o", str(tiny_run / "tuned")]) == 0
    first, tuned = load_policy(start), load_policy(tiny_run / "tuned")
    rec = tuned.record
    assert rec["init"] == str(start) and rec["init_timesteps"] == first.record["timesteps"]
    assert rec["timesteps"] == 32  # its own budget, counted from 0
    assert rec["env_kwargs"]["tipped_starts"] == 0.5
    # evaluation keeps the task's own starts
    assert "tipped_starts" not in env_kwargs_of(rec) and env_kwargs_of(rec)["task"] == "goal"
    # the statistics carried on from the policy's (a fresh run would count 32 steps)
    assert first.vecnorm is not None and tuned.vecnorm is not None
    assert tuned.vecnorm.obs_rms.count >= first.vecnorm.obs_rms.count + 32
    # bad input: one line, exit status 2
    assert cli([*args, "--init", str(tiny_run / "none.zip"), "-o", str(tiny_run / "x")]) == 2
    assert "--init" in capsys.readouterr().err


def test_generic_env_training_transfers_end_to_end(tiny_run: Path) -> None:
    runs = [tiny_run / "runs" / f"s{s}" for s in (0, 1)]
    policy = load_policy(runs[0])
    assert policy.record["env_kwargs"]["task"] == "goal"
    assert policy.goal_frame and policy.goal_frame_caps == CAPS
    out = tiny_run / "transfer"
    code = cli(["transfer", *map(str, runs), "--episodes", "2", "-o", str(out)])
    assert code == 0
    doc = json.loads((out / "transfer.json").read_text())
    assert len(doc["runs"]) == 2
    run = doc["runs"][0]
    # the source and twin were chosen from the run record
    assert run["source"]["env_id"] == "TensegritySR-v0"
    assert run["target"]["env_id"] == "TensegrityMJ-v0"
    assert len(run["source"]["returns"]) == len(run["target"]["returns"]) == 2
    agg = doc["aggregate"]
    assert agg["n_runs"] == 2 and agg["ratio"]["low"] <= agg["ratio"]["iqm"] <= agg["ratio"]["high"]
    # stored under the robot's key, with the markdown regenerated from the JSON
    stem = tiny_run / "results" / "policies"
    (stem.parent).mkdir()
    assert results(["--robot", f"lab_prism_winch={out / 'transfer.json'}", "-o", str(stem)]) == 0
    stored = json.loads(stem.with_suffix(".json").read_text())
    assert stored["lab_prism_winch"]["transfer"]["runs"][1]["record"]["seed"] == 1
    assert "Robot `lab_prism_winch`" in stem.with_suffix(".md").read_text()


def test_icosahedron_with_winches_is_the_same_robot_in_both_envs() -> None:
    import gymnasium as gym

    robot = str(Path(__file__).parents[2] / "tensegrity_env/assets/icosahedron_winches.xml")
    sr, mj = gym.make("TensegritySR-v0", robot=robot), gym.make("TensegrityMJ-v0", robot=robot)
    topo = sr.unwrapped.sim.topology
    assert (topo.n_rods, topo.n_springs, topo.n_winches) == (6, 24, 12)
    assert sr.action_space.shape == mj.action_space.shape == (12,)
    sr.reset(seed=0)
    mj.reset(seed=0, options=sr.unwrapped.start_options())
    rng = np.random.default_rng(0)
    for _ in range(40):
        a = rng.uniform(-1, 1, 12).astype(np.float32)
        sr.step(a)
        mj.step(a)
    # the file's own parameters in the engine follow MuJoCo (to well under a millimetre)
    assert np.abs(sr.unwrapped.state[:, :3] - mj.unwrapped.state[:, :3]).max() < 1e-6
