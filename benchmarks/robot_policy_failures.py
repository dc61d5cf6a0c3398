"""Why a winch-driven robot's goal policy fails: its seeded episodes, sorted by outcome.

Runs a trained policy (a ``train`` run's ``model.zip``, or the shipped one) over the
seeded episodes ``transfer`` uses (seeds 1000, 1001, ...) in ``TensegritySR-v0`` with the
policy's own env arguments (its run record: model, task options), and prints

* the success rate per band of the goal's start distance (is the goal reachable, and how
  does success fall with distance?);
* the failed episodes in two kinds: the robot **tipped** onto another face (the set of
  end caps touching the floor changed: the end cap lowest and those within 2 cm of it),
  with the median distance they ended from the goal; or it **stayed** on its face, with
  the median end distance and how many winches ended within 5 mm of a range limit (a
  lean that ran out of cable);
* the mean episode length of the successes against the time limit;
* the success rate by the goal's bearing from the centre of the base (the three lowest
  end caps at the start), as the angle to the nearest base end cap: 0 deg, the goal lies
  beyond a corner of the base; 60 deg, beyond the middle of an edge (the near and the far
  half of the goal distances apart).

    python benchmarks/robot_policy_failures.py policies/pretrained/ppo_TensegritySR-v0.zip
    python benchmarks/robot_policy_failures.py runs/policies_robot/runs/s0/model.zip --episodes 100

``--tipped-starts P`` starts a share P of the episodes resting on another face (the env's
training option ``tipped_starts``; 0 by default: the task's own starts, as evaluation
uses): how well the policy goes on from a tipped state.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import tensegrity_env  # noqa: F401  (registers the envs)
from policies.artifacts import load_policy, read_record
from policies.transfer import env_kwargs_of
from tensegrity_env.envs.robot_task import RobotSensors

#: an end cap within this height of the lowest one touches the floor [m]
ON_FLOOR = 0.02
#: a winch within this of an end of its range has run out of cable [m]
AT_LIMIT = 5e-3


def bearing(caps: np.ndarray, goal: np.ndarray) -> float:
    """Angle [deg] between the goal and the nearest base end cap as seen from the base's
    centre (0-60: 0 beyond a corner, 60 beyond an edge); caps (2R, 3), goal (2,) [m]."""
    base = caps[np.argsort(caps[:, 2])[:3], :2]
    c = base.mean(axis=0)
    to_goal = np.arctan2(goal[1] - c[1], goal[0] - c[0])
    to_caps = np.arctan2(base[:, 1] - c[1], base[:, 0] - c[0])
    off = np.abs((np.degrees(to_caps - to_goal) + 180.0) % 360.0 - 180.0)
    return float(off.min())


def episode(
    env: gym.Env, policy: object, seed: int
) -> tuple[bool, float, float, bool, int, int, float]:
    """(success, start distance [m], end distance [m], tipped, winches at a limit, steps,
    the goal's bearing off the nearest base corner at the start [deg])."""
    u = env.unwrapped
    sensors = RobotSensors(u.sim.topology)  # type: ignore[attr-defined]
    params = u.sim.params  # type: ignore[attr-defined]
    lo, hi = params.winch_min.numpy(), params.winch_max.numpy()
    obs, info = env.reset(seed=seed)
    start, first, tipped, steps = info["task_error"], None, False, 0
    off = bearing(sensors.end_caps(u.state[None])[0], u.target)  # type: ignore[attr-defined]
    while True:
        caps = sensors.end_caps(u.state[None])[0]  # type: ignore[attr-defined]
        low = frozenset(np.flatnonzero(caps[:, 2] < caps[:, 2].min() + ON_FLOOR).tolist())
        first = first or low
        tipped |= bool(low - first) and bool(first - low)
        obs, _, terminated, truncated, info = env.step(policy(obs))  # type: ignore[operator]
        steps += 1
        if terminated or truncated:
            break
    rest = u.winch[:, 0]  # type: ignore[attr-defined]
    limit = int(np.sum((rest - lo < AT_LIMIT) | (hi - rest < AT_LIMIT)))
    return bool(info["is_success"]), start, info["task_error"], tipped, limit, steps, off


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("policy", type=Path, help="a trained policy (model.zip)")
    p.add_argument("--episodes", type=int, default=100, help="seeded episodes (default 100)")
    p.add_argument("--seed", type=int, default=1000, help="first episode seed (default 1000)")
    p.add_argument("--bands", type=int, default=4, help="goal-distance bands (default 4)")
    p.add_argument("--tipped-starts", type=float, default=0.0,
                   help="share of episodes starting on another face (default 0)")  # fmt: skip
    args = p.parse_args(argv)
    if not 0.0 <= args.tipped_starts <= 1.0:
        p.error(f"--tipped-starts {args.tipped_starts}: a share in [0, 1]")
    kwargs = env_kwargs_of(read_record(args.policy))
    if args.tipped_starts > 0:
        kwargs["tipped_starts"] = args.tipped_starts
    env = gym.make("TensegritySR-v0", **kwargs)
    policy = load_policy(args.policy)
    rows = np.array([episode(env, policy, args.seed + k) for k in range(args.episodes)],
                    dtype=float)  # fmt: skip
    ok, start, end, tipped, limit, steps, off = (rows[:, 0] > 0, rows[:, 1], rows[:, 2],
                                                 rows[:, 3] > 0, rows[:, 4], rows[:, 5],
                                                 rows[:, 6])  # fmt: skip
    W = env.unwrapped.sim.topology.n_winches  # type: ignore[attr-defined]
    limit_s = env.spec.max_episode_steps if env.spec else None
    print(f"{args.policy}: {args.episodes} episodes from seed {args.seed}, env arguments "
          f"{kwargs}\nsuccess {ok.mean():.2f}; the successes took {steps[ok].mean():.0f} steps "
          f"on average (time limit {limit_s})")  # fmt: skip
    lo, hi = kwargs.get("goal_distance", (start.min(), start.max()))
    edges = np.linspace(lo, hi, args.bands + 1)
    for a, b in itertools.pairwise(edges):
        m = (start >= a) & (start <= b if b == edges[-1] else start < b)
        print(f"  goal {a:.3f}-{b:.3f} m away: {m.sum():3d} episodes, success "
              f"{ok[m].mean() if m.any() else float('nan'):.2f}")  # fmt: skip
    for label, m in (
        ("tipped onto another face", ~ok & tipped),
        ("stayed on its face", ~ok & ~tipped),
    ):
        if m.any():
            print(
                f"  failed, {label}: {m.sum()} (ended {np.median(end[m]):.2f} m from the goal, "
                f"median; winches at a range limit: median {np.median(limit[m]):.0f} of {W})"
            )
    print(f"  succeeded and tipped on the way: {np.sum(ok & tipped)}")
    mid = (lo + hi) / 2
    for near, m_d in ((f"{lo:.2f}-{mid:.2f}", start < mid), (f"{mid:.2f}-{hi:.2f}", start >= mid)):
        parts = []
        for a, b in ((0, 20), (20, 40), (40, 60)):
            m = m_d & (off >= a) & ((off <= b) if b == 60 else (off < b))
            rate = f"{ok[m].mean():.2f}" if m.any() else "-"
            parts.append(f"{a}-{b} deg {rate} of {m.sum()}")
        print(f"  goal {near} m away, by bearing off a base corner: " + ", ".join(parts))
    env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
