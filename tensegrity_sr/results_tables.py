"""The README's headline results table, generated from the committed JSON in docs/results/.

    python -m tensegrity_sr.results_tables          # rewrite the table in README.md
    python -m tensegrity_sr.results_tables --check  # exit 1 if README.md is out of date

The table sits between the markers ``<!-- results:begin -->`` and
``<!-- results:end -->``; everything else in the README is left alone. Its sources:
``docs/results/results.json`` (``tensegrity-sr experiment paper --scale full -o
docs/results``) and ``docs/results/policies.json`` (``python -m policies.results``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tensegrity_env.io_utils import atomic_write_text

ROOT = Path(__file__).resolve().parent.parent
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"
MODELS = ("Ours", "Interaction", "Interaction+Int", "Koopman+Int")


def headline(results: dict, policies: dict | None) -> str:
    """Markdown: rollout error of each model on the paper-scale icosahedron, parameter
    errors, and the shipped policy in both environments."""
    ico = results["assemblies"]["icosahedron"]
    steps = ico["counts"]["steps"]
    lines = [
        f"Icosahedron, paper scale ({ico['counts']['train']} training trajectories x {steps} "
        f"steps, test split), from `{results['command']}`:",
        "",
        f"| model | one-step position error [m] | {steps}-step rollout error [m] | training time [s] |",
        "| --- | --- | --- | --- |",
    ]
    for m in MODELS:
        if m in ico["curves"]:
            lines.append(
                f"| {m} | {ico['one_step'][m]['position']:.2e} | {ico['curves'][m][-1]:.2e} "
                f"| {ico['seconds'].get(m, float('nan')):.0f} |"
            )
    worst = max(ico["group_errors"].values())
    lines += ["", f"Ours recovers every parameter to {worst:.1e} relative (worst group)."]
    if policies is not None:
        s = policies["shipped"]
        lines += [
            "",
            "Shipped PPO policy, 100 seeded episodes (`python -m policies.results`):",
            "",
            "| evaluated in | mean return | success | mean time to goal [s] |",
            "| --- | --- | --- | --- |",
        ]
        for side in ("source", "target"):
            e = s[side]
            lines.append(
                f"| {e['env_id']} | {e['mean_return']:.1f} | {100 * e['success_rate']:.0f} % "
                f"| {e['time_to_goal_s']:.2f} |"
            )
        lines += ["", f"Transfer ratio (MuJoCo twin / identified env): **{s['ratio']:.3f}**."]
    return "\n".join(lines)


def render(readme: str, table: str) -> str:
    """``readme`` with the text between the markers replaced by ``table``."""
    if BEGIN not in readme or END not in readme:
        raise SystemExit(f"README.md: markers {BEGIN} / {END} missing")
    head, rest = readme.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{table}\n{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="exit 1 if README.md is out of date")
    args = ap.parse_args(argv)
    results = json.loads((ROOT / "docs/results/results.json").read_text())
    pol_path = ROOT / "docs/results/policies.json"
    policies = json.loads(pol_path.read_text()) if pol_path.is_file() else None
    readme_path = ROOT / "README.md"
    readme = readme_path.read_text()
    new = render(readme, headline(results, policies))
    if args.check:
        if new != readme:
            print("README.md: results table out of date; run python -m tensegrity_sr.results_tables")
            return 1
        return 0
    atomic_write_text(readme_path, new)
    return 0


if __name__ == "__main__":
    sys.exit(main())
