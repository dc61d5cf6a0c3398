"""``tensegrity-sr transfer``: a trained policy in IcosahedronSR-v0 and in its MuJoCo twin."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any

from tensegrity_env.io_utils import (
    InputError,
    add_force_option,
    atomic_dir,
    atomic_write_text,
    check_number,
    check_output_dir,
)


def register(sub: Any) -> None:
    p = sub.add_parser(
        "transfer",
        help="evaluate a policy in the identified env and the MuJoCo twin (sim-to-sim transfer)",
        description=(
            "Evaluate POLICY (a model zip with its _vecnormalize.pkl beside it, or a training "
            "folder) deterministically over the same seeded episodes in the source env "
            "(default IcosahedronSR-v0) and the target env (default IcosahedronMJ-v0, the "
            "ground truth): mean return, success rate, time to goal in each and the transfer "
            "ratio (target return / source return), with a side-by-side video. With "
            "--train-reference DIR the same algorithm and hyperparameters are also trained "
            "directly on the target with the same env-step budget and seed, and compared; "
            "--reference MODEL compares against such a policy trained earlier. A policy "
            "trained on TensegritySR-v0 is evaluated with the environment arguments of its "
            "run record (identified model, robot, task) and its twin TensegrityMJ-v0 on the "
            "same robot file; --source/--target default to the pair it was trained for."
        ),
    )
    p.add_argument("policy", type=Path, nargs="*",
                   help="model zip or training folder; several (one per seed): IQM with 95 %% "
                        "bootstrap intervals over them")  # fmt: skip
    p.add_argument("--pretrained", choices=("ppo",), default=None,
                   help="the policy shipped with the package instead of POLICY")  # fmt: skip
    p.add_argument("--episodes", type=int, default=20, help="episodes per env (default 20)")
    p.add_argument("--seed", type=int, default=1000,
                   help="episode k starts from the source's reset(seed=SEED+k) (default 1000)")  # fmt: skip
    p.add_argument("--source", default=None,
                   help="env trained in (default: the policy's, else IcosahedronSR-v0)")  # fmt: skip
    p.add_argument("--target", default=None,
                   help="env transferred to (default: the source's MuJoCo twin)")  # fmt: skip
    p.add_argument("-o", "--output", type=Path, default=Path("transfer"),
                   help="folder for transfer.md, transfer.json and the video (default %(default)s)")  # fmt: skip
    p.add_argument("--no-video", action="store_true", help="skip the side-by-side video")
    ref = p.add_mutually_exclusive_group()
    ref.add_argument("--reference", type=Path, default=None,
                     help="a policy trained on the target env to compare with")  # fmt: skip
    ref.add_argument("--train-reference", type=Path, default=None, metavar="DIR",
                     help="train the reference on the target into DIR (same algo, budget, seed)")  # fmt: skip
    p.add_argument("--threads", type=int, default=1,
                   help="physics threads when training the reference, 0 for every core")  # fmt: skip
    add_force_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from policies.artifacts import load_policy, read_record, resolve_model_path
    from policies.evaluate import episode_starts, evaluate
    from policies.transfer import (
        SOURCE_ENV,
        TARGET_ENV,
        TWINS,
        TransferResult,
        env_kwargs_of,
        reference_table,
        side_by_side_video,
        train_reference,
        transfer_table,
        twin_kwargs,
    )
    from policies.vec import env_spec

    check_output_dir(args.output, args.force, inputs=[*args.policy, args.reference])
    if args.train_reference is not None:  # an existing reference run is resumed, not replaced
        check_output_dir(args.train_reference, force=True, option="--train-reference")
    if args.episodes < 1:
        raise InputError("--episodes must be >= 1")
    check_number("--seed", args.seed, 0)
    check_number("--threads", args.threads, 0)
    if bool(args.policy) == (args.pretrained is not None):
        raise InputError("give POLICY (one or more) or --pretrained, not both or neither")
    if args.pretrained is not None:
        from policies.artifacts import pretrained_path

        args.policy = [pretrained_path(args.pretrained, args.source or SOURCE_ENV)]
    first = read_record(resolve_model_path(args.policy[0]))
    args.env_kwargs = env_kwargs_of(first)
    args.source = args.source or first.get("env_id") or SOURCE_ENV
    args.target = args.target or TWINS.get(args.source, TARGET_ENV)
    env_spec(args.source), env_spec(args.target)  # unknown ids fail before any work
    if len(args.policy) > 1:
        return run_several(args)
    policy = load_policy(args.policy[0])
    label = f"{policy.algo} ({policy.path})"
    src_kw, tgt_kw = args.env_kwargs, twin_kwargs(args.env_kwargs)
    starts = episode_starts(args.source, args.episodes, args.seed, src_kw)
    print(
        f"evaluating {policy.path} over {args.episodes} episodes in {args.source} and {args.target}"
    )
    result = TransferResult(
        evaluate(policy, args.source, starts, src_kw),
        evaluate(policy, args.target, starts, tgt_kw),
    )
    report = [f"# Transfer of {policy.path}\n", transfer_table(result, label)]
    doc: dict[str, Any] = {"policy": str(policy.path), "seed": args.seed, **result.to_dict()}

    ref_path = args.reference
    if args.train_reference is not None:
        print(f"training the reference on {args.target} into {args.train_reference}")
        ref_path = train_reference(
            policy.record, args.target, args.train_reference, threads=args.threads or None,
            command=shlex.join(["tensegrity-sr", *sys.argv[1:]]),
        ).model_path  # fmt: skip
    if ref_path is not None:
        ref = load_policy(ref_path)
        ref_eval = evaluate(ref, args.target, starts, tgt_kw)
        rec = policy.record
        report += [
            f"\n## Against {ref.algo} trained directly on {args.target}\n",
            reference_table(
                result, ref_eval, label, f"{ref.algo} ({ref.path})",
                rec.get("wall_s"), ref.record.get("wall_s"),
                rec.get("timesteps"), ref.record.get("timesteps"),
            ),
        ]  # fmt: skip
        doc["reference"] = {
            "policy": str(ref.path),
            "mean_return": ref_eval.mean_return,
            "success_rate": ref_eval.success_rate,
            "time_to_goal_s": ref_eval.time_to_goal,
            "returns": ref_eval.returns.tolist(),
            "wall_s": ref.record.get("wall_s"),
            "timesteps": ref.record.get("timesteps"),
        }
    written = [args.output / "transfer.md", args.output / "transfer.json"]
    with atomic_dir(args.output) as out:  # moved to --output only when complete
        if not args.no_video:
            from tensegrity_env.envs import RenderingUnavailable

            try:
                video = side_by_side_video(
                    policy, out / "side_by_side.mp4", args.seed, source=args.source,
                    target=args.target, env_kwargs=src_kw,
                )  # fmt: skip
                report.append(f"\nvideo (left {args.source}, right {args.target}): {video.name}")
                written.append(args.output / video.name)
            except RenderingUnavailable as e:
                print(f"no video: {e}")
        text = "\n".join(report) + "\n"
        atomic_write_text(out / "transfer.md", text)
        atomic_write_text(out / "transfer.json", json.dumps(doc, indent=2) + "\n")
    print(text)
    print(f"wrote {', '.join(str(w) for w in written[:-1])} and {written[-1]}")
    return 0


def run_several(args: argparse.Namespace) -> int:
    """Several runs over the same episodes: each run's table, then IQM with intervals."""
    from policies.aggregate import aggregate, aggregate_table, to_dict
    from policies.artifacts import load_policy
    from policies.evaluate import episode_starts, evaluate
    from policies.transfer import TransferResult, transfer_table, twin_kwargs

    if args.reference is not None or args.train_reference is not None:
        raise InputError("--reference/--train-reference take one POLICY, not several")
    policies = [load_policy(p) for p in args.policy]  # every file checked before any work
    for policy in policies[1:]:
        if policy.record.get("env_kwargs", {}) != policies[0].record.get("env_kwargs", {}):
            raise InputError(f"{policy.path}: trained with other environment arguments than "
                             f"{policies[0].path}")  # fmt: skip
    src_kw, tgt_kw = args.env_kwargs, twin_kwargs(args.env_kwargs)
    starts = episode_starts(args.source, args.episodes, args.seed, src_kw)
    report = [f"# Transfer of {len(policies)} runs over {args.episodes} episodes\n"]
    runs, results = [], []
    for policy in policies:
        print(f"evaluating {policy.path} in {args.source} and {args.target}")
        r = TransferResult(
            evaluate(policy, args.source, starts, src_kw),
            evaluate(policy, args.target, starts, tgt_kw),
        )
        results.append(r)
        report += [transfer_table(r, f"{policy.algo} ({policy.path})"), ""]
        runs.append({"policy": str(policy.path), "seed": policy.record.get("seed"), **r.to_dict()})
    agg = aggregate(results)
    report.append(aggregate_table(agg, len(results), args.source, args.target))
    doc = {"seed": args.seed, "episodes": args.episodes, "runs": runs,
           "aggregate": to_dict(agg, len(results))}  # fmt: skip
    text = "\n".join(report) + "\n"
    with atomic_dir(args.output) as out:  # moved to --output only when complete
        atomic_write_text(out / "transfer.md", text)
        atomic_write_text(out / "transfer.json", json.dumps(doc, indent=2) + "\n")
    print(text)
    print(f"wrote {args.output / 'transfer.md'} and {args.output / 'transfer.json'}")
    return 0
