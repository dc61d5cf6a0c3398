"""A goal-distance curriculum: near goals first, the task's full range as success rises.

A robot that crawls by winding its cables reaches a near goal with one lean; a far one
needs it to recover and lean again (a step). Trained on the full range from the start,
a policy can settle on the single lean, which reaches the near goals and never the far
ones. The curriculum trains on near goals first and widens the range in ``levels``
equal steps to the task's own ``goal_distance`` each time the training episodes succeed
often enough, so the policy meets goals a single lean cannot reach only once it
reliably reaches the others.

It is a training setting (``curriculum`` in the hyperparameters YAML, beside
``goal_frame``)::

    curriculum:
      start: [0.2, 0.3]   # goal distances of level 0 [m]
      levels: 4           # widening steps to the task's goal_distance
      threshold: 0.8      # success rate that widens the range
      window: 200         # over this many episodes ended since the last widening
      end: [0.3, 0.6]     # optional: the last level's range (default: goal_distance)

Level ``k`` draws goals ``(1 - k/levels) * start + (k/levels) * end`` away, both ends
interpolated; level ``levels`` is ``end``, by default the task's own ``goal_distance``
(an ``end`` beyond it trains on farther goals than the task asks for). The environment keeps the
task's ``goal_distance`` in its arguments, so evaluation (which rebuilds the env from
the run record) always uses the full task. The level reached is kept in the run record
(``curriculum_level``) and a resumed run continues from it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from tensegrity_env.io_utils import InputError

#: the settings a ``curriculum`` entry takes
KEYS = ("start", "levels", "threshold", "window", "end")


@dataclass(frozen=True)
class GoalCurriculum:
    """The schedule of goal distances.

    Attributes:
        start: goal-distance range of level 0 (low, high) [m].
        levels: widening steps from ``start`` to the task's range (>= 1).
        threshold: success rate (0-1] over ``window`` episodes that moves to the next level.
        window: episodes [count] that must have ended at the current level to judge it.
        end: goal-distance range of the last level (low, high) [m]; None: the task's.
    """

    start: tuple[float, float]
    levels: int = 4
    threshold: float = 0.8
    window: int = 200
    end: tuple[float, float] | None = None

    @classmethod
    def from_config(cls, entry: Any, where: str) -> GoalCurriculum:
        """The curriculum of a YAML mapping; :class:`InputError` naming ``where`` (file and
        env id) and the problem if it is not one."""
        if not isinstance(entry, Mapping):
            raise InputError(f"{where}: curriculum must be a mapping of {', '.join(KEYS)}")
        unknown = sorted(set(entry) - set(KEYS))
        if unknown:
            raise InputError(f"{where}: curriculum: unknown key(s) {unknown} (takes {list(KEYS)})")
        if "start" not in entry:
            raise InputError(f"{where}: curriculum needs start: [low, high] [m]")
        try:
            ranges = [tuple(float(d) for d in entry[k]) for k in ("start", "end") if k in entry]
            start = ranges[0]
            levels, window = int(entry.get("levels", 4)), int(entry.get("window", 200))
            threshold = float(entry.get("threshold", 0.8))
        except (TypeError, ValueError):
            raise InputError(f"{where}: curriculum: start and end must be two numbers each, "
                             "levels and window integers, threshold a number") from None  # fmt: skip
        for name, r in zip(("start", "end"), ranges, strict=False):
            if len(r) != 2 or not 0 <= r[0] <= r[1]:
                raise InputError(f"{where}: curriculum: {name} must be [low, high] with 0 <= "
                                 f"low <= high, got {list(r)}")  # fmt: skip
        if levels < 1 or window < 1 or not 0 < threshold <= 1:
            raise InputError(f"{where}: curriculum: levels and window must be >= 1 and "
                             f"threshold in (0, 1], got {levels}, {window}, {threshold}")  # fmt: skip
        end = (ranges[1][0], ranges[1][1]) if len(ranges) == 2 else None
        return cls((start[0], start[1]), levels, threshold, window, end)

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the run record."""
        d = asdict(self)
        d["start"] = list(self.start)
        if self.end is None:
            del d["end"]
        else:
            d["end"] = list(self.end)
        return d

    def distance(self, level: int, task: tuple[float, float]) -> tuple[float, float]:
        """Goal-distance range (low, high) [m] of ``level`` towards ``end`` (None: the
        task's range ``task``)."""
        final = self.end if self.end is not None else task
        w = min(max(level, 0), self.levels) / self.levels
        lo = (1 - w) * self.start[0] + w * final[0]
        hi = (1 - w) * self.start[1] + w * final[1]
        return lo, hi


