"""The committed policy results: one JSON assembled from ``transfer`` outputs, and its tables.

    python -m policies.results --shipped runs/transfer_shipped/transfer.json \\
        [--seeds runs/transfer_seeds/transfer.json ...] [--study runs/tune_ppo/study.json] \\
        -o docs/results/policies

writes ``policies.json`` (the inputs, unchanged, under ``shipped``, ``seeds`` (a list,
one per ``--seeds``) and ``study``, with the run records of the policies) and ``policies.md`` (markdown tables
generated from that JSON alone: ``--from-json docs/results/policies.json`` rewrites
the markdown without re-reading the inputs).

    python -m policies.results --robot lab_prism_winch=runs/robot/transfer/transfer.json \
        [--pipeline runs/robot/pipeline.json] -o docs/results/policies

adds (or replaces) one robot's results in an existing ``policies.json``, under the key
``lab_prism_winch``: a ``transfer`` output over several seeds of a policy trained on a
generic robot's identified model and evaluated in its twin, with the run records and
the pipeline that produced the model (``--pipeline``: the commands, as a JSON object).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from tensegrity_env.io_utils import InputError, atomic_write_text


def read_json(path: Path, option: str) -> dict[str, Any]:
    """A JSON object from ``path``; :class:`InputError` naming ``option`` otherwise."""
    try:
        doc = json.loads(path.read_text())
    except OSError as e:
        raise InputError(f"{option} {path}: cannot read ({e.strerror})") from None
    except ValueError:
        raise InputError(f"{option} {path}: not JSON") from None
    if not isinstance(doc, dict):
        raise InputError(f"{option} {path}: expected a JSON object")
    return doc


#: what the seeds table keeps of each run's record
RUN_KEYS = ("algo", "env_id", "seed", "timesteps", "wall_s", "hyperparams_file", "command",
            "env_kwargs")  # fmt: skip


def repo_path(path: str | None) -> str:
    """A file of this repository by its path inside it (``policies/...``, ``docs/...``)."""
    if not path:
        return "?"
    parts = Path(path).parts
    for i, part in enumerate(parts):
        if part in ("policies", "docs"):
            return "/".join(parts[i:])
    return path


def fmt(x: float | None, spec: str = ".2f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def shipped_table(doc: dict[str, Any]) -> list[str]:
    rec = doc.get("record", {})
    n = len(doc["source"]["returns"])
    lines = [
        f"## Shipped policy\n\n{rec.get('algo', '?').upper()} trained on {rec.get('env_id')} for "
        f"{rec.get('timesteps', 0):,} env steps in {fmt(rec.get('wall_s'), '.0f')} s (seed "
        f"{rec.get('seed')}, hyperparameters `{repo_path(rec.get('hyperparams_file'))}`; "
        f"`{rec.get('command')}`), evaluated deterministically over the same "
        f"{n} seeded episodes (seeds {doc['seed']}..{doc['seed'] + n - 1}) in both envs.\n",
        "| evaluated in | mean return ± std | success | mean time to goal [s] |",
        "| --- | --- | --- | --- |",
    ]
    for k in ("source", "target"):
        r = doc[k]
        lines.append(
            f"| {r['env_id']} | {fmt(r['mean_return'])} ± {fmt(r['std_return'])} | "
            f"{100 * r['success_rate']:.0f}% | {fmt(r['time_to_goal_s'])} |"
        )
    lines.append(f"\ntransfer ratio (twin return / identified-env return): **{doc['ratio']:.3f}**")
    return lines


def seeds_table(doc: dict[str, Any]) -> list[str]:
    agg = doc["aggregate"]
    runs = doc["runs"]
    src, tgt = runs[0]["source"]["env_id"], runs[0]["target"]["env_id"]

    def cell(k: str, scale: float = 1.0, spec: str = ".2f") -> str:
        a = agg[k]
        return f"{format(scale * a['iqm'], spec)} [{format(scale * a['low'], spec)}, {format(scale * a['high'], spec)}]"

    recs = [r.get("record") or {} for r in runs]
    files = sorted({repo_path(r.get("hyperparams_file")) for r in recs})
    steps = sorted({r.get("timesteps") or 0 for r in recs})
    trained = (
        f" trained with `{'`, `'.join(files)}` for {', '.join(f'{n:,}' for n in steps)} env steps"
        if any(recs)
        else ""
    )
    title = f"Seeds of `{'`, `'.join(files)}`" if any(recs) else "Seeds"
    lines = [
        f"## {title}\n\n{agg['n_runs']} runs{trained}, {doc['episodes']} episodes each; IQM "
        "with 95 % stratified bootstrap interval (rliable).\n",
        f"| seed | return {src} | success {src} | return {tgt} | success {tgt} | ratio |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for r in runs:
        s, t = r["source"], r["target"]
        lines.append(
            f"| {r.get('seed')} | {fmt(s['mean_return'])} | {100 * s['success_rate']:.0f}% | "
            f"{fmt(t['mean_return'])} | {100 * t['success_rate']:.0f}% | {r['ratio']:.3f} |"
        )
    lines.append(
        f"| **IQM** | {cell('source_return')} | {cell('source_success', 100, '.0f')}% | "
        f"{cell('target_return')} | {cell('target_success', 100, '.0f')}% | {cell('ratio', spec='.3f')} |"
    )
    return lines


def trial_origin(t: dict[str, Any]) -> str:
    """Where a trial's settings came from: the enqueued file, or the sampler."""
    return f"enqueued `{t['enqueued']}`" if t.get("enqueued") else "sampled"


