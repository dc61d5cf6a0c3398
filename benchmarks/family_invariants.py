"""The invariants a drawn plant's identification must meet, judged from the params file
``tensegrity-sr identify`` wrote and the plant's ground truth.

- From the exact true model (start ``truth``): the fit stays at the noise, an end-cap
  RMS of at most :data:`RMS_OVER_NOISE` times the plant's noise, and the parameters'
  moves from their true values, in their stated standard errors, have an RMS of at
  most :data:`MAX_SE_RMS` (honest standard errors give about 1). The largest move is
  reported, not judged: of N honest ones it grows like ``sqrt(2 ln N)`` (2.9 for the
  icosahedron's 89), so "none above 2" fails most honest fits.
- From the default start (``default``): masses, perpendicular inertias and stiffnesses
  within :data:`STRUCTURE_TOL`, spring damping and the floor contact's stiffness,
  damping and friction within :data:`DISSIPATION_TOL` (a contact parameter the command
  reports as not identifiable from the data is listed, not judged). Where the data's own
  standard errors are wider than these tolerances no start can meet them, so the fit is
  also judged as the truth's is (:func:`at_the_truth`): whether it ends where the data
  puts the truth, and the parameters' median relative standard error per group
  (:func:`relative_se`) is reported beside it. A fit written with its masses, inertias
  or stiffnesses off must carry ``identify``'s warning (:func:`silently_wrong`).

A miss is one line naming the stage (the plant, the command, or the invariant) and why.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from identification.trajectory.stage_check import POORLY_DETERMINED

#: the fit from the truth may end at most this far above the noise (RMS / noise)
RMS_OVER_NOISE = 1.2
#: and move the parameters by an RMS of at most this many of their stated standard
#: errors (1 where they are honest; 1.5 allows them to understate the error by a third)
MAX_SE_RMS = 1.5
#: relative tolerance of masses, inertias and stiffnesses from the default start
STRUCTURE_TOL = 0.03
#: relative tolerance of spring damping and floor contact from the default start
DISSIPATION_TOL = 0.10
#: parameter groups of the table (rest length reported, not judged)
GROUPS = ("mass", "inertia", "stiffness", "damping", "rest_length")
#: group -> tolerance from the default start
TOLERANCE = {"mass": STRUCTURE_TOL, "inertia": STRUCTURE_TOL, "stiffness": STRUCTURE_TOL,
             "damping": DISSIPATION_TOL, "contact": DISSIPATION_TOL}  # fmt: skip
#: floor contact parameters judged from the default start
CONTACT = ("stiffness", "damping", "friction")


def perpendicular(inertia: np.ndarray) -> np.ndarray:
    """Mask (R, 3) of the perpendicular principal moments: all but each rod's smallest
    (the axial one, assumed rather than identified)."""
    return inertia > inertia.min(axis=1, keepdims=True) * (1 + 1e-9)


def worst_errors(params: Mapping[str, Any], truth: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Largest relative error per group of :data:`GROUPS`; inertia: perpendicular moments."""
    out = {}
    for g in GROUPS:
        got, want = np.asarray(params[g], float), np.asarray(truth[g], float)
        if g == "inertia":
            keep = perpendicular(want)
            got, want = got[keep], want[keep]
        out[g] = float(np.max(np.abs(got / want - 1)))
    return out


def named_values(doc: Mapping[str, Any]) -> dict[str, tuple[str, tuple[int, ...]]]:
    """Parameter name as the params file's ``uncertainty`` spells it -> (group, index)."""
    rods = [r["name"] for r in doc["topology"]["rods"]]
    springs = [s["name"] for s in doc["topology"]["springs"]]
    out: dict[str, tuple[str, tuple[int, ...]]] = {}
    for r, name in enumerate(rods):
        out[f"mass[{name}]"] = ("mass", (r,))
        for k, ax in enumerate("xyz"):
            out[f"inertia[{name},{ax}]"] = ("inertia", (r, k))
    for group in ("stiffness", "damping", "rest_length"):
        for s, name in enumerate(springs):
            out[f"{group}[{name}]"] = (group, (s,))
    return out


def largest_move(
    doc: Mapping[str, Any], truth: Mapping[str, np.ndarray]
) -> tuple[str, float, float]:
    """The parameter moved furthest from its true value in its stated standard errors:
    (name, its |value - truth| / stderr, the RMS of that ratio over every parameter that
    states one: about 1 where the standard errors are honest); ("", 0, 0) when none does.

    With N honest standard errors the largest ratio grows like sqrt(2 ln N) (about 2.9
    for the icosahedron's 89), so the RMS is the check of the errors' honesty and the
    largest one is reported only."""
    names = named_values(doc)
    zs: dict[str, float] = {}
    for name, se in doc.get("uncertainty", {}).items():
        if name in names and se > 0:
            group, idx = names[name]
            got = float(np.asarray(doc["params"][group])[idx])
            zs[name] = abs(got - float(truth[group][idx])) / se
    if not zs:
        return ("", 0.0, 0.0)
    name = max(zs, key=lambda k: zs[k])
    return (name, zs[name], float(np.sqrt(np.mean(np.square(list(zs.values()))))))


