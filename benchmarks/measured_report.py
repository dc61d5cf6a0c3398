"""Scoring of one measured-benchmark cell, and the Markdown table of all of them.

:func:`evaluate_cell` compares the params files ``identify`` and ``diagnose`` wrote
with the truth the plant simulated; :func:`write_markdown` renders the JSON that
``bench_measured.py`` accumulates.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shlex
import warnings
from pathlib import Path
from typing import Any

import measured_plant as plant
import numpy as np
import torch
from measured_plant import PLANT_VERSION, CellData, drop_states, simulate

from identification.commands.diagnose import WINDOW_S, WINDOWS
from identification.commands.durations import seconds
from identification.data.dataset import read_dataset
from identification.trajectory.end_cap_data import FINAL_FLOOR_WINDOWS, FLOOR_WINDOWS
from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import effects_from_document
from tensegrity_env.engine.state import State
from tensegrity_env.engine.step import Engine
from tensegrity_env.io_utils import InputError, atomic_write_text
from tensegrity_env.mjcf import from_mjcf
from tensegrity_env.mjcf_checks import FEATURES, IgnoredFeatureWarning
from tensegrity_env.params import params_from_dict
from tensegrity_env.rotations import quat_to_matrix

GROUPS = ("mass", "inertia", "stiffness", "damping", "rest_length")
#: the ground contact's parameters scored by relative error (the floor height: by distance)
CONTACT_KEYS = ("stiffness", "damping", "impedance", "friction")
#: the selection windows of cells that did not record theirs (``diagnose``'s default then)
OLD_SELECTION = {"window_s": 0.1, "windows": 8}
#: the floor fit's windows of floor cells that did not record theirs (fixed then)
OLD_FLOOR_WINDOWS = 8
HORIZON = 1.0
#: the floor cells' drop check: drops from rest, seconds each, passing within 2 cm
N_DROPS, DROP_SECONDS, DROP_TOLERANCE = 3, 2.0, 0.02


def unphysical(p: dict[str, np.ndarray]) -> list[str]:
    """What in a parameter set lies outside its physical domain (empty: nothing)."""
    bad = []
    for k in ("mass", "stiffness", "rest_length"):
        if not (np.isfinite(p[k]).all() and (p[k] > 0).all()):
            bad.append(f"{k} not positive and finite")
    if not (np.isfinite(p["damping"]).all() and (p["damping"] >= 0).all()):
        bad.append("damping negative or non-finite")
    inertia = p["inertia"]
    if not (np.isfinite(inertia).all() and (inertia > 0).all()):
        bad.append("inertia not positive and finite")
    else:
        s = inertia.sum(axis=-1, keepdims=True)
        if (2 * inertia > s * (1 + 1e-9)).any():
            bad.append("inertia violates the triangle inequality")
    return bad


def relative_errors(est: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> dict[str, Any]:
    """Max and median |relative error| per parameter group."""
    out = {}
    for g in GROUPS:
        e = np.abs(np.asarray(est[g], float) / truth[g] - 1.0).ravel()
        out[g] = {"max": float(np.max(e)), "median": float(np.median(e))}
    return out


def true_contact(data: CellData) -> dict[str, float]:
    """The plant's floor contact as :class:`~tensegrity_env.effects.GroundContact`
    parameters: read from its MJCF by :func:`~tensegrity_env.mjcf.from_mjcf` (MuJoCo's
    ``solref``/``solimp`` mapped as the engine reproduces them), the floor at ``z = 0``.
    The planted features (fluid drag, joint damping, ...) are ignored: only the contact
    is read here."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IgnoredFeatureWarning)
        asm = from_mjcf("<plant>", xml=data.truth.xml, ignore=tuple(FEATURES))
    return {**asm.contact, "height": 0.0}


def contact_errors(doc: dict[str, Any], truth: dict[str, float]) -> dict[str, float] | None:
    """|relative error| of the params file's ground contact per :data:`CONTACT_KEYS`, and
    ``height_mm``, the floor height's distance from the truth [mm]; None without contact."""
    found = [e for e in doc.get("effects", []) if e.get("name") == "ground_contact"]
    if not found:
        return None
    p = found[0]["params"]
    out = {k: float(abs(float(p[k]) / truth[k] - 1.0)) for k in CONTACT_KEYS}
    out["height_mm"] = float(abs(float(p["height"]) - truth["height"]) * 1e3)
    return out


