"""Winches: motors that wind a spring, changing its rest length over time.

A winch's motor command ``u`` (clipped to [-1, 1]) sets the winding speed
``dl0/dt = u * v_max`` of its spring's rest length ``l0`` (the winch radius is inside
``v_max``), optionally through a first-order motor lag ``tau`` on that speed, and ``l0``
stays within its range ``[l_min, l_max]`` (``Params.winch_*``). The winch state is
``(l0, s)`` per winch, ``s`` the winding speed [m/s] (:attr:`State.winch
<tensegrity_env.engine.state.State.winch>`).

One physics step ``h`` with the command held (the MuJoCo plant does the same,
:mod:`tensegrity_env.mjcf.winches`):

1. the springs pull with the rest lengths at the step's start;
2. the rods are integrated;
3. ``s' = s* + (s - s*) exp(-h / tau)`` with ``s* = u v_max`` (the lag's exact solution
   over ``h``; ``s' = s*`` without lag), then ``l0' = clamp(l0 + h s', l_min, l_max)``.

A clamped rest length stops winding; the motor's speed state is left as the lag has it.
"""

from __future__ import annotations

import torch

from tensegrity_env.params import Params
from tensegrity_env.topology import Topology

#: the winch state's columns: rest length [m], winding speed [m/s]
REST, SPEED = 0, 1


def initial_winch_state(topology: Topology, params: Params, batch: int) -> torch.Tensor:
    """The winch state at rest: each wound spring's declared ``rest_length`` and speed 0,
    (batch, W, 2) [m, m/s]."""
    idx = torch.as_tensor(topology.winches, dtype=torch.long, device=params.rest_length.device)
    rest = params.rest_length[..., idx]  # differentiable: the start is a fitted rest length
    rest = rest.expand(batch, -1) if rest.dim() == 1 else rest
    return torch.stack([rest, torch.zeros_like(rest)], dim=-1)


def winding_speed(
    speed: torch.Tensor,
    v_max: torch.Tensor,
    lag: torch.Tensor,
    command: torch.Tensor,
    h: float | torch.Tensor,
) -> torch.Tensor:
    """Each motor's winding speed after one step ``h`` [s] (a float, or (B, 1) per
    assembly), (B, W) [m/s] (module doc, 3).

    ``speed`` (B, W) [m/s] before the step, ``v_max`` [m/s] and ``lag`` [s] (W,) or
    (B, W), ``command`` (B, W) in command units (clipped to [-1, 1]).
    """
    target = command.clamp(-1.0, 1.0) * v_max
    return target + (speed - target) * winding_decay(lag, h)


def winding_decay(lag: torch.Tensor, h: float | torch.Tensor) -> torch.Tensor:
    """How much of a motor's speed error is left after one step ``h`` [s] (a float, or
    (B, 1) per assembly):
    ``exp(-h / tau)``, 0 without lag (``tau`` = ``lag`` [s], same shape)."""
    lagged = lag > 0
    decay = torch.exp(-h / torch.where(lagged, lag, torch.ones_like(lag)))
    return torch.where(lagged, decay, torch.zeros_like(decay))


def unit_winding(commands: torch.Tensor, lag: torch.Tensor, h: float) -> torch.Tensor:
    """How far each rest length has moved per unit ``v_max``, from rest, ignoring the
    range: (..., T + 1, W) [m per m/s] for commands (..., T, W) held ``h`` [s] each.

    The winding is linear in ``v_max`` (module doc, step 3, without the clamp), so
    ``l0(t) = l0(0) + v_max * unit_winding(t)`` while no range is reached.
    """
    one = torch.ones((), dtype=commands.dtype)
    speed = torch.zeros_like(commands[..., 0, :])
    moved = [torch.zeros_like(speed)]
    for t in range(commands.shape[-2]):
        speed = winding_speed(speed, one, lag, commands[..., t, :], h)
        moved.append(moved[-1] + h * speed)
    return torch.stack(moved, dim=-2)


def winch_step(
    winch: torch.Tensor, params: Params, command: torch.Tensor | None, h: float | torch.Tensor
) -> torch.Tensor:
    """The winch state after one physics step ``h`` [s] (a float, or (B, 1) per
    assembly) (module doc, step 3).

    Args:
        winch: (B, W, 2) rest length [m] and winding speed [m/s].
        params: ``winch_speed``, ``winch_min``, ``winch_max``, ``winch_lag`` (W,) or (B, W).
        command: motor commands (B, W) in [-1, 1] (clipped); None holds the motors at 0.
    """
    if command is None:
        command = torch.zeros_like(winch[..., REST])
    speed = winding_speed(winch[..., SPEED], params.winch_speed, params.winch_lag,
                          command.to(winch), h)  # fmt: skip
    rest = torch.clamp(winch[..., REST] + h * speed, params.winch_min, params.winch_max)
    return torch.stack([rest, speed], dim=-1)


def wound_rest_lengths(params: Params, winches: torch.Tensor, winch: torch.Tensor) -> Params:
    """``params`` with the wound springs' rest lengths from the winch state, (B, S) [m].

    ``winches`` (W,) spring indices; ``winch`` (B, W, 2).
    """
    rest = params.rest_length
    batch, S = winch.shape[0], rest.shape[-1]
    rest = rest.expand(batch, S).index_copy(1, winches, winch[..., REST].to(rest))
    return params.replace(rest_length=rest)


def winch_history(
    topology: Topology, params: Params, commands: torch.Tensor, h: float
) -> torch.Tensor:
    """The winch state along a command log from rest, one :func:`winch_step` per
    command: (..., T + 1, W, 2) [m, m/s] for commands (..., T, W) held ``h`` [s] each."""
    lead = commands.shape[:-2]
    flat = commands.reshape(-1, *commands.shape[-2:])
    winch = initial_winch_state(topology, params, flat.shape[0]).to(commands)
    out = [winch]
    for t in range(flat.shape[1]):
        winch = winch_step(winch, params, flat[:, t], h)
        out.append(winch)
    return torch.stack(out, dim=1).reshape(*lead, flat.shape[1] + 1, -1, 2)