def trial_rank(t: dict[str, Any]) -> tuple[bool, float]:
    """Sort key: complete trials first, then by value, best first."""
    value = t["value"] if t["value"] is not None else -math.inf
    return t["state"] != "COMPLETE", -value


def study_table(doc: dict[str, Any]) -> list[str]:
    best = doc.get("best")
    counts = ", ".join(f"{v} {k.lower()}" for k, v in doc["counts"].items() if v)
    s = doc.get("settings", {})
    lines = [
        f"## Search\n\nstudy `{doc['study_name']}` on {s.get('env_id')} ({s.get('sampler')}, "
        f"{s.get('pruner')}): {counts}; {s.get('timesteps', 0):,} env steps per trial, "
        f"value = mean return of the last of {s.get('n_evaluations')} deterministic evaluations "
        f"over {s.get('eval_episodes')} episodes (seeds {s.get('eval_seed')}..). "
        f"`{s.get('command')}`\n"
    ]
    for q in s.get("enqueued") or []:
        notes = "; ".join(q.get("notes", []))
        lines.append(f"enqueued: `{q['file']}`" + (f" ({notes})" if notes else "") + "\n")
    if best is not None:
        lines.append(
            f"best: trial {best['number']} ({trial_origin(best)}), mean return "
            f"{fmt(best['value'])}, success {fmt(best.get('success_rate'))}; parameters "
            f"`{json.dumps(best['params'])}`\n"
        )
    done = [t for t in doc.get("trials", []) if t["state"] in ("COMPLETE", "PRUNED")]
    if done:
        lines += [
            "| trial | settings | state | mean return | success | env steps | wall time [s] |",
            "| --- | --- | --- | --- | --- | --- | --- |",
        ]
        for t in sorted(done, key=trial_rank):
            succ = t.get("success_rate")
            lines.append(
                f"| {t['number']} | {trial_origin(t)} | {t['state'].lower()} | {fmt(t['value'])} | "
                f"{'-' if succ is None else f'{100 * succ:.0f}%'} | {t.get('timesteps') or 0:,} | "
                f"{fmt(t.get('wall_s'), '.0f')} |"
            )
    return lines


def shipped_origin(shipped: dict[str, Any], study: dict[str, Any]) -> list[str]:
    """Whether the shipped policy's settings are the search's best trial (by file name)."""
    rec, best = shipped.get("record", {}), study.get("best")
    algo = rec.get("algo", "?")
    if best is None or Path(rec.get("hyperparams_file") or "").name != f"best_{algo}.yml":
        return []
    s = study.get("settings", {})
    return [
        f"Its settings are the best trial of the search below: trial {best['number']} "
        f"({trial_origin(best)}), mean return {fmt(best['value'])} at "
        f"{s.get('timesteps', 0):,} env steps per trial, retrained from scratch for "
        f"{rec.get('timesteps', 0):,} env steps with seed {rec.get('seed')}."
    ]


def robot_table(name: str, doc: dict[str, Any]) -> list[str]:
    """One robot's section: how its model was made, then its seeds table."""
    pipe = doc.get("pipeline") or {}
    runs = doc["transfer"]["runs"]
    kw = (runs[0].get("record") or {}).get("env_kwargs") or {}
    lines = [f"## Robot `{name}`\n"]
    if pipe.get("summary"):
        lines.append(pipe["summary"] + "\n")
    if kw:
        shown = {k: (Path(v).name if k in ("model", "robot") else v) for k, v in kw.items()}
        lines.append(f"environment arguments: `{json.dumps(shown)}`\n")
    for cmd in pipe.get("commands", []):
        lines.append(f"    {cmd}")
    if pipe.get("commands"):
        lines.append("")
    table = seeds_table(doc["transfer"])
    table[0] = table[0].split("\n\n", 1)[-1]  # the runs and episodes, without the title
    walls = [(r.get("record") or {}).get("wall_s") for r in runs]
    if all(w is not None for w in walls):
        table[0] = table[0].rstrip() + (
            f" Training wall time per seed: {', '.join(f'{w:.0f}' for w in walls)} s.\n"
        )
    return [*lines, *table]