def coverage_pairs(doc: dict[str, Any], truth: dict[str, np.ndarray], rods: list[str],
                   springs: list[str]) -> list[bool]:  # fmt: skip
    """Per parameter with a stated standard error: is the truth within 2 of them?"""
    hits = []
    for name, se in (doc.get("uncertainty") or {}).items():
        m = re.fullmatch(r"(\w+)\[(\w+)(?:,([xyz]))?\]", name)
        if m is None or m.group(1) not in GROUPS or not isinstance(se, (int, float)):
            continue
        g, el, ax = m.groups()
        idx: tuple[int, ...] = (
            (rods.index(el),) if g in ("mass", "inertia") else (springs.index(el),)
        )
        if ax is not None:
            idx = (*idx, "xyz".index(ax))
        est = np.asarray(doc["params"][g], float)[idx]
        hits.append(bool(abs(est - truth[g][idx]) <= 2 * se))
    return hits


def rollout_error(data: CellData, doc: dict[str, Any], path: Path) -> dict[str, Any]:
    """End-cap RMS error [m] of the params file's model over the clean test split's first second."""
    clean = read_dataset(data.clean)
    split = clean.split("test")
    steps = min(split.n_transitions, round(HORIZON / clean.dt))
    init = {k: getattr(split, k)[:, 0] for k in ("p", "v", "q", "omega")}
    return caps_error(data, doc, path, init, split.nodes, steps)


def drop_error(data: CellData, doc: dict[str, Any], path: Path) -> dict[str, Any]:
    """The 2-s drop check of a floor cell: :data:`N_DROPS` drops from rest simulated by the
    plant, the params file's model rolled out from the same states; end-cap RMS error [m]
    per sample (``mean`` over the 2 s, ``worst`` sample, ``final``)."""
    init = drop_states(N_DROPS, np.random.default_rng([data.cell.seed, 29]))
    drops = simulate(data.cell, data.truth, init, DROP_SECONDS)
    steps = drops.nodes.shape[1] - 1
    return caps_error(data, doc, path, init, drops.nodes, steps)


def caps_error(
    data: CellData,
    doc: dict[str, Any],
    path: Path,
    init: dict[str, np.ndarray],
    nodes: np.ndarray,
    steps: int,
) -> dict[str, Any]:
    """End-cap RMS error [m] per sample of the params file's model rolled out open-loop
    from rod states ``init`` (n, R, ·) against clean end caps ``nodes`` (n, >= steps+1,
    2R, 3), at the cell's physics step."""
    topo, dt, n_sub = icosahedron().topology, 1.0 / data.cell.rate, data.cell.substeps
    params = params_from_dict(doc["params"])
    engine = Engine(topo, dt / n_sub, effects_from_document(doc, topo, root=path.parent))
    state = State(*(torch.as_tensor(init[k]) for k in ("p", "v", "q", "omega")))
    offsets = torch.as_tensor(topo.end_offsets)
    rms = [0.0]
    with torch.no_grad():
        for t in range(1, steps + 1):
            for _ in range(n_sub):
                state = engine.step(state, params)
            caps = state.p[:, :, None] + torch.einsum("brij,rkj->brki", quat_to_matrix(state.q),
                                                      offsets)  # fmt: skip
            diff = caps.reshape(caps.shape[0], -1, 3).numpy() - nodes[:, t]
            e = float(np.sqrt(np.mean(np.sum(diff**2, -1))))
            rms.append(e if math.isfinite(e) else math.inf)
            if not math.isfinite(e) or e > 10.0:
                return {"diverged_at_s": t * dt, "mean": math.inf, "final": math.inf,
                        "worst": math.inf}  # fmt: skip
    return {"mean": float(np.mean(rms)), "final": rms[-1], "worst": float(np.max(rms)),
            "seconds": steps * dt}  # fmt: skip


