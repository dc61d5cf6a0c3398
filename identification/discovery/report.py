"""The residual loop's report: markdown (with the residual PNGs) and the extended params file.

One writer for both scorers (:class:`~identification.discovery.loop.DiscoveryResult`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from identification.discovery.judge import Candidate, Criteria
from identification.discovery.loop import DiscoveryResult
from identification.report.tables import error_text
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.effects.residual_network import NOT_PHYSICAL
from tensegrity_env.io_utils import atomic_write_text


def fmt_err(x: float) -> str:
    """An error [m] for a table; a diverged rollout (NaN or inf) says so."""
    return error_text(x)


def ratio(before: float, after: float) -> str:
    """``before / after`` as ``123x``, or which of the two diverged (NaN or inf)."""
    if not np.isfinite(after):
        return "diverged after" if np.isfinite(before) else "diverged both"
    if not np.isfinite(before):
        return "∞ (was diverged)"
    return f"{before / max(after, 1e-300):.3g}x"


def effect_table(effect: PhysicalEffect) -> str:
    """Markdown rows: parameter, value, unit, standard error."""
    d = effect.to_dict()
    lines = ["| parameter | value | unit | std. error |", "|---|---|---|---|"]
    for k, v in d["params"].items():
        se = d["uncertainty"].get(k, "")
        lines.append(f"| {k} | {_num(v)} | {d['units'][k]} | {_num(se) if se != '' else '-'} |")
    return "\n".join(lines)


def _num(v: Any) -> str:
    a = np.asarray(v, dtype=float)
    if a.size == 1:
        return f"{float(a):.4g}"
    return "[" + ", ".join(f"{x:.3g}" for x in a.ravel()) + "]"


def fmt_unit(x: float, unit: str) -> str:
    """An error in metres shown in ``unit`` (``"m"`` or ``"mm"``); diverged says so."""
    if unit == "mm":
        return error_text(x, ".4f", "mm", 1e3)
    return fmt_err(x)


def candidate_table(
    current: Candidate[Any],
    candidates: list[Candidate[Any]],
    criteria: Criteria,
    labels: dict[str, tuple[str, str]],
) -> str:
    """One row per candidate: gate, held-out errors, held-out gain, ΔBIC, verdict.

    ``labels``: error name -> (label, unit); the held-out errors the candidates carry.
    """
    keys = [k for k in labels if k in current.heldout]
    head = " | ".join(f"held-out {labels[k][0]}" for k in keys)
    lines = [
        f"| candidate | gate (why it may act) | {head} | {criteria.measure} gain | ΔBIC | verdict |",
        "|---|---|" + "---|" * len(keys) + "---|---|---|",
        "| *nothing is missing* | - | "
        + " | ".join(fmt_unit(current.heldout[k], labels[k][1]) for k in keys)
        + " | 0 | 0 | reference |",
    ]
    for c in candidates:
        errors = " | ".join(fmt_unit(c.heldout[k], labels[k][1]) for k in keys)
        lines.append(
            f"| {c.name} | {c.gate} | {errors} | {criteria.format_gain(c.gain)} | "
            f"{-c.bic_drop:+.4g} | {c.verdict} |"
        )
    return "\n".join(lines)


def test_table(
    before: dict[str, Any], after: dict[str, Any], labels: dict[str, tuple[str, str]]
) -> str:
    """Test-split errors before and after (the rows both hold)."""
    lines = ["| test split | before | after | improvement |", "|---|---|---|---|"]
    for key, (label, unit) in labels.items():
        if key in before and key in after:
            b, a = float(before[key]), float(after[key])
            lines.append(f"| {label} | {fmt_unit(b, unit)} | {fmt_unit(a, unit)} | {ratio(b, a)} |")
    return "\n".join(lines)


def write_report(
    result: DiscoveryResult,
    out: Path,
    source: str,
    planted: list[dict[str, Any]] | None = None,
    sections: Sequence[str] = (),
) -> Path:
    """``out/report.md``: every iteration's candidates, the choice, errors before and after.

    ``sections`` (markdown, each with its own heading) follow the result."""
    labels = result.test_labels
    data = "rod states" if result.method == "one_step" else "end caps"
    L = [f"# Residual loop: {source} ({data})", "", result.description, ""]
    L += ["## Result", "", test_table(result.baseline_test, result.final_test, labels), ""]
    L += [f"Added: **{', '.join(result.model.names) or 'nothing'}**", ""]
    if result.open_loop:
        L += [result.open_loop, ""]
    if result.rollout_plot is not None:
        L += [f"![measured end caps against the declared and the final model]"
              f"({result.rollout_plot.name})", ""]  # fmt: skip
    for e in result.model.effects:
        L += [f"### {e.name}", "", effect_table(e), ""]
    for section in sections:
        L += [section, ""]
    if planted is not None:
        names = [p.get("name") for p in planted] or ["nothing"]
        L += [
            f"Ground truth (read only for this report): planted {', '.join(map(str, names))}.",
            "",
        ]
    for k, it in enumerate(result.iterations):
        L += [f"## Iteration {k + 1}", ""]
        if it.residual.plot is not None:
            L += [f"![residuals, iteration {k + 1}]({it.residual.plot.name})", ""]
        L += [it.residual.markdown, ""]
        L += [candidate_table(it.before, it.candidates, result.criteria, labels), ""]
        if it.skipped:
            L += ["Not tried: " + "; ".join(f"{p.name}: {p.gate}" for p in it.skipped), ""]
        if it.chosen is None:
            L += ["**No candidate passes: stop.**", ""]
            continue
        c = it.added or it.chosen
        added = next(e for e in c.model.effects if e.name == c.name)
        instead = f", in place of {', '.join(it.replaced)}" if it.replaced else ""
        L += [f"**Added: {c.name}** ({type(added).summary}){instead}", ""]
        if it.removed:
            L += ["**Removed** (not needed beside it): "
                  + "; ".join(f"{n}: {why}" for n, why in it.removed.items()), ""]  # fmt: skip
        if it.runner_up is not None:
            r = it.runner_up
            L += [
                f"Runner-up **{r.name}** also passes: predicted changes correlate "
                f"{r.correlation:.3f} with the chosen one's; its {r.note}.",
                "",
            ]
        if it.ambiguous is not None:
            L += [
                f"**Flag:** {c.name} cannot be told apart from {it.ambiguous[0]} on this data "
                f"(their predicted changes correlate {it.ambiguous[1]:.3f}); the attribution is "
                "uncertain.",
                "",
            ]
        L += [effect_table(added), ""]
        if c.model.notes.get(c.name):
            L += [c.model.notes[c.name], ""]
        L += [test_table(it.test_before, it.test_after or {}, labels), ""]
    L += ["## Final residual", ""]
    if result.final_residual.plot is not None:
        L += [f"![final residuals]({result.final_residual.plot.name})", ""]
    L += [result.final_residual.markdown, ""]
    if result.unexplained:
        L += [f"**Unexplained:** {result.unexplained}", ""]
    elif result.method == "one_step":  # held-out error at round-off, or noisy data
        L += ["The residual left is noise (round-off or measurement noise).", ""]
    L += _network_section(result)
    return atomic_write_text(out / "report.md", "\n".join(L))


#: file names written beside ``params.json`` when a residual network absorbs the rest
NETWORK_PARAMS = "params_residual_network.json"


def _network_section(result: DiscoveryResult) -> list[str]:
    """Markdown lines about the residual network (none if there is none)."""
    fit = result.residual_network
    if fit is None:
        return []
    L = ["## Residual network (unexplained: NOT a physical effect)", "",
         f"{fit.effect.describe()}. Fitted jointly with the declared parameters "
         f"(readout by least squares, then Adam; {fit.seconds:.1f} s). It absorbs structure "
         "no candidate explains; it names nothing. The physical model above is unchanged.", "",
         "| held-out | split | loop's model | + residual network | improvement |",
         "|---|---|---|---|---|"]  # fmt: skip
    for split, before in fit.before.items():
        after = fit.after[split]
        for key, label in (
            ("one_step", "one-step"),
            ("rollout", f"{before['horizon_s']:g}-s rollout"),
        ):
            L.append(f"| {label} | {split} | {fmt_err(before[key])} | {fmt_err(after[key])} | "
                     f"{ratio(before[key], after[key])} |")  # fmt: skip
    moved = ", ".join(f"{k} {v:.1%}" for k, v in fit.moved.items())
    L += ["", f"Refitted with the network, the declared parameters move by (‖Δ‖/‖p‖): {moved} (a "
          "large move: the identified values are biased by what the network absorbs).",
          f"The network and its refitted parameters are in `{NETWORK_PARAMS}` (weights: "
          f"`{fit.effect.sidecar}`); `params.json` keeps the physical model.", ""]  # fmt: skip
    return L


def write_params(result: DiscoveryResult, path: Path, extra: dict[str, Any]) -> Path:
    """The extended params file: the model found (:meth:`Model.save`) and a ``diagnose`` section.

    With a residual network (``result.residual_network``), also writes its weights
    (sidecar, atomically) and ``params_residual_network.json`` beside ``path``: the
    declared parameters refitted with it and the effects, the network's entry
    included; ``params.json``'s ``diagnose.residual_network`` points at both.
    """
    doc = {
        "diagnose": {
            **extra,
            "added": result.added,
            "ambiguous": {
                it.chosen.name: {"with": amb[0], "correlation": amb[1]}
                for it in result.iterations
                if it.chosen is not None and (amb := it.ambiguous) is not None
            },
            "test_errors_before": {k: v for k, v in result.baseline_test.items() if k != "curve"},
            "test_errors_after": {k: v for k, v in result.final_test.items() if k != "curve"},
            "unexplained": result.unexplained,
        },
        "uncertainty": result.model.uncertainty,
    }
    fit = result.residual_network
    if fit is not None:
        directory = Path(path).parent
        fit.effect.save(directory)
        note = {"note": NOT_PHYSICAL, "params_file": NETWORK_PARAMS,
                "sidecar": fit.effect.sidecar, **fit.summary()}  # fmt: skip
        network_model = result.model.model.replace(params=fit.params, effects=fit.effects)
        network_doc = jsonable({"residual_network": note})
        network_model.save(directory / NETWORK_PARAMS, network_doc)
        doc["diagnose"]["residual_network"] = note
    doc = jsonable(doc)
    return result.model.model.save(path, doc)


def jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x
