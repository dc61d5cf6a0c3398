"""The goal-distance curriculum: it widens the goals as training episodes succeed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.logger import Logger

from policies.artifacts import read_record
from policies.curriculum import CurriculumCallback, GoalCurriculum, task_goal_distance
from policies.hyperparams import load_hyperparams
from policies.train import train
from policies.vec import make_training_env
from tensegrity_env.io_utils import InputError

#: the goal task's range and disc: a robot that never moves reaches goals under 0.2 m
TASK = {"task": "goal", "goal_distance": (0.3, 0.5), "goal_radius": 0.2}


def still_robot_levels(threshold: float, steps: int = 300) -> tuple[int, list[float]]:
    """The level a curriculum reaches under a robot that never winds (it succeeds exactly
    when its goal is drawn inside the goal disc), and the goal distances [m] of the
    episodes reset at that level."""
    env_kw = {**TASK, "max_episode_steps": 10}  # a failure ends after 10 steps
    venv = make_training_env("TensegritySR-v0", 8, seed=0, env_kwargs=env_kw)
    # levels 0..3: goals 0-0.1, 0.1-0.3, 0.2-0.5, 0.3-0.7 m away
    curriculum = GoalCurriculum(start=(0.0, 0.1), levels=3, threshold=threshold, window=24,
                                end=(0.3, 0.7))  # fmt: skip
    record: dict[str, object] = {}
    cb = CurriculumCallback(curriculum, task_goal_distance(venv), record)
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=16, device="cpu")
    model.set_logger(Logger(folder=None, output_formats=[]))
    cb.init_callback(model)
    venv.reset()
    cb.on_training_start({}, {})
    drawn: dict[int, list[float]] = {}  # per level, the distances of the goals it drew
    for _ in range(steps):
        level = cb.level  # the ended episodes reset in this step draw this level's goals
        _, _, dones, infos = venv.step(np.zeros((8, 6), dtype=np.float32))
        goals = venv.get_attr("targets")[0][dones]
        drawn.setdefault(level, []).extend(np.linalg.norm(goals, axis=1).tolist())
        cb.update_locals({"dones": dones, "infos": infos})
        cb.on_step()
    assert record["curriculum_level"] == cb.level
    venv.close()
    return cb.level, drawn[cb.level]


def test_curriculum_widens_the_goal_distance_while_the_episodes_succeed() -> None:
    # every goal of level 0 lies in the disc: all succeed, so the range widens; at level 1
    # (0.1-0.3 m) half of them do: a 90 % threshold holds the robot there, a 30 % one
    # lets it widen once more, to 0.2-0.5 m, where a still robot never succeeds
    strict, drawn = still_robot_levels(threshold=0.9)
    assert strict == 1
    assert drawn and 0.1 - 0.01 <= min(drawn) and max(drawn) <= 0.3 + 0.01
    lenient, drawn = still_robot_levels(threshold=0.3)
    assert lenient == 2
    assert drawn and 0.2 - 0.01 <= min(drawn) and max(drawn) <= 0.5 + 0.01


def test_curriculum_levels_interpolate_to_the_task_or_its_end() -> None:
    c = GoalCurriculum(start=(0.2, 0.3), levels=2)
    assert c.distance(0, (0.3, 0.5)) == (0.2, 0.3)
    assert c.distance(1, (0.3, 0.5)) == pytest.approx((0.25, 0.4))
    assert c.distance(2, (0.3, 0.5)) == pytest.approx((0.3, 0.5))
    assert c.distance(9, (0.3, 0.5)) == pytest.approx((0.3, 0.5))
    far = GoalCurriculum(start=(0.2, 0.3), levels=2, end=(0.3, 0.7))
    assert far.distance(2, (0.3, 0.5)) == pytest.approx((0.3, 0.7))


def _hyperparams(tmp: Path, curriculum: object) -> Path:
    doc = yaml.safe_load((Path(__file__).parents[2] / "policies/hyperparams/ppo.yml").read_text())
    entry = {**doc["TensegritySR-v0"], "n_steps": 64, "batch_size": 256, "n_epochs": 1,
             "curriculum": curriculum}  # fmt: skip
    path = tmp / "ppo.yml"
    path.write_text(yaml.safe_dump({"TensegritySR-v0": entry}))
    return path


def test_bad_curriculum_is_one_error_naming_file_and_problem(tmp_path: Path) -> None:
    for bad, problem in (
        ({"levels": 3}, "needs start"),
        ({"start": [0.4, 0.3]}, "start must be"),
        ({"start": [0.1, 0.2], "threshold": 0}, "threshold in"),
        ({"start": [0.1, 0.2], "speed": 1}, "unknown key"),
        ([0.1, 0.2], "must be a mapping"),
    ):
        with pytest.raises(InputError, match=rf"ppo\.yml: TensegritySR-v0: curriculum.*{problem}"):
            load_hyperparams("ppo", "TensegritySR-v0", _hyperparams(tmp_path, bad))


def test_training_records_the_level_and_a_resumed_run_keeps_it(tmp_path: Path) -> None:
    # goals of level 0 lie in the goal disc: every episode succeeds on its first step
    hp = _hyperparams(tmp_path, {"start": [0.0, 0.1], "levels": 2, "window": 16})
    loaded = load_hyperparams("ppo", "TensegritySR-v0", hp)
    assert loaded.curriculum == GoalCurriculum((0.0, 0.1), 2, 0.8, 16)
    run = tmp_path / "run"
    first = train("ppo", "TensegritySR-v0", run, timesteps=512, n_envs=8, hyperparams=hp,
                  progress=False, tensorboard=False)  # fmt: skip
    assert first.record["hyperparams"]["curriculum"]["start"] == [0.0, 0.1]
    assert first.record["curriculum_level"] >= 1
    # the environment keeps the task's range: evaluation rebuilds the full task
    assert first.record["env_kwargs"]["goal_distance"] == [0.3, 0.5]
    again = train("ppo", "TensegritySR-v0", run, timesteps=1024, n_envs=8, hyperparams=hp,
                  resume=True, progress=False, tensorboard=False)  # fmt: skip
    assert again.record["curriculum_level"] >= first.record["curriculum_level"]
    assert read_record(again.model_path)["curriculum_level"] == again.record["curriculum_level"]


def test_both_goal_envs_take_a_goal_distance_and_the_shape_task_refuses_it() -> None:
    for env_id, kw in (("IcosahedronSR-v0", {}), ("TensegritySR-v0", TASK)):
        venv = make_training_env(env_id, 2, seed=0, env_kwargs=dict(kw))
        venv.env_method("set_goal_distance", 0.1, 0.2, indices=[0])
        assert task_goal_distance(venv) == (0.1, 0.2), env_id
        venv.reset()
        goals = venv.get_attr("goals" if env_id == "IcosahedronSR-v0" else "targets")[0]
        assert np.all((np.linalg.norm(goals, axis=1) >= 0.1 - 1e-9)
                      & (np.linalg.norm(goals, axis=1) <= 0.2 + 1e-9)), env_id  # fmt: skip
        venv.close()
    shape = make_training_env("TensegritySR-v0", 2, seed=0, env_kwargs={"task": "shape"})
    with pytest.raises(InputError, match="needs a goal task"):
        task_goal_distance(shape)
    with pytest.raises(ValueError, match="no goal distance"):
        shape.env_method("set_goal_distance", 0.1, 0.2, indices=[0])
    shape.close()