def score_params(data: CellData, path: Path) -> dict[str, Any]:
    """Errors, physical checks, rollout and coverage of one params file."""
    if not path.is_file():
        return {"written": False}
    doc = json.loads(path.read_text())
    truth = data.truth.params.numpy()
    est = {k: np.asarray(v, float) for k, v in doc["params"].items()}
    topo = read_dataset(data.clean).topology
    out: dict[str, Any] = {"written": True, "unphysical": unphysical(est)}
    try:  # each effect's own domain (drag >= 0, contact in range, ...), as a user loads it
        effects_from_document(doc, topo, root=path.parent)
    except InputError as e:
        out["unphysical"].append(f"effect refused: {e}")
    out["errors"] = relative_errors(est, truth)
    out["effects"] = [e.get("name") for e in doc.get("effects", [])]
    out["coverage"] = coverage_pairs(doc, truth, [r.name for r in topo.rods],
                                     [s.name for s in topo.springs])  # fmt: skip
    checks = {"rollout": rollout_error}
    if data.cell.setting == "floor":
        checks["drop"] = drop_error
        out["contact"] = contact_errors(doc, true_contact(data))
    for key, check in checks.items():
        try:
            out[key] = check(data, doc, path)
        except Exception as e:  # the model file itself is the result under test
            out[key] = {"error": f"{type(e).__name__}: {e}"}
    return out


def evaluate_cell(data: CellData, identify: Path, diagnose: Path) -> dict[str, Any]:
    """The scores of ``identify``'s ("before") and ``diagnose``'s ("after") params files."""
    before, after = score_params(data, identify), score_params(data, diagnose)
    named = after.get("effects") if after.get("written") else None
    rec: dict[str, Any] = {"before": before, "after": after, "named": named}
    if named is not None:
        exp = set(data.cell.expected)
        rec["false_discoveries"] = sorted(set(named) - exp)
        rec["missed"] = sorted(exp - set(named))
        rec["named_right"] = set(named) == exp
    return rec


# ------------------------------------------------------------------ markdown
def coverage_section(cells: dict[str, Any]) -> list[str]:
    """Per seed, the fraction of true parameters within 2 stated standard errors (identify)."""
    rows = []
    for label, r in sorted(cells.items(), key=lambda kv: (kv[1]["cell"]["setting"],
                                                          kv[1]["cell"]["effect"],
                                                          kv[1]["cell"]["seed"])):  # fmt: skip
        hits = r["before"].get("coverage", [])
        if hits:
            rows.append((label, r, hits))
    if not rows:
        return []
    every = [h for _, _, hs in rows for h in hs]
    lines = ["", "## Standard errors: 2-sigma coverage (`identify`)", "",
             "The fraction of true parameters (masses, inertias, stiffness, damping, rest",
             "lengths) within two standard errors stated in `identify`'s params file "
             "(the window-clustered sandwich or Gauss-Newton, whichever is larger), per cell;",
             "cells with `diagnose` skipped come from runs with `--identify-only`: the seeds",
             "and the other rates, noise levels and dropouts of the control cell from", "",
             "    OMP_NUM_THREADS=1 nice -n 10 python benchmarks/bench_measured.py --settings flight \\",
             "        --effects none --seeds 10 --seed0 1 --identify-only",
             "    python benchmarks/bench_measured.py --settings flight --effects none --identify-only \\",
             "        --rates 60,240,1000   # and: --noise 0.5; --noise 2; --dropout 2", "",
             f"Overall: **{100 * np.mean(every):.1f} %** of {len(every)} parameters over "
             f"{len(rows)} cells.", *coverage_by_model(cells), "",
             "| cell | parameters | coverage | largest relative error | 1-s rollout [mm] |",
             "| --- | --- | --- | --- | --- |"]  # fmt: skip
    for label, r, hits in rows:
        errs = r["before"].get("errors", {})
        worst = max(errs, key=lambda g: errs[g]["max"]) if errs else None
        text = "-" if worst is None else f"{worst} {100 * errs[worst]['max']:.2g} %"
        roll = _mm(r["before"].get("rollout", {}).get("mean"))
        lines.append(f"| {label}{stale(r)} | {len(hits)} | {100 * np.mean(hits):.1f} % | {text} "
                     f"| {roll} |")  # fmt: skip
    return lines