def markdown(doc: dict[str, Any]) -> str:
    """The tables of a combined results document."""
    parts = [
        "# Policy results\n",
        "Generated by `python -m policies.results` from policies.json.\n",
    ]
    if doc.get("shipped") is not None:
        parts += [*shipped_table(doc["shipped"]), ""]
        if doc.get("study") is not None:
            parts += [*shipped_origin(doc["shipped"], doc["study"]), ""]
    seeds = doc.get("seeds")
    for group in [seeds] if isinstance(seeds, dict) else seeds or []:
        parts += [*seeds_table(group), ""]
    if doc.get("study") is not None:
        parts += [*study_table(doc["study"]), ""]
    for name, robot in doc.items():
        if isinstance(robot, dict) and robot.get("kind") == "robot":
            parts += [*robot_table(name, robot), ""]
    return "\n".join(parts)


def relative(path: str) -> str:
    """``path`` relative to the working folder where it lies below it (a record names the
    files of the machine it ran on; the results name them as the reproduce line does)."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except (ValueError, OSError):
        return path


def read_seeds(path: Path) -> dict[str, Any]:
    """A ``transfer`` output over several runs, each run with its record's main keys (the
    hyperparameters file by its path in the repository, the env's files relative to the
    working folder)."""
    doc = read_json(path, "--seeds")
    for run in doc.get("runs", []):
        rec = read_json(Path(run["policy"]).with_suffix(".json"), "--seeds (run record)")
        run["record"] = {k: rec.get(k) for k in RUN_KEYS}
        if run["record"].get("hyperparams_file"):
            run["record"]["hyperparams_file"] = repo_path(run["record"]["hyperparams_file"])
        kw = run["record"].get("env_kwargs")
        if isinstance(kw, dict):
            run["record"]["env_kwargs"] = {
                k: relative(v) if k in ("model", "robot") and isinstance(v, str) else v
                for k, v in kw.items()
            }
        run["policy"] = relative(run["policy"])
    return doc


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m policies.results", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("--shipped", type=Path, help="transfer.json of the shipped policy")
    ap.add_argument("--record", type=Path,
                    help="the shipped policy's run record (default: beside the evaluated zip)")  # fmt: skip
    ap.add_argument("--seeds", type=Path, action="append", default=[],
                    help="transfer.json over several seeds of one recipe; repeatable")  # fmt: skip
    ap.add_argument("--study", type=Path, help="study.json of a search")
    ap.add_argument("--robot", action="append", default=[], metavar="NAME=TRANSFER_JSON",
                    help="a generic robot's transfer.json over several seeds, stored under "
                         "NAME in the existing output JSON; repeatable")  # fmt: skip
    ap.add_argument("--pipeline", type=Path,
                    help="with --robot: JSON object describing how its model was made")  # fmt: skip
    ap.add_argument("--from-json", type=Path, help="rewrite the markdown of a policies.json")
    ap.add_argument("-o", "--output", type=Path, default=Path("docs/results/policies"),
                    help="output stem (default %(default)s: .json and .md)")  # fmt: skip
    args = ap.parse_args(argv)
    try:
        if args.from_json is not None:
            doc = read_json(args.from_json, "--from-json")
        elif args.robot and args.shipped is None:
            out = args.output.with_suffix(".json")
            doc = read_json(out, "-o") if out.exists() else {}
            pipeline = read_json(args.pipeline, "--pipeline") if args.pipeline else None
            for spec in args.robot:
                name, sep, path = spec.partition("=")
                if not sep or not name or not path:
                    raise InputError(f"--robot {spec!r}: expected NAME=TRANSFER_JSON")
                doc[name] = {"kind": "robot", "pipeline": pipeline,
                             "transfer": read_seeds(Path(path))}  # fmt: skip
            atomic_write_text(out, json.dumps(doc, indent=2) + "\n")
        else:
            if args.shipped is None:
                raise InputError("--shipped is required (or --from-json)")
            doc = {"shipped": read_json(args.shipped, "--shipped")}
            record = args.record or Path(doc["shipped"]["policy"]).with_suffix(".json")
            doc["shipped"]["record"] = read_json(record, "--shipped (run record)")
            doc["seeds"] = [read_seeds(path) for path in args.seeds] or None
            doc["study"] = read_json(args.study, "--study") if args.study else None
            out = args.output.with_suffix(".json")
            if out.exists():  # the robots' results stay
                old = read_json(out, "-o")
                doc.update({k: v for k, v in old.items()
                            if isinstance(v, dict) and v.get("kind") == "robot"})  # fmt: skip
            atomic_write_text(args.output.with_suffix(".json"), json.dumps(doc, indent=2) + "\n")
        atomic_write_text(args.output.with_suffix(".md"), markdown(doc))
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.output.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
