"""Tension-only springs the data holds nothing of: slack throughout the fitted data.

A tension-only spring (a declared model's ``slack_springs``, e.g. an NTRT cable) that is
never as long as its rest length pulls on nothing, so the data fixes none of its
stiffness, damping or rest length. Two ways it happens:

* slack at the declared model: the fit has nothing to move, and whatever it drifted to
  is replaced by the declared values;
* slack at the fit: the fit lengthened the rest length past every measured length (to
  its bound, kilometres for a robot of decimetres) because the data is better explained
  without the spring. What the data supports is a lower bound: the rest length is
  written as the spring's longest length anywhere in the recording (every split, so
  that the written model stays slack wherever the fitted one was), and its stiffness
  and damping keep the declared values.

Either way the written model pulls on nothing on the recorded motion where the fit's
model pulled on nothing, and nothing unphysical is written.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import torch

from tensegrity_env.effects import SlackSprings
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology

#: the note of a spring slack at the declared model
SLACK_AT_START = ("a tension-only spring slack throughout the data (never as long as its rest "
                  "length): the declared value is kept")  # fmt: skip


def longest_lengths(
    nodes: np.ndarray | Sequence[np.ndarray], topology: Topology, springs: list[int]
) -> np.ndarray:
    """(len(springs),) [m]: each spring's longest measured length in ``nodes`` (N, T, 2R, 3)
    [m] or a sequence of such arrays, gaps ignored (NaN where a spring is never seen or
    does not join two end caps)."""
    caps = 2 * topology.n_rods
    out = np.full(len(springs), np.nan)
    for i, s in enumerate(springs):
        a, b = topology.spring_nodes[s]
        if max(a, b) >= caps:
            continue
        for part in [nodes] if isinstance(nodes, np.ndarray) else nodes:
            length = np.linalg.norm(part[..., a, :] - part[..., b, :], axis=-1)
            length = length[np.isfinite(length)]
            if length.size:
                out[i] = np.fmax(out[i], length.max())
    return out


def never_taut(
    nodes: np.ndarray, topology: Topology, effects: list[PhysicalEffect], rest_length: np.ndarray
) -> list[int]:
    """The tension-only springs of ``effects`` (a declared model's ``slack_springs``)
    between two end caps whose measured length in ``nodes`` (N, T, 2R, 3) [m] never
    reaches ``rest_length`` (S,) [m]: slack throughout, they pull on nothing, so the data
    holds nothing of their stiffness, damping or rest length."""
    # narrowing to the class: only tension-only springs can be slack throughout
    slack = [
        int(s) for e in effects if isinstance(e, SlackSprings) for s in e.values["springs"].tolist()
    ]
    longest = longest_lengths(nodes, topology, slack)
    return [s for s, m in zip(slack, longest, strict=True) if np.isfinite(m) and m < rest_length[s]]


def settle_slack(
    params: Params,
    declared: Params,
    nodes: np.ndarray,
    topology: Topology,
    effects: list[PhysicalEffect],
    recorded: Sequence[np.ndarray] = (),
) -> tuple[Params, dict[str, str]]:
    """``params`` (fitted) with the tension-only springs slack throughout ``nodes``
    (N, T, 2R, 3) [m], the fitted data, settled, and a note per changed parameter name
    (e.g. ``rest_length[cable1]``) saying why.

    Springs slack at ``declared``'s rest lengths keep all three declared values; springs
    slack only at the fitted rest lengths get their longest length in ``nodes`` and
    ``recorded`` (the recording's other splits, each (N, T, 2R, 3) [m]) as rest length
    (m) and the declared stiffness (N/m) and damping (N*s/m).
    """
    values = {k: getattr(params, k).clone() for k in ("stiffness", "damping", "rest_length")}
    notes: dict[str, str] = {}
    at_start = never_taut(nodes, topology, effects, declared.rest_length.numpy())
    at_fit = [s for s in never_taut(nodes, topology, effects, params.rest_length.numpy())
              if s not in at_start]  # fmt: skip
    for s in at_start + at_fit:
        for k, v in values.items():
            v[s] = getattr(declared, k)[s]
    longest = longest_lengths([nodes, *recorded], topology, at_fit)
    for s, m in zip(at_fit, longest, strict=True):
        values["rest_length"][s] = torch.as_tensor(m, dtype=values["rest_length"].dtype)
    for s in at_start:
        for k in values:
            notes[f"{k}[{topology.springs[s].name}]"] = SLACK_AT_START
    for s, m in zip(at_fit, longest, strict=True):
        name = topology.springs[s].name
        fitted = float(params.rest_length[s])
        notes[f"rest_length[{name}]"] = (
            f"a tension-only spring slack throughout the data at the fit (rest length fitted "
            f"to {fitted:.4g} m, never reached): written as its longest length in the "
            f"recording, "
            f"{m:.4g} m, a lower bound")  # fmt: skip
        for k in ("stiffness", "damping"):
            notes[f"{k}[{name}]"] = ("a tension-only spring slack throughout the data at the "
                                     "fit: the declared value is kept")  # fmt: skip
    return replace(params, **values), notes


def spring_names(notes: dict[str, str]) -> list[str]:
    """The springs named in :func:`settle_slack`'s notes (``rest_length[cable1]`` ->
    ``cable1``), sorted."""
    return sorted({name.partition("[")[2][:-1] for name in notes})