def coverage_by_model(cells: dict[str, Any]) -> list[str]:
    """Coverage split by whether the fitted model holds the plant: a standard error bounds
    the scatter of a fit, not the bias of a model that lacks the planted effect."""
    groups: dict[tuple[str, str, str], list[bool]] = {}
    for r in cells.values():
        setting = r["cell"]["setting"]
        complete = not set(r["expected"]) - {"ground_contact"}
        key = (setting, "`identify`", "the declared model" + (" (and contact)" if setting ==
               "floor" else "") + (" holds the plant" if complete else " lacks the planted effect"))
        groups.setdefault(key, []).extend(r["before"].get("coverage", []))
        if r.get("named") is not None:
            right = "the effects named right" if r.get("named_right") else "an effect missed"
            groups.setdefault((setting, "`diagnose`", right), []).extend(
                r["after"].get("coverage", []))
    rows = [f"| {s} | {fit} | {model} | {len(h)} | {100 * np.mean(h):.1f} % |"
            for (s, fit, model), h in sorted(groups.items()) if h]  # fmt: skip
    if not rows:
        return []
    return ["", "By the model fitted: a standard error bounds the scatter of a fit, not the "
            "bias of a model that lacks the planted effect (`identify` on a plant with an "
            "effect the declared model does not have: its parameters absorb the effect).", "",
            "| setting | fit | model | parameters | coverage |", "| --- | --- | --- | --- | --- |",
            *rows]  # fmt: skip