class CurriculumCallback(BaseCallback):
    """Widens the training envs' goal distance as their episodes succeed (SB3 callback).

    The level is judged on a cohort: the first ``window`` episodes that start at the
    current level, once every one of them has ended. (Counting whichever episodes end
    first would over-count successes, which end early, while failures run to the time
    limit.) When the cohort's success rate (``is_success`` of its last step) is at least
    ``threshold``, the next level begins: ``set_goal_distance`` of the training env (the
    batched env's; episodes reset from then on draw the new range) and a new cohort;
    otherwise a new cohort at the same level. Logs ``curriculum/level``,
    ``curriculum/goal_far`` [m] and ``curriculum/success`` (of the last cohort).

    Args:
        curriculum: the schedule.
        task: the task's goal-distance range (low, high) [m].
        record: the run record; ``record["curriculum_level"]`` follows the level, so the
            checkpoints and the final model keep it.
        level: the level to start at (a resumed run's).
    """

    def __init__(
        self,
        curriculum: GoalCurriculum,
        task: tuple[float, float],
        record: dict[str, Any],
        level: int = 0,
    ) -> None:
        super().__init__()
        self.curriculum, self.task, self.record = curriculum, task, record
        self.level = min(max(int(level), 0), curriculum.levels)
        self.in_cohort = np.zeros(0, dtype=bool)  # (n_envs,): its episode is in the cohort
        self.started = 0  # cohort episodes started
        self.results: list[bool] = []  # success of each cohort episode that ended

    def _apply(self) -> None:
        lo, hi = self.curriculum.distance(self.level, self.task)
        self.training_env.env_method("set_goal_distance", lo, hi, indices=[0])
        self.record["curriculum_level"] = self.level
        self.logger.record("curriculum/level", self.level)
        self.logger.record("curriculum/goal_far", hi)

    def _new_cohort(self) -> None:
        self.in_cohort[:] = False
        self.started, self.results = 0, []

    def _on_training_start(self) -> None:
        # the episodes under way drew their goals before this level: never in a cohort
        self.in_cohort = np.zeros(self.training_env.num_envs, dtype=bool)
        self._apply()

    def _on_step(self) -> bool:
        ended = np.flatnonzero(self.locals["dones"])
        if ended.size == 0:
            return True
        infos = self.locals["infos"]
        for i in ended[self.in_cohort[ended]]:
            self.results.append(bool(infos[i].get("is_success", False)))
        self.in_cohort[ended] = False
        widened = False
        if len(self.results) >= self.curriculum.window:
            rate = float(np.mean(self.results))
            self.logger.record("curriculum/success", rate)
            self._new_cohort()
            if rate >= self.curriculum.threshold and self.level < self.curriculum.levels:
                self.level += 1
                self._apply()
                widened = True
        if not widened:  # the episodes that just began drew this level's goals
            join = ended[: max(self.curriculum.window - self.started, 0)]
            self.in_cohort[join] = True
            self.started += len(join)
        return True


def task_goal_distance(venv: VecEnv) -> tuple[float, float]:
    """The goal-distance range (low, high) [m] of a training env's task; :class:`InputError`
    where the env has no goal distance to widen (the shape task, an env without
    ``set_goal_distance``)."""
    from tensegrity_env.envs.robot_task import GoalTask
    from tensegrity_env.envs.task import RollingTask

    try:
        task = venv.get_attr("task", [0])[0]
    except AttributeError:
        task = None
    rolling = task.rolling if isinstance(task, GoalTask) else task
    if not isinstance(rolling, RollingTask):
        raise InputError("curriculum: needs a goal task on one of this package's batched envs")
    lo, hi = rolling.goal_distance
    return float(lo), float(hi)
