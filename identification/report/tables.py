"""Tables of identified parameters, with units, uncertainty and (where known) error vs truth."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from identification.linear.regression import ParameterRow
from tensegrity_env.params import Params


def error_text(x: float, spec: str = ".3g", unit: str = "m", scale: float = 1.0) -> str:
    """An error for consoles and reports alike: ``x * scale`` formatted by ``spec`` with
    ``unit``, or ``diverged`` where the rollout it measures diverged (NaN or inf)."""
    return f"{x * scale:{spec}} {unit}" if np.isfinite(x) else "diverged"


def truth_value(row: ParameterRow, truth: Params, scale: float = 1.0) -> float:
    """The true value of a table row (divided by ``scale`` for ratio results); NaN for
    ``K·v`` of a winch (compared through its ``winch_speed`` row)."""
    t = truth.numpy()
    el = max(row.element, 0)
    if row.group == "stiffness_winch_speed":
        return float("nan")
    if row.group == "stiffness_rest":
        value = t["stiffness"][el] * t["rest_length"][el]
    elif row.group == "inertia":
        value = np.ravel(t["inertia"])[el]
    else:
        value = np.ravel(t[row.group])[el]
    scale_free = row.group in ("rest_length", "winch_speed", "winch_lag", "winch_min", "winch_max")
    return float(value) if scale_free else float(value) / scale


def relative_errors(
    rows: Sequence[ParameterRow], truth: Params | None, ratios: bool = False
) -> list[float]:
    """|value - truth| / |truth| per row (NaN without truth or for unidentifiable rows)."""
    if truth is None:
        return [float("nan")] * len(rows)
    scale = float(truth.mass[0]) if ratios else 1.0
    out = []
    for r in rows:
        if r.status == "not identifiable":
            out.append(float("nan"))
            continue
        tv = truth_value(r, truth, scale)
        out.append(abs(r.value - tv) / abs(tv) if tv != 0 else abs(r.value))
    return out


def _fmt(x: float) -> str:
    return "—" if not np.isfinite(x) else f"{x:.6g}"


def parameter_table(
    rows: Sequence[ParameterRow],
    truth: Params | None = None,
    ratios: bool = False,
    markdown: bool = False,
) -> str:
    """Aligned text (or markdown) table: name, value, ±stderr, unit, status, rel. error."""
    errs = relative_errors(rows, truth, ratios)
    header = ["parameter", "value", "± std err", "unit", "status"] + (
        ["rel. error"] if truth else []
    )
    lines = []
    for r, e in zip(rows, errs, strict=True):
        if r.group == "stiffness_rest":  # internal unknown K*l0; its l0 row is shown instead
            continue
        status = r.status + (f" ({r.note})" if r.note else "")
        value = _fmt(r.value) if r.status != "not identifiable" or np.isfinite(r.value) else "—"
        if r.status == "not identifiable":
            value = f"[{value} assumed]" if np.isfinite(r.value) else "—"
        stderr = _fmt(r.stderr)
        cells = [r.name, value, stderr, r.unit, status]
        if truth is not None:
            cells.append("—" if not np.isfinite(e) else f"{e:.2e}")
        lines.append(cells)
    if markdown:
        out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        out += ["| " + " | ".join(c) + " |" for c in lines]
        return "\n".join(out)
    widths = [max(len(h), *(len(c[i]) for c in lines)) for i, h in enumerate(header)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return "\n".join(
        [fmt.format(*header), fmt.format(*("-" * w for w in widths))]
        + [fmt.format(*c) for c in lines]
    )


def group_errors(
    rows: Sequence[ParameterRow], truth: Params, ratios: bool = False
) -> dict[str, float]:
    """Largest relative error per parameter group over identified rows."""
    out: dict[str, float] = {}
    for r, e in zip(rows, relative_errors(rows, truth, ratios), strict=True):
        if np.isfinite(e) and r.status in ("identified", "ratio"):
            out[r.group] = max(out.get(r.group, 0.0), e)
    return out