def floor_section(cells: dict[str, Any]) -> list[str]:
    """The floor cells' checks: 1-s rolling (the clean test trajectories) and 2-s drops,
    for the identified models and for models within the targets (``reference``)."""
    floor = [(label, r) for label, r in sorted(cells.items()) if r["cell"]["setting"] == "floor"]
    if not any(r[k].get("drop") for _, r in floor for k in ("before", "after")):
        return []
    lines = ["", "## Floor checks", "",
             f"Rolling: the clean test trajectories (tumbling and rolling on the floor), end-cap "
             f"RMS error over the first second, mean and at 1 s. Drop: {N_DROPS} drops from "
             f"rest, 0.1-0.5 m above the floor, simulated by the plant for {DROP_SECONDS:g} s; "
             f"the worst end-cap RMS error over the samples, passing below "
             f"{DROP_TOLERANCE * 100:g} cm. Model: `identify` (before) or `diagnose` (after).", "",
             "Rows *within targets* read these numbers: the same checks for models drawn "
             "around the truth with every parameter off by a uniform relative error up to the "
             "identification targets (masses, inertias, stiffnesses 3 %; spring damping, "
             "contact stiffness, damping and friction 10 %; `benchmarks/measured_tolerance.py`), "
             "median over the draws and how many pass the drop check. Rollouts through impacts "
             "diverge fast: a model within those targets can miss the drop check by decimetres.",
             "", "| cell | model | rolling mean [mm] | rolling at 1 s [mm] | drop worst [mm] "
             "| drop passes |",
             "| --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for label, r in floor:
        for k, model in (("before", "identify"), ("after", "diagnose")):
            rec = r[k]
            if not rec.get("drop"):
                continue
            roll, worst = rec.get("rollout", {}), rec["drop"].get("worst")
            ok = "-" if worst is None else ("yes" if worst < DROP_TOLERANCE else "no")
            lines.append(f"| {label} | {model} | {_mm(roll.get('mean'))} "
                         f"| {_mm(roll.get('final'))} | {_mm(worst)} | {ok} |")  # fmt: skip
        ref = r.get("reference")
        if ref:
            lines.append(f"| {label} | within targets (median of {ref['models']}) "
                         f"| {_mm(ref['rolling_median'])} | - | {_mm(ref['drop_median'])} "
                         f"| {ref['drop_passes']} of {ref['models']} |")  # fmt: skip
    return lines


def contact_section(cells: dict[str, Any]) -> list[str]:
    """The floor cells' ground-contact parameters against the plant's (``contact``)."""
    rows = []
    for label, r in sorted(cells.items()):
        for k, model in (("before", "identify"), ("after", "diagnose")):
            c = r.get(k, {}).get("contact")
            if c:
                rows.append(f"| {label} | {model} | "
                            + " | ".join(f"{100 * c[key]:.3g}" for key in CONTACT_KEYS)
                            + f" | {c['height_mm']:.3g} |")  # fmt: skip
    if not rows:
        return []
    head = " | ".join(f"{key} [%]" for key in CONTACT_KEYS)
    return ["", "## Contact parameters", "",
            "The identified ground contact against the plant's (MuJoCo's default soft contact "
            "read from the plant's MJCF as the engine's parameters: stiffness and damping per "
            "unit effective mass, impedance, friction; the floor at z = 0): |relative error| "
            "[%], and the floor height's distance [mm]. Cells scored before the contact was "
            "recorded are not listed; `--rescore --workdir DIR` scores kept cells again.", "",
            f"| cell | model | {head} | height [mm] |",
            "| --- | --- | " + "--- | " * len(CONTACT_KEYS) + "--- |", *rows]  # fmt: skip


def selection(diagnose_args: str) -> dict[str, float]:
    """The selection windows ``diagnose`` runs with given extra options ``diagnose_args``:
    ``window_s`` (length [s]) and ``windows`` (random windows per split)."""
    ap = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    ap.add_argument("--window", type=seconds, default=WINDOW_S)
    ap.add_argument("--windows", type=int, default=WINDOWS)
    known, _ = ap.parse_known_args(shlex.split(diagnose_args))
    return {"window_s": known.window, "windows": known.windows}


def floor_windows(identify_args: str, diagnose_args: str) -> dict[str, float]:
    """The windows of the floor fit of ``identify`` and ``diagnose`` and of the final
    refit of ``diagnose`` (``diagnose_final``, and its window length
    ``diagnose_final_window_s`` where one is given), given their extra options."""
    ap = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    ap.add_argument("--floor-windows", type=int, default=FLOOR_WINDOWS)
    ap.add_argument("--final-floor-windows", type=int, default=FINAL_FLOOR_WINDOWS)
    ap.add_argument("--final-floor-window", type=seconds, default=0.0)
    ident = ap.parse_known_args(shlex.split(identify_args))[0]
    diag = ap.parse_known_args(shlex.split(diagnose_args))[0]
    out = {"identify": ident.floor_windows, "diagnose": diag.floor_windows,
           "diagnose_final": diag.final_floor_windows}  # fmt: skip
    if diag.final_floor_window > 0:
        out["diagnose_final_window_s"] = diag.final_floor_window
    return out


def floor_windows_text(r: dict[str, Any]) -> str:
    """A floor cell's floor-fit windows in ``identify`` / ``diagnose``, and the final
    refit's where it has more (``"8 / 8 → 24"``; :data:`OLD_FLOOR_WINDOWS` and no
    final refit where unrecorded), ``"-"`` in free flight."""
    if r["cell"]["setting"] != "floor":
        return "-"
    fw = r.get("floor_windows") or {}
    ident = fw.get("identify", OLD_FLOOR_WINDOWS)
    if r["diagnose"]["status"] == "skipped":
        return str(ident)
    diag = fw.get("diagnose", OLD_FLOOR_WINDOWS)
    final = fw.get("diagnose_final", 0)
    length = fw.get("diagnose_final_window_s")
    final_text = f" → {final}" + (f" x {length:g} s" if length else "")
    return f"{ident} / {diag}" + (final_text if final > diag else "")


def selection_text(r: dict[str, Any]) -> str:
    """``"8 x 0.2 s"``: a cell's selection windows (:data:`OLD_SELECTION` if unrecorded)."""
    sel = r.get("selection") or OLD_SELECTION
    return f"{sel['windows']} x {sel['window_s']:g} s"


def stale(r: dict[str, Any]) -> str:
    """`` †`` for a cell measured with an older plant (see :data:`STALE_NOTE`), else ``""``."""
    return " †" if r.get("plant_version", 1) < PLANT_VERSION else ""


def marks(r: dict[str, Any]) -> str:
    """:func:`stale`'s mark, and `` ‡`` for a diagnosis selected on other windows than
    ``diagnose``'s default (:func:`other_note`)."""
    default = {"window_s": WINDOW_S, "windows": WINDOWS}
    other = (
        r["diagnose"]["status"] != "skipped" and (r.get("selection") or OLD_SELECTION) != default
    )
    return stale(r) + (" ‡" if other else "")


def other_note() -> str:
    """The footnote of cells marked ``‡`` by :func:`stale`."""
    return (f"‡ candidates selected on other windows than `diagnose`'s default "
            f"({WINDOWS} x {WINDOW_S:g} s per split; column `selection`).")  # fmt: skip


#: the footnote of cells marked by :func:`stale`
STALE_NOTE = ("† measured with the plant's first version, whose end caps lagged its rod states "
              "by one physics step (about 1 ms), which adds millimetres to the rollout errors "
              "(the control cell's `identify` at 120 Hz: 4.8-5.7 mm over seeds 0-10 with it, "
              "0.13-0.24 mm over seeds 1-10 without).")  # fmt: skip


def _mm(x: Any) -> str:
    if not isinstance(x, (int, float)):
        return "-"
    return "diverged" if not math.isfinite(x) else f"{x * 1e3:.1f}"


def _pct(rec: dict[str, Any], group: str) -> str:
    e = rec.get("errors", {}).get(group)
    return "-" if e is None else f"{e['max'] * 100:.3g}"


def _status(run: dict[str, Any]) -> str:
    if run["status"] == "ok":
        cpu = run.get("cpu_seconds")  # (recorded from a later version of the script on)
        return f"ok {run['seconds']:.0f} s" + ("" if cpu is None else f" ({cpu:.0f} s CPU)")
    msg = run["message"].replace("|", "/")[:90]
    return f"{run['status']}: {msg}"


def matrix_section(cells: dict[str, Any]) -> list[str]:
    """How much of the whole matrix has been run: per setting and planted effect, the
    (rate, noise, dropout) combinations with at least one cell, and any crash among them."""
    combos = len(plant.RATES) * len(plant.NOISES) * len(plant.DROPOUTS)
    total = len(plant.SETTINGS) * len(plant.PLANTED) * combos
    ran: dict[tuple[str, str], set[tuple[float, float, float]]] = {}
    crashed: dict[tuple[str, str], int] = {}
    for r in cells.values():
        c = r["cell"]
        key = (c["setting"], c["effect"])
        ran.setdefault(key, set()).add((c["rate"], c["noise"], c["dropout"]))
        crashed[key] = crashed.get(key, 0) + sum(
            r[cmd]["status"] == "crash" for cmd in ("identify", "diagnose")
        )
    done = sum(len(v) for v in ran.values())
    lines = [
        "", "## The whole matrix", "",
        f"{len(plant.SETTINGS)} settings x {len(plant.RATES)} rates x {len(plant.NOISES)} noise levels x "
        f"{len(plant.DROPOUTS)} dropout rates x {len(plant.PLANTED)} planted effects = {total} "
        f"combinations; **{done} run** (any seed), with a crash in "
        f"{sum(crashed.values())} runs. More of it, drawn at random among the combinations "
        "not yet run, in two processes (each `--json` starts as a copy of `measured.json`, "
        "so cells already run are skipped; the new cells are copied back):", "",
        "    OMP_NUM_THREADS=1 python benchmarks/bench_measured.py --all --identify-only \\",
        "        --sample 24 --sample-seed 28 --shard K/2 --json sweepK.json   # K = 0, 1",
        "",
        "| setting | planted | combinations run | with diagnose | crashes |",
        "| --- | --- | --- | --- | --- |",
    ]  # fmt: skip
    for setting in plant.SETTINGS:
        for effect in plant.PLANTED:
            key = (setting, effect)
            diag = {(r["cell"]["rate"], r["cell"]["noise"], r["cell"]["dropout"])
                    for r in cells.values() if (r["cell"]["setting"], r["cell"]["effect"]) == key
                    and r["diagnose"]["status"] != "skipped"}  # fmt: skip
            lines.append(f"| {setting} | {effect} | {len(ran.get(key, ()))} of {combos} "
                         f"| {len(diag)} | {crashed.get(key, 0)} |")  # fmt: skip
    return lines


def is_default(cell: dict[str, Any]) -> bool:
    """Whether a cell is at the committed rate, noise and dropout (120 Hz, 1 mm, none)."""
    return cell["rate"] == 120 and abs(cell["noise"] - 1e-3) < 1e-12 and cell["dropout"] == 0


def diagnosis_rows(cells: dict[str, Any], default: bool) -> list[str]:
    """Table rows of the cells that ran ``diagnose``: at 120 Hz / 1 mm / no dropouts
    (``default``: one column per axis of the cell) or elsewhere (the cell's label)."""
    lines = []
    for _label, r in sorted(cells.items()):
        c = r["cell"]
        if is_default(c) != default or r["diagnose"]["status"] == "skipped":
            continue
        a, b = r["after"], r["before"]
        unphys = sorted(set(a.get("unphysical", [])) | set(b.get("unphysical", [])))
        named = "-" if r["named"] is None else ", ".join(r["named"]) or "nothing"
        expected = ", ".join(r["expected"]) or "-"
        if default:
            head = (f"| {c['setting']}{marks(r)} | {c['effect']} | {c['seed']} | {expected} "
                    f"| {named} | {selection_text(r)} | {floor_windows_text(r)} ")  # fmt: skip
        else:
            head = f"| {c['label']}{marks(r)} | {expected} | {named} "
        lines.append(
            head + f"| {_status(r['identify'])} | {_status(r['diagnose'])} "
            f"| {_pct(a, 'mass')} | {_pct(a, 'inertia')} | {_pct(a, 'stiffness')} "
            f"| {_pct(a, 'damping')} | {_mm(b.get('rollout', {}).get('mean'))} "
            f"| {_mm(a.get('rollout', {}).get('mean'))} | {'; '.join(unphys) or 'none'} |"
        )
    return lines


def write_markdown(results: dict[str, Any], path: Path) -> Path:
    """``docs/results/measured.md``: the 120 Hz / 1 mm rows and a summary of every cell."""
    cells = results.get("cells", {})
    lines = [
        "# The closed loop on measured data",
        "",
        "Generated by `benchmarks/bench_measured.py` from `measured.json` (do not edit).",
        "Data: the icosahedron simulated by the benchmark's own MuJoCo script",
        "(`benchmarks/measured_plant.py`), end caps only with Gaussian noise; `identify` and",
        "`diagnose` run through the CLI with one weighed rod (`--anchor mass[rod0]=...`).",
        "Errors: max |relative error| per group [%]; rollout: end-cap RMS error [mm] over the",
        "first second of the clean test trajectories from their true initial states, mean over",
        "that second, of the declared model (`identify`, before) and the diagnosed one (after).",
        "`identify`, `diagnose`: how each command ended and its wall time, with its CPU time",
        "(user + system, worker processes included; recorded for cells run since it was",
        "added) in brackets: the wall time depends on the machine's load, the CPU time little.",
        "",
        "    OMP_NUM_THREADS=1 nice -n 10 python benchmarks/bench_measured.py",
        "",
        "## 120 Hz, 1 mm noise, no dropouts",
        "",
        "`floor fit`: the windows of the joint fit of the declared model and contact on floor",
        "data, in `identify` / `diagnose` (`--floor-windows`), and after the arrow those of",
        "`diagnose`'s final refit of the selected model (`--final-floor-windows`).",
        "",
        "| setting | planted | seed | expected | named | selection | floor fit | identify "
        "| diagnose | M | I | K | c | rollout before | rollout after | unphysical written |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- "
        "| --- | --- |",
    ]
    lines += diagnosis_rows(cells, default=True)
    lines += [
        "", "## Other rates, noise levels and dropouts", "",
        "The cells of the rest of the matrix that ran `diagnose`; columns as above.", "",
        "| cell | expected | named | identify | diagnose | M | I | K | c | rollout before "
        "| rollout after | unphysical written |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]  # fmt: skip
    lines += diagnosis_rows(cells, default=False)
    lines += floor_section(cells)
    lines += contact_section(cells)
    lines += coverage_section(cells)
    lines += matrix_section(cells)
    lines += ["", "## Every cell run", ""]
    runs = list(cells.values())
    if runs:
        for cmd in ("identify", "diagnose"):
            counts: dict[str, int] = {}
            for r in runs:
                counts[r[cmd]["status"]] = counts.get(r[cmd]["status"], 0) + 1
            lines.append(f"- `{cmd}`: " + ", ".join(f"{v} {k}" for k, v in sorted(counts.items()))
                         + f" of {len(runs)} cells")  # fmt: skip
        named = [r for r in runs if r.get("named") is not None]
        right = sum(bool(r.get("named_right")) for r in named)
        lines.append(f"- effects named right: {right} of {len(named)} cells with a diagnosis")
        hits = [h for r in runs for k in ("before", "after") for h in r[k].get("coverage", [])]
        if hits:
            lines.append(f"- 2-sigma coverage of stated standard errors: "
                         f"{100 * np.mean(hits):.1f} % of {len(hits)} parameters")  # fmt: skip
        unphys = sum(bool(r[k].get("unphysical")) for r in runs for k in ("before", "after"))
        lines.append(f"- params files with an unphysical value: {unphys}")
        lines += ["", "| cell | identify | diagnose | named |", "| --- | --- | --- | --- |"]
        for label, r in sorted(cells.items()):
            nm = "-" if r["named"] is None else ", ".join(r["named"]) or "nothing"
            lines.append(
                f"| {label}{marks(r)} | {_status(r['identify'])} | {_status(r['diagnose'])} | {nm} |"
            )
    if any(stale(r) for r in cells.values()):
        lines += ["", STALE_NOTE]
    if any("‡" in marks(r) for r in cells.values()):
        lines += ["", other_note()]
    return atomic_write_text(path, "\n".join(lines) + "\n")
