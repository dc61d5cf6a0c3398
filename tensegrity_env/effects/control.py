"""Control that is not what was commanded: a first-order lag between command and force.

Gate: correlates with the applied command. The force that acts is ``h u_f`` with
``τ u̇_f = u - u_f``, starting from ``u_f = 0``. A wrong gain alone is the identified
``h`` of the params. Two discretisations:

* control forces f_u (the planted effect): ``u_f += dt / (τ + dt) (u - u_f)``, and the
  step's force uses the updated ``u_f``;
* cable actuators (MuJoCo's ``dyntype="filter"``, ``explicit=True``): the step's force
  uses the activation before the update ``u_f += dt / τ (u - u_f)`` (MuJoCo's Euler step
  of the actuator activation, ``actearly="false"``).

The engine hands commands to the control term, not to effects, so this effect acts
on the command sequence before a rollout: ``engine.rollout(state, params, T,
lag.filter_commands(control, dt))``. Its ``wrench`` hook adds nothing.
"""

from __future__ import annotations

from typing import ClassVar

import torch

from tensegrity_env.effects.base import FitForm, Gate, ParamSpec, PhysicalEffect


class ControlLag(PhysicalEffect):
    """First-order lag ``time_constant`` τ [s] between command and applied force."""

    name: ClassVar[str] = "control_lag"
    summary: ClassVar[str] = "applied control force lags the command (first order)"
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "time_constant": ParamSpec("s", 0.0),
    }
    gate: ClassVar[Gate] = Gate("control commands are applied", needs="commands")
    #: given τ the model is linear: a search over τ, the regression refitting the rest
    fit_form: ClassVar[FitForm] = FitForm(route="search")
    filters_commands: ClassVar[bool] = True
    no_native: ClassVar[str] = "it filters the commands before a rollout, not inside a step"

    def filter_commands(
        self, control: torch.Tensor, dt: float, explicit: bool = False
    ) -> torch.Tensor:
        """Lagged commands, same shape as ``control`` (B, T, ...) (time on dim 1).

        ``explicit``: MuJoCo's filter actuator (see the module docstring), for cable
        commands (B, T, C); needs ``τ > 0``.
        """
        tau = self.value("time_constant", control)
        if explicit and not bool(tau > 0):
            raise ValueError(f"control_lag: MuJoCo's filter needs a time constant > 0, got {tau}")
        alpha = dt / tau if explicit else dt / (tau + dt)
        out = torch.empty_like(control)
        u_f = torch.zeros_like(control[:, 0])
        for t in range(control.shape[1]):
            if explicit:
                out[:, t] = u_f
            u_f = u_f + alpha * (control[:, t] - u_f)
            if not explicit:
                out[:, t] = u_f
        return out