def relative_se(doc: Mapping[str, Any]) -> dict[str, float]:
    """Median over each group's parameters of standard error / |value|, for the groups
    of :data:`GROUPS` whose parameters state one (what the data determines them to)."""
    names = named_values(doc)
    ratios: dict[str, list[float]] = {}
    for name, se in doc.get("uncertainty", {}).items():
        if name in names and se > 0:
            group, idx = names[name]
            value = abs(float(np.asarray(doc["params"][group])[idx]))
            if value > 0:
                ratios.setdefault(group, []).append(float(se) / value)
    return {g: float(np.median(ratios[g])) for g in GROUPS if g in ratios}


def at_the_truth(record: Mapping[str, Any]) -> str:
    """``""`` when a record's fit ends where the truth's own check asks (end-cap RMS at
    most :data:`RMS_OVER_NOISE` times the noise, the parameters' moves from the truth an
    RMS of at most :data:`MAX_SE_RMS` standard errors), else one line why."""
    run = record["identify"]
    if run["status"] != "ok":
        return f"identify ({run['status']})"
    ratio = record["rms_over_noise"]
    if not ratio <= RMS_OVER_NOISE:
        return f"end-cap RMS {ratio:.3g} x noise > {RMS_OVER_NOISE:g}"
    name, z, rms = (*record["moved"], float("nan"))[:3]
    if not rms <= MAX_SE_RMS:
        return (f"the parameters moved by an RMS of {rms:.3g} standard errors > {MAX_SE_RMS:g} "
                f"(largest: {name}, {z:.3g})")  # fmt: skip
    return ""


def warned(record: Mapping[str, Any]) -> bool:
    """Whether ``identify`` writes the record's fit with a warning: a mass, inertia,
    stiffness or rest length with a standard error of
    :data:`~identification.trajectory.stage_check.POORLY_DETERMINED` times its value or
    more (judged at the current limit from the record's ``worst_se_ratio``), or the floor
    fit's two starts ending apart (the record's ``two_starts``)."""
    poor = record.get("worst_se_ratio", 0.0) >= POORLY_DETERMINED
    apart = bool(record.get("two_starts", {}).get("apart", False))
    return record["identify"]["status"] == "ok" and (poor or apart)


def structure_error(record: Mapping[str, Any]) -> float:
    """The largest relative error of a record's masses, perpendicular inertias and
    stiffnesses (0 where it has none: nothing written; NaN where one is NaN)."""
    worst = record.get("worst", {})
    return float(np.max([worst.get(g, 0.0) for g in ("mass", "inertia", "stiffness")]))


def silently_wrong(record: Mapping[str, Any]) -> bool:
    """A fit written with a mass, inertia or stiffness off by more than
    :data:`STRUCTURE_TOL` and without the warning (:func:`warned`), which judges those
    groups (spring damping and contact it leaves alone: a weakly seen damping is legitimate)."""
    off = not structure_error(record) <= STRUCTURE_TOL
    return record["identify"]["status"] == "ok" and off and not warned(record)


def contact_errors(
    doc: Mapping[str, Any], truth_effects: list[dict[str, Any]]
) -> tuple[dict[str, float], dict[str, str]]:
    """Relative errors of the identified floor contact's :data:`CONTACT` parameters, and
    those the command reports as not identifiable (name -> its reason)."""
    want = next((e["params"] for e in truth_effects if e["name"] == "ground_contact"), None)
    if want is None:
        return {}, {}
    got = next((e["params"] for e in doc.get("effects", []) if e["name"] == "ground_contact"),
               None)  # fmt: skip
    unseen = {k.split(".", 1)[1]: why for k, why in
              doc.get("identifiability", {}).get("not_identifiable", {}).items()
              if k.startswith("ground_contact.")}  # fmt: skip
    if got is None:
        return {k: float("inf") for k in CONTACT}, unseen
    errs = {k: abs(float(got[k]) / float(want[k]) - 1) for k in CONTACT if k not in unseen}
    return errs, unseen


def verdict(record: Mapping[str, Any]) -> str:
    """``""`` when the record meets its start's invariants, else one line: the stage and
    why (``record`` as :func:`bench_family.run_plant` writes it)."""
    run = record["identify"]
    if run["status"] == "no data":
        return f"plant: {run['message']}"
    if run["status"] != "ok":
        return f"identify ({run['status']}): {run['message']}"
    if record["start"] == "truth":
        why = at_the_truth(record)
        return f"fit from the truth: {why}" if why else ""
    misses = [f"{g} {100 * e:.3g} %" for g, e in record["worst"].items()
              if g in TOLERANCE and not e <= TOLERANCE[g]]  # fmt: skip
    misses += [f"contact {k} {100 * e:.3g} %" for k, e in record.get("contact", {}).items()
               if not e <= DISSIPATION_TOL]  # fmt: skip
    if misses:
        return "fit from the default start: " + ", ".join(misses) + " off the truth"
    return ""
