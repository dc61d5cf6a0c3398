"""The residual loop's report: markdown (with the residual PNGs) and the extended params file."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from identification.discovery.diagnose import DiagnoseResult, Scored
from identification.discovery.residuals import summary_table
from identification.report.tables import error_text
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.effects.residual_network import NOT_PHYSICAL
from tensegrity_env.io_utils import atomic_write_text

if TYPE_CHECKING:
    from identification.discovery.trajectory_loop import NoisyDiagnoseResult


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


def candidate_table(current: Scored, candidates: list[Scored]) -> str:
    lines = [
        "| candidate | gate (why it may act) | held-out one-step | held-out rollout | ΔBIC | verdict |",
        "|---|---|---|---|---|---|",
        f"| *nothing is missing* | - | {fmt_err(current.val['one_step'])} | "
        f"{fmt_err(current.val['rollout'])} | 0 | reference |",
    ]
    for s in candidates:
        d = s.bic - current.bic
        lines.append(
            f"| {s.name} | {s.gate} | {fmt_err(s.val['one_step'])} | {fmt_err(s.val['rollout'])} | "
            f"{d:+.3g} | {s.verdict} |"
        )
    return "\n".join(lines)


def write_report(
    result: DiagnoseResult,
    out: Path,
    dataset_name: str,
    horizon_s: float,
    planted: list[dict[str, Any]] | None = None,
) -> Path:
    """``out/report.md``: every iteration, what justified it, errors before and after."""
    L = [f"# Residual loop: {dataset_name}", ""]
    b, f = result.baseline_test, result.final_test
    L += [
        "Held-out (test split, never used for selection) errors of the declared model and of "
        "the final model; one-step: mean rod position error after one step; rollout: mean rod "
        f"position error after {horizon_s:g} s open-loop.",
        "",
        "| model | one-step | rollout |",
        "|---|---|---|",
        f"| declared | {fmt_err(b['one_step'])} | {fmt_err(b['rollout'])} |",
        f"| final: declared{''.join(' + ' + n for n in result.model.names)} | "
        f"{fmt_err(f['one_step'])} | {fmt_err(f['rollout'])} |",
        f"| improvement | {ratio(b['one_step'], f['one_step'])} | {ratio(b['rollout'], f['rollout'])} |",
        "",
    ]
    if planted is not None:
        names = [p.get("name") for p in planted] or ["nothing"]
        L += [
            f"Ground truth (read only for this report): planted {', '.join(map(str, names))}.",
            "",
        ]
    for k, it in enumerate(result.iterations):
        L += [f"## Iteration {k + 1}", ""]
        if it.plot is not None:
            L += [f"![residuals]({it.plot.name})", ""]
        L += ["Residual signatures of the current model (training split):", "",
              summary_table(it.residual), ""]  # fmt: skip
        L += [candidate_table(it.before, it.candidates), ""]
        if it.skipped:
            L += [
                "Not tried (gate not passed): "
                + "; ".join(f"{p.name}: {p.gate}" for p in it.skipped),
                "",
            ]
        if it.chosen is None:
            L += ["**No candidate passes: stop.**", ""]
            continue
        c = it.chosen
        L += [
            f"**Added: {c.name}** ({type(c.model.effects[-1]).summary if c.model.effects else ''})",
            "",
        ]
        if it.ambiguous is not None:
            L += [
                f"**Flag:** {c.name} cannot be told apart from {it.ambiguous[0]} on this data "
                f"(their predicted changes correlate {it.ambiguous[1]:.3f}); the attribution is "
                "uncertain.",
                "",
            ]
        added = next(e for e in c.model.effects if e.name == c.name)
        L += [effect_table(added), ""]
        if c.model.notes.get(c.name):
            L += [c.model.notes[c.name], ""]
        ta = it.test_after or {}
        L += [
            "| held-out (test) | before | after | improvement |",
            "|---|---|---|---|",
            f"| one-step | {fmt_err(it.test_before['one_step'])} | {fmt_err(ta.get('one_step', np.nan))} | "
            f"{ratio(it.test_before['one_step'], ta.get('one_step', np.nan))} |",
            f"| {horizon_s:g}-s rollout | {fmt_err(it.test_before['rollout'])} | {fmt_err(ta.get('rollout', np.nan))} | "
            f"{ratio(it.test_before['rollout'], ta.get('rollout', np.nan))} |",
            "",
        ]
    L += ["## Final residual", ""]
    if result.final_plot is not None:
        L += [f"![final residuals]({result.final_plot.name})", ""]
    L += [summary_table(result.final_residual), ""]
    L += [f"**Unexplained:** {result.unexplained}" if result.unexplained
          else "The residual left is noise (round-off or measurement noise).", ""]  # fmt: skip
    L += _network_section(result)
    return atomic_write_text(out / "report.md", "\n".join(L))


#: file names written beside ``params.json`` when a residual network absorbs the rest
NETWORK_PARAMS = "params_residual_network.json"


def _network_section(result: DiagnoseResult) -> list[str]:
    """Markdown lines about the residual network (none if there is none)."""
    fit = getattr(result, "residual_network", None)
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


def write_params(
    result: DiagnoseResult | NoisyDiagnoseResult, path: Path, extra: dict[str, Any]
) -> Path:
    """The extended params file: the model found (:meth:`Model.save`) and a ``diagnose`` section.

    With a residual network (``result.residual_network``), also writes its weights
    (sidecar, atomically) and ``params_residual_network.json`` beside ``path``: the
    declared parameters refitted with it and the effects, the network's entry
    included; ``params.json``'s ``diagnose.residual_network`` points at both.
    """
    doc = {
        "diagnose": {
            **extra,
            "added": [it.chosen.name for it in result.iterations if it.chosen is not None],
            "ambiguous": {
                it.chosen.name: {"with": it.ambiguous[0], "correlation": it.ambiguous[1]}
                for it in result.iterations
                if it.chosen is not None and it.ambiguous is not None
            },
            "test_errors_before": {k: v for k, v in result.baseline_test.items() if k != "curve"},
            "test_errors_after": {k: v for k, v in result.final_test.items() if k != "curve"},
            "unexplained": result.unexplained,
        },
    }
    fit = getattr(result, "residual_network", None)
    if fit is not None:
        directory = Path(path).parent
        fit.effect.save(directory)
        note = {"note": NOT_PHYSICAL, "params_file": NETWORK_PARAMS,
                "sidecar": fit.effect.sidecar, **fit.summary()}  # fmt: skip
        network_model = result.model.model.replace(params=fit.params, effects=fit.effects)
        network_doc = _jsonable({"residual_network": note})
        network_model.save(directory / NETWORK_PARAMS, network_doc)
        doc["diagnose"]["residual_network"] = note
    doc = _jsonable(doc)
    return result.model.model.save(path, doc)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x
