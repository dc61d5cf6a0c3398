"""Is a candidate effect negligible? The force it adds on the rods, against their weight.

A fit can give an effect a small, "significant" value that is an artefact of the
model (an integration scheme, a bias of the noise) rather than physics: 3.9 mN of
"force field" on 2 kg rods is 0.02 % of their weight. :func:`force_ratio` measures
what a candidate changes in the forces on the rods over sampled states of the data:
per rod and sample ``|ΔF| + |Δτ| / (L/2)`` (the torque as a force at the rod's end),
its RMS divided by the rod's weight ``M |g|``. A candidate below :data:`NEGLIGIBLE`
is reported as negligible and not added
(:func:`~identification.discovery.judge.judge`).
"""

from __future__ import annotations

import math

import torch

from identification.discovery.library import FittedModel
from tensegrity_env.effects import ControlLag
from tensegrity_env.engine import PHYSICS_DT, Engine, State

#: an effect whose forces on the rods are below this fraction of their weight is negligible
NEGLIGIBLE = 1e-3


def force_ratio(candidate: FittedModel, current: FittedModel, states: State) -> float:
    """RMS force ``candidate`` adds over ``current`` at ``states``, in rod weights.

    Both models are evaluated with the candidate's declared parameters, so only the
    effects differ. NaN where that cannot be measured without the commands (a control
    lag acts on the commands only).

    Args:
        candidate: the current model plus one effect, fitted.
        current: the model it is compared with.
        states: rod states sampled from the data, batch B.
    """
    if any(isinstance(e, ControlLag) for e in candidate.effects):
        return math.nan
    topo, params = candidate.model.topology, candidate.params
    with torch.no_grad():
        out = []
        for effects in (candidate.effects, current.effects):
            engine = Engine(topo, PHYSICS_DT, effects, dtype=states.p.dtype)
            a, alpha_l, _ = engine.accelerations(states, params)
            out.append((a, alpha_l))
        mass = params.mass.to(states.p)
        inertia = params.inertia.to(states.p)
        half = torch.tensor([r.length / 2 for r in topo.rods], dtype=states.p.dtype)
        d_force = mass[:, None] * (out[0][0] - out[1][0])
        d_torque = inertia * (out[0][1] - out[1][1])
        size = d_force.norm(dim=-1) + d_torque.norm(dim=-1) / half
        weight = mass * params.gravity.to(states.p).norm()
        ratio = size / weight
        ratio = ratio[torch.isfinite(ratio)]
    if ratio.numel() == 0:
        return math.nan
    return float(ratio.pow(2).mean().sqrt())
