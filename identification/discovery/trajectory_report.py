"""Markdown report of the end-cap (noisy-data) residual loop (:mod:`identification.discovery.trajectory_loop`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from identification.discovery.report import effect_table, fmt_err, ratio
from identification.discovery.trajectory_loop import Candidate, NoisyDiagnoseResult
from identification.report.tables import error_text
from tensegrity_env.io_utils import atomic_write_text


def _mm(x: float) -> str:
    return error_text(x, ".4f", "mm", 1e3)


def candidate_table(current: Candidate, tried: list[Candidate]) -> str:
    """One row per candidate: gate, held-out RMS, held-out chi-square gain, ΔBIC, verdict."""
    lines = [
        "| candidate | gate (why it may act) | held-out end-cap RMS | held-out Δχ² | ΔBIC | verdict |",
        "|---|---|---|---|---|---|",
        f"| *nothing is missing* | - | {_mm(current.val_rms)} | 0 | 0 | reference |",
    ]
    for c in tried:
        lines.append(
            f"| {c.name} | {c.gate} | {_mm(c.val_rms)} | {-c.chi2_gain:+.4g} | "
            f"{-c.bic_drop:+.4g} | {c.verdict} |"
        )
    return "\n".join(lines)


def test_table(before: dict[str, float], after: dict[str, float], horizon_s: float) -> str:
    """Test-split errors before and after (clean-truth rows only when known)."""
    lines = ["| test split | before | after | improvement |", "|---|---|---|---|"]
    lines.append(f"| end-cap RMS (noisy, window states fitted) | {_mm(before['caps_rms'])} | "
                 f"{_mm(after['caps_rms'])} | {ratio(before['caps_rms'], after['caps_rms'])} |")  # fmt: skip
    for key, label in (("one_step", "one-step vs clean truth"),
                       ("rollout", f"{horizon_s:g}-s rollout vs clean truth")):  # fmt: skip
        if key in before and key in after:
            lines.append(f"| {label} | {fmt_err(before[key])} | {fmt_err(after[key])} | "
                         f"{ratio(before[key], after[key])} |")  # fmt: skip
    return "\n".join(lines)


def write_noisy_report(
    result: NoisyDiagnoseResult, out: Path, source: str, horizon_s: float,
    planted: list[dict[str, Any]] | None = None,
) -> Path:  # fmt: skip
    """``out/report.md``: every iteration's candidates, the choice, the errors."""
    L = [f"# Diagnosis of {source} (end caps, trajectory fit)", ""]
    L += [
        "Models are compared by multi-step prediction of the measured end caps: each is "
        "fitted jointly on windows of the training split; held-out windows (validation) "
        "fit only their initial states. A candidate must lower the training BIC by "
        f"{result.settings['min_bic_drop']:g} and the held-out chi-square by "
        f"{result.settings['min_chi2_gain']:g}. The declared model and every accepted one "
        f"are refitted on {result.settings.get('fit_windows', 0)} training windows: the "
        "parameters below and the test errors come from that fit.",
        "",
    ]
    if planted:
        L += [f"Planted (ground truth, not read by the loop): {planted}", ""]
    L += ["## Result", "", test_table(result.baseline_test, result.final_test, horizon_s), ""]
    names = result.model.names
    L += [f"Added: **{', '.join(names) or 'nothing'}**", ""]
    for e in result.model.effects:
        L += [f"### {e.name}", "", effect_table(e), ""]
    for k, it in enumerate(result.iterations):
        L += [f"## Iteration {k}", ""]
        if it.residual:
            r = it.residual
            L += [f"Held-out end-cap residual of the current model: RMS {r['rms'] * 1e3:.3f} mm; "
                  f"near the floor {r['near_floor'] * 1e3:.3f} mm vs above {r['above_floor'] * 1e3:.3f} mm; "
                  f"fastest quarter {r['fast'] * 1e3:.3f} mm vs slowest {r['slow'] * 1e3:.3f} mm; "
                  f"end of the window {r['late'] * 1e3:.3f} mm vs start {r['early'] * 1e3:.3f} mm.", ""]  # fmt: skip
        if it.plot is not None:
            L += [f"![held-out residuals, iteration {k}]({it.plot.name})", ""]
        L += [candidate_table(it.before, it.candidates), ""]
        for name, why in it.skipped:
            L += [f"- {name}: not tried ({why})"]
        L += [""]
        if it.chosen is None:
            L += ["No candidate passes: the loop stops.", ""]
            continue
        L += [f"Chosen: **{it.chosen.name}**."]
        if it.runner_up is not None:
            name, corr, gap = it.runner_up
            L += [f"Runner-up **{name}** also passes: predicted end-cap changes correlate "
                  f"{corr:.3f} with the chosen one's; its held-out chi-square is {gap:.4g} "
                  "higher."]  # fmt: skip
        if it.ambiguous is not None:
            L += [f"Cannot be told apart from **{it.ambiguous[0]}** (predicted changes "
                  f"correlate {it.ambiguous[1]:.3f})."]  # fmt: skip
        if it.test_after is not None:
            L += ["", test_table(it.test_before, it.test_after, horizon_s)]
        L += [""]
    if result.unexplained:
        L += [f"**Unexplained:** {result.unexplained}", ""]
    return atomic_write_text(out / "report.md", "\n".join(L))
