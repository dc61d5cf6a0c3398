"""Is a candidate effect negligible? The force it adds on the rods, against their weight.

A fit can give an effect a small, "significant" value that is an artefact of the
model (an integration scheme, a bias of the noise) rather than physics: 3.9 mN of
"force field" on 2 kg rods is 0.02 % of their weight. :func:`force_ratio` measures
what a candidate changes in the forces on the rods over sampled states of the data:
per rod and sample ``|ΔF| + |Δτ| / (L/2)`` (the torque as a force at the rod's end),
its RMS divided by the rod's weight ``M |g|``. A candidate below :data:`NEGLIGIBLE`
is reported as negligible and not added
(:func:`~identification.discovery.judge.judge`). :func:`group_power` is the energy a
part of an effect adds per second: a drag that adds energy is not drag.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch

from identification.trajectory.fitted_model import FittedModel
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import PHYSICS_DT, Engine, State
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology

#: an effect whose forces on the rods are below this fraction of their weight is negligible
NEGLIGIBLE = 1e-3
#: a drag part's mean power below this fraction of the rods' weight times their speed
#: [W] is round-off (a part at 0 comes out at ~1e-17 of it beside other effects)
ROUND_OFF_POWER = 1e-12


def force_change(
    topology: Topology,
    params: Params,
    effects: Sequence[PhysicalEffect],
    reference: Sequence[PhysicalEffect],
    states: State,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What ``effects`` change in the forces on the rods against ``reference`` at
    ``states``, both with the same declared ``params``.

    Returns:
        ΔF (B, R, 3) [N] in the world frame, Δτ (B, R, 3) [N*m] and ω (B, R, 3) [rad/s],
        both in each rod's frame.
    """
    with torch.no_grad():
        out = []
        for fx in (effects, reference):
            engine = Engine(topology, PHYSICS_DT, list(fx), dtype=states.p.dtype)
            out.append(engine.accelerations(states, params))
        mass = params.mass.to(states.p)
        inertia = params.inertia.to(states.p)
        # the same state and parameters: the gyroscopic terms cancel in the difference
        return (mass[:, None] * (out[0][0] - out[1][0]), inertia * (out[0][1] - out[1][1]),
                out[0][2])  # fmt: skip


def force_ratio(candidate: FittedModel, current: FittedModel, states: State) -> float:
    """RMS force ``candidate`` adds over ``current`` at ``states``, in rod weights.

    NaN where that cannot be measured without the commands (a control lag acts on the
    commands only).

    Args:
        candidate: the current model plus one effect, fitted.
        current: the model it is compared with.
        states: rod states sampled from the data, batch B.
    """
    if any(e.filters_commands for e in candidate.effects):
        return math.nan
    params, topo = candidate.params, candidate.model.topology
    d_force, d_torque, _ = force_change(topo, params, candidate.effects, current.effects, states)
    half = torch.tensor([r.length / 2 for r in topo.rods], dtype=states.p.dtype)
    size = d_force.norm(dim=-1) + d_torque.norm(dim=-1) / half
    weight = params.mass.to(states.p) * params.gravity.to(states.p).norm()
    ratio = size / weight
    ratio = ratio[torch.isfinite(ratio)]
    if ratio.numel() == 0:
        return math.nan
    return float(ratio.pow(2).mean().sqrt())


def group_power(effect: PhysicalEffect, params: Params, states: State) -> dict[str, float]:
    """Mean power [W] that each parameter group of ``effect`` adds on its own at
    ``states`` (all rods, ``ΔF·v + Δτ·ω``, the group's values kept and the others at
    zero); NaN where not finite.

    A drag (:attr:`~tensegrity_env.effects.base.PhysicalEffect.dissipative`) removes
    energy through its translational and its rotational part alike: a fitted one whose
    part adds energy compensates for something else (a declared model or contact a
    little too dissipative), even when each coefficient is within its standard errors of
    zero and the other part removes more. A mean power within :data:`ROUND_OFF_POWER` of
    the rods' weight times their speed (``Σ M |g| |v|``, mean over the states) is
    round-off, and 0 (a part at exactly zero computed beside other effects).
    """
    out = {}
    weight = params.mass.to(states.v) * float(params.gravity.norm())  # (R,) [N]
    scale = float((weight * states.v.norm(dim=-1)).sum(-1).mean())  # [W]
    for key in effect.PARAMS:
        only: dict[str, Any] = {
            k: v if k == key else torch.zeros_like(v) for k, v in effect.values.items()
        }  # parameter name -> value: ``key`` alone
        alone = type(effect)(effect.topology, validate=False, **only)
        d_force, d_torque, omega_l = force_change(effect.topology, params, [alone], [], states)
        power = (d_force * states.v).sum((-1, -2)) + (d_torque * omega_l).sum((-1, -2))
        power = power[torch.isfinite(power)]
        mean = float(power.mean()) if power.numel() else math.nan
        out[key] = 0.0 if abs(mean) <= ROUND_OFF_POWER * scale else mean
    return out
