"""Control that is not what was commanded: a first-order lag between command and force.

Gate: correlates with the applied command. The force that acts is ``h u_f`` with
``τ u̇_f = u - u_f`` (discretised per step as ``u_f += dt / (τ + dt) (u - u_f)``,
starting from ``u_f = 0``). A wrong gain alone is the identified ``h`` of the params.

The engine hands commands to the control term, not to effects, so this effect acts
on the command sequence before a rollout: ``engine.rollout(state, params, T,
lag.filter_commands(control, dt))``. Its ``wrench`` hook adds nothing.
"""

from __future__ import annotations

from typing import ClassVar

import torch

from tensegrity_env.effects.base import ParamSpec, PhysicalEffect


class ControlLag(PhysicalEffect):
    """First-order lag ``time_constant`` τ [s] between command and applied force."""

    name: ClassVar[str] = "control_lag"
    summary: ClassVar[str] = "applied control force lags the command (first order)"
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "time_constant": ParamSpec("s", 0.0),
    }

    def filter_commands(self, control: torch.Tensor, dt: float) -> torch.Tensor:
        """Lagged commands, same shape as ``control`` (B, T, R, 3) (time on dim 1)."""
        tau = self.value("time_constant", control)
        alpha = dt / (tau + dt)
        out = torch.empty_like(control)
        u_f = torch.zeros_like(control[:, 0])
        for t in range(control.shape[1]):
            u_f = u_f + alpha * (control[:, t] - u_f)
            out[:, t] = u_f
        return out
