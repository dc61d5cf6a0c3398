"""Train on the identified env vs train on MuJoCo: return and wall time, same step budget.

Trains one algorithm (PPO by default, the shipped hyperparameters) on
``IcosahedronSR-v0`` and then on ``IcosahedronMJ-v0`` with the same settings, seed and
env-step budget, one after the other in this process, and evaluates both policies over
the same seeded episodes in the MuJoCo twin. Prints the transfer table of the
SR-trained policy and the ratios against the MuJoCo-trained reference measured here:
return (at least 0.9 when the identified env stands in for MuJoCo) and training wall
time (below 1 when it is also cheaper). The ratio of the two runs' process CPU time
(every thread) is printed beside it: it measures the same cost apart from whatever else
the machine runs meanwhile, which changes the wall-time ratio.

    python benchmarks/bench_transfer.py --timesteps 1000000 -o runs/bench_transfer

Runs already in the output folder are reused (resumed to the budget), so an
interrupted benchmark continues where it stopped.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from policies.artifacts import load_policy
from policies.evaluate import episode_starts, evaluate
from policies.train import latest_checkpoint, train
from policies.transfer import (
    SOURCE_ENV,
    TARGET_ENV,
    TransferResult,
    reference_table,
    transfer_table,
)
from tensegrity_env.io_utils import atomic_write_text


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--algo", default="ppo", choices=("ppo", "sac"))
    p.add_argument("--timesteps", type=int, default=None, help="budget (default: the YAML's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--episodes", type=int, default=50, help="evaluation episodes")
    p.add_argument("--eval-seed", type=int, default=1000)
    p.add_argument("--threads", type=int, default=1, help="physics threads, both envs")
    p.add_argument("-o", "--output", type=Path, default=Path("runs/bench_transfer"))
    args = p.parse_args(argv)

    runs = {}
    for env_id in (SOURCE_ENV, TARGET_ENV):
        out = args.output / env_id
        resume = out.exists() and latest_checkpoint(out) is not None
        print(f"training {args.algo} on {env_id} into {out}", flush=True)
        runs[env_id] = train(
            args.algo, env_id, out, timesteps=args.timesteps, seed=args.seed,
            resume=resume, threads=args.threads,
            command=" ".join(["python", *sys.argv]),
        )  # fmt: skip
    starts = episode_starts(SOURCE_ENV, args.episodes, args.eval_seed)
    sr_policy = load_policy(runs[SOURCE_ENV].model_path)
    mj_policy = load_policy(runs[TARGET_ENV].model_path)
    result = TransferResult(
        evaluate(sr_policy, SOURCE_ENV, starts), evaluate(sr_policy, TARGET_ENV, starts)
    )
    ref = evaluate(mj_policy, TARGET_ENV, starts)
    sr, mj = runs[SOURCE_ENV], runs[TARGET_ENV]
    text = "\n\n".join(
        [
            f"# {args.algo} trained on {SOURCE_ENV} vs on {TARGET_ENV} ({args.episodes} episodes)",
            transfer_table(result, f"{args.algo} on SR"),
            reference_table(
                result,
                ref,
                f"{args.algo} on SR",
                f"{args.algo} on MJ",
                sr.wall_s,
                mj.wall_s,
                sr.timesteps,
                mj.timesteps,
            ),
        ]
    )
    cpu_ratio = sr.cpu_s / mj.cpu_s
    text += (
        f"\n\ntraining CPU time, transferred / reference: **{cpu_ratio:.3f}** "
        f"({sr.cpu_s:.0f} s / {mj.cpu_s:.0f} s, every thread of the training process)"
    )
    print(text)
    atomic_write_text(args.output / "bench_transfer.md", text + "\n")
    doc = {
        **result.to_dict(),
        "reference_return": ref.mean_return,
        "reference_success_rate": ref.success_rate,
        "reference_time_to_goal_s": ref.time_to_goal,
        "return_vs_reference": result.target.mean_return / ref.mean_return,
        "wall_s": {"sr": sr.wall_s, "mj": mj.wall_s, "ratio": sr.wall_s / mj.wall_s},
        "cpu_s": {"sr": sr.cpu_s, "mj": mj.cpu_s, "ratio": cpu_ratio},
        "timesteps": {"sr": sr.timesteps, "mj": mj.timesteps},
    }
    atomic_write_text(args.output / "bench_transfer.json", json.dumps(doc, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
