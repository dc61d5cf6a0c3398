"""Policies: train, save, reload, resume, evaluate, transfer; bad files exit 2."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from policies import SHIPPED_POLICY
from policies.artifacts import load_policy, read_record, stats_path
from policies.evaluate import episode_starts, evaluate
from policies.goal_frame import VecGoalFrame, to_goal_frame, to_world_actions
from policies.hyperparams import load_hyperparams
from policies.train import TrainResult, train
from policies.transfer import transfer
from tensegrity_env.io_utils import InputError
from tensegrity_sr.cli import main as cli

SHIPPED = SHIPPED_POLICY
#: PPO small enough for a test: 8 envs x 64 steps per rollout
SMALL_PPO = {"n_steps": 64, "batch_size": 256, "n_epochs": 2}


def _small_hyperparams(tmp: Path, algo: str, **entry: object) -> Path:
    doc = yaml.safe_load(
        (Path(__file__).parents[2] / f"policies/hyperparams/{algo}.yml").read_text()
    )
    for env_id in doc:
        doc[env_id] = {**doc[env_id], **entry}
    path = tmp / f"{algo}.yml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> TrainResult:
    """PPO trained for 2,048 env steps (two checkpoints) on the batched identified env."""
    tmp = tmp_path_factory.mktemp("ppo")
    hp = _small_hyperparams(tmp, "ppo", **SMALL_PPO)
    return train("ppo", "IcosahedronSR-v0", tmp / "run", timesteps=2048, n_envs=8,
                 hyperparams=hp, checkpoint_every=1024, progress=False, tensorboard=True)  # fmt: skip


# ---------------------------------------------------------------------- hyperparameters
def test_hyperparams_are_keyed_by_environment_id(tmp_path: Path) -> None:
    for algo in ("ppo", "sac"):
        sr = load_hyperparams(algo, "IcosahedronSR-v0")
        mj = load_hyperparams(algo, "IcosahedronMJ-v0")
        assert sr.to_dict() == mj.to_dict()  # the reference trains with the same settings
        assert sr.normalize is not None
    with pytest.raises(InputError, match=r"ppo\.yml: no entry for 'Pendulum-v1'"):
        load_hyperparams("ppo", "Pendulum-v1")
    bad = tmp_path / "bad.yml"
    bad.write_text("IcosahedronSR-v0: {policy_kwargs: {activation_fn: swish}}\n")
    with pytest.raises(InputError, match=r"bad\.yml"):
        load_hyperparams("ppo", "IcosahedronSR-v0", bad)


# ---------------------------------------------------------------------- save / reload / resume
def test_saved_policy_reloads_and_evaluates_identically(trained: TrainResult) -> None:
    starts = episode_starts("IcosahedronSR-v0", 2, seed=7)
    in_memory = evaluate(trained.policy, "IcosahedronSR-v0", starts)
    reloaded = load_policy(trained.model_path)
    from_disk = evaluate(reloaded, "IcosahedronSR-v0", starts)
    np.testing.assert_allclose(from_disk.returns, in_memory.returns, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(from_disk.steps, in_memory.steps)
    # the folder resolves to the same policy, and the record knows what trained it
    assert load_policy(trained.model_path.parent).path == trained.model_path
    assert reloaded.record["timesteps"] == trained.timesteps == 2048
    assert reloaded.record["algo"] == "ppo" and reloaded.algo == "ppo"


def test_normalization_is_saved_and_frozen_at_evaluation(trained: TrainResult) -> None:
    policy = load_policy(trained.model_path)
    vn = policy.vecnorm
    assert vn is not None and stats_path(trained.model_path).exists()
    assert not vn.training and not vn.norm_reward
    mean, var, count = vn.obs_rms.mean.copy(), vn.obs_rms.var.copy(), vn.obs_rms.count
    assert count > 2048  # statistics were learnt in training, not left at their start
    evaluate(policy, "IcosahedronMJ-v0", episode_starts("IcosahedronSR-v0", 1, seed=3))
    np.testing.assert_array_equal(vn.obs_rms.mean, mean)
    np.testing.assert_array_equal(vn.obs_rms.var, var)
    assert vn.obs_rms.count == count
    obs = np.linspace(-1, 1, 75, dtype=np.float32)
    expected = np.clip((obs - mean) / np.sqrt(var + vn.epsilon), -vn.clip_obs, vn.clip_obs)
    np.testing.assert_allclose(policy.normalize(obs), expected, rtol=1e-5, atol=1e-6)


def test_resume_continues_the_timestep_counter(trained: TrainResult, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(trained.model_path.parent, run)  # the shared run stays as trained
    ckpts = sorted(p.name for p in (run / "checkpoints").glob("ckpt_*.zip"))
    assert ckpts == ["ckpt_0000001024.zip", "ckpt_0000002048.zip"]
    with pytest.raises(InputError, match="already holds a run"):
        train("ppo", "IcosahedronSR-v0", run, timesteps=4096, progress=False)
    hp = trained.record["hyperparams_file"]
    resumed = train("ppo", "IcosahedronSR-v0", run, timesteps=3072, n_envs=8, hyperparams=hp,
                    checkpoint_every=1024, resume=True, progress=False)  # fmt: skip
    assert resumed.timesteps == 3072
    assert resumed.policy.model.num_timesteps == 3072
    assert (run / "checkpoints" / "ckpt_0000003072.zip").exists()
    assert [p.name for p in (run / "tb").iterdir()] == ["PPO_1"]  # one TensorBoard run
    # wall and CPU time accumulate across resumes, from the checkpoint resumed (2048 steps;
    # the finished run's own totals also count what it did after that checkpoint)
    at = read_record(run / "checkpoints" / "ckpt_0000002048.zip")
    assert 0 < at["wall_s"] < resumed.wall_s and 0 < at["cpu_s"] < resumed.cpu_s


def test_sac_saves_its_replay_buffer_and_reloads_identically(tmp_path: Path) -> None:
    hp = _small_hyperparams(tmp_path, "sac", learning_starts=200, buffer_size=5000, batch_size=64,
                            policy_kwargs={"net_arch": [32, 32]})  # fmt: skip
    result = train("sac", "IcosahedronSR-v0", tmp_path / "run", timesteps=400, n_envs=4,
                   hyperparams=hp, checkpoint_every=200, progress=False, tensorboard=False)  # fmt: skip
    buffers = list((tmp_path / "run" / "checkpoints").glob("*_replay_buffer.pkl"))
    assert [b.name for b in buffers] == ["ckpt_0000000400_replay_buffer.pkl"]  # newest only
    starts = episode_starts("IcosahedronSR-v0", 1, seed=0)
    a = evaluate(result.policy, "IcosahedronSR-v0", starts)
    b = evaluate(load_policy(result.model_path), "IcosahedronSR-v0", starts)
    np.testing.assert_allclose(a.returns, b.returns, rtol=0, atol=1e-9)


# ---------------------------------------------------------------------- transfer
def test_same_episodes_start_identically_in_both_envs() -> None:
    starts = episode_starts("IcosahedronSR-v0", 2, seed=5)
    assert starts[0].seed == 5 and starts[1].seed == 6
    assert not np.allclose(starts[0].goal, starts[1].goal)

    def still(obs: np.ndarray) -> np.ndarray:
        return np.zeros(18, dtype=np.float32)

    sr = evaluate(still, "IcosahedronSR-v0", starts[:1])
    mj = evaluate(still, "IcosahedronMJ-v0", starts[:1])
    assert sr.steps[0] == mj.steps[0] == 300  # no goal reached, both truncated
    assert abs(sr.returns[0]) < 0.5 and abs(mj.returns[0]) < 0.5  # and nobody moved


def test_transfer_command_trains_the_reference_with_the_same_budget(
    trained: TrainResult, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, ref = tmp_path / "transfer", tmp_path / "reference"
    code = cli(["transfer", str(trained.model_path), "--episodes", "2", "--no-video",
                "--train-reference", str(ref), "-o", str(out)])  # fmt: skip
    assert code == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]  # every file with its folder
    assert last == f"wrote {out / 'transfer.md'} and {out / 'transfer.json'}"
    doc = json.loads((out / "transfer.json").read_text())
    assert doc["ratio"] == pytest.approx(
        doc["target"]["mean_return"] / doc["source"]["mean_return"]
    )
    reference = load_policy(ref)
    assert reference.record["env_id"] == "IcosahedronMJ-v0"
    for key in ("algo", "seed", "timesteps", "n_envs", "hyperparams"):
        assert reference.record[key] == trained.record[key], key
    assert doc["reference"]["timesteps"] == trained.timesteps
    text = (out / "transfer.md").read_text()
    assert "transfer ratio" in text and "trained directly on IcosahedronMJ-v0" in text


@pytest.mark.skipif(not SHIPPED.exists(), reason="no shipped policy")
def test_shipped_policy_reaches_the_goal_in_both_envs() -> None:
    policy = load_policy(SHIPPED)
    assert policy.vecnorm is not None and policy.record["env_id"] == "IcosahedronSR-v0"
    result = transfer(policy, episodes=2, seed=1003)  # two starts it solves in both
    assert result.source.success.all() and result.target.success.all()


# ---------------------------------------------------------------------- bad input
def test_bad_files_exit_2_with_one_line(
    trained: TrainResult, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    garbage = tmp_path / "garbage.zip"
    garbage.write_bytes(b"not a zip")
    broken_stats = tmp_path / "copy.zip"
    broken_stats.write_bytes(trained.model_path.read_bytes())
    stats_path(broken_stats).write_bytes(b"\x80\x04truncated")
    cases = [
        (["transfer", str(tmp_path / "missing.zip")], "missing.zip"),
        (["transfer", str(garbage)], "garbage.zip"),
        (["transfer", str(broken_stats)], "copy_vecnormalize.pkl"),
        (["transfer", str(trained.model_path), "--target", "Nope-v0"], "Nope-v0"),
        (["train", "ppo", "--env", "Nope-v0", "-o", str(tmp_path / "r")], "Nope-v0"),
        (["train", "ppo", "--hyperparams", str(tmp_path / "none.yml")], "none.yml"),
    ]
    for argv, name in cases:
        capsys.readouterr()
        assert cli(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("error:") and name in err and "\n" not in err, err


# ---------------------------------------------------------------------- goal frame
def test_goal_frame_turns_the_scene_so_the_goal_is_ahead() -> None:
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(4, 75)).astype(np.float32)
    seen = to_goal_frame(obs)
    np.testing.assert_allclose(seen[:, 73], np.linalg.norm(obs[:, 73:75], axis=1), rtol=1e-6)
    np.testing.assert_allclose(seen[:, 74], 0.0, atol=1e-6)
    np.testing.assert_array_equal(seen[:, 72], obs[:, 72])  # height unchanged
    lengths = np.linalg.norm(obs[:, :72].reshape(4, 24, 3), axis=-1)
    np.testing.assert_allclose(
        np.linalg.norm(seen[:, :72].reshape(4, 24, 3), axis=-1), lengths, rtol=1e-5
    )
    # "push straight ahead" in the goal frame is "push towards the goal" in the world
    ahead = np.tile([1.0, 0.0, 0.0], (4, 6)).astype(np.float32)
    world = to_world_actions(ahead, obs).reshape(4, 6, 3)
    direction = obs[:, 73:75] / np.linalg.norm(obs[:, 73:75], axis=1, keepdims=True)
    np.testing.assert_allclose(world[:, :, :2], np.repeat(direction[:, None], 6, 1), atol=1e-6)
    # actions come back inside the unit ball, so the task's own clipping changes nothing
    big = to_world_actions(np.ones((4, 18), np.float32), obs).reshape(4, 6, 3)
    assert np.all(np.linalg.norm(big, axis=-1) <= 1 + 1e-6) and np.all(np.abs(big) <= 1)


def test_goal_frame_wrapper_turns_terminal_observations() -> None:
    from tensegrity_env.envs import IcosahedronSRVectorEnv, SB3VecEnv

    venv = VecGoalFrame(SB3VecEnv(IcosahedronSRVectorEnv(num_envs=2, max_episode_steps=2)))
    venv.seed(0)
    obs = venv.reset()
    np.testing.assert_allclose(obs[:, 74], 0.0, atol=1e-6)
    for _ in range(2):
        obs, _, done, infos = venv.step(np.zeros((2, 18), np.float32))
    assert done.all()
    for info in infos:
        assert abs(info["terminal_observation"][74]) < 1e-6


# ---------------------------------------------------------------------- to the targets (slow)
@pytest.mark.slow
def test_ppo_trained_on_the_identified_env_transfers(tmp_path: Path) -> None:
    """The shipped recipe (ppo.yml, seed 0, 1M steps, ~5 min): transfer ratio >= 0.9."""
    result = train("ppo", "IcosahedronSR-v0", tmp_path / "sr", seed=0, progress=False)
    t = transfer(load_policy(result.model_path), episodes=50, seed=1000)
    assert t.ratio >= 0.9
    assert t.target.success_rate >= 0.5


@pytest.mark.slow
def test_identified_env_policy_matches_one_trained_on_mujoco(tmp_path: Path) -> None:
    """Same recipe on both envs (the MuJoCo run takes ~25 min on one core): the
    SR-trained policy gets >= 90 % of the MuJoCo-trained one's return in MuJoCo, in less
    training wall time."""
    sr = train("ppo", "IcosahedronSR-v0", tmp_path / "sr", seed=0, progress=False)
    mj = train("ppo", "IcosahedronMJ-v0", tmp_path / "mj", seed=0, progress=False)
    starts = episode_starts("IcosahedronSR-v0", 50, seed=1000)
    ours = evaluate(load_policy(sr.model_path), "IcosahedronMJ-v0", starts)
    reference = evaluate(load_policy(mj.model_path), "IcosahedronMJ-v0", starts)
    assert ours.mean_return >= 0.9 * reference.mean_return
    assert sr.wall_s < mj.wall_s
