"""Trajectories at their own sample times: measured states and winding.

A real take's samples are not evenly spaced (message times, dropped frames, two
messages of one frame). Everything here works at each sample's own time ``t`` (the
dataset's ``time``): no grid is assumed.

* :func:`states_at_times`: rod states from end caps, each end cap smoothed by a local
  linear fit in time (Gaussian weights of std ``smoothing`` [s] over the neighbouring
  samples at their times), which gives its position and velocity at the sample;
* :func:`winch_at_times`: the winch state at every sample from the command log, the
  motors integrated from the trajectory's start in the physics steps the engine takes
  between those samples (:meth:`~tensegrity_env.engine.Engine.advance`);
* :func:`window_caps`: windows of a trajectory rolled out from measured states at their
  sample times (:meth:`~tensegrity_env.engine.Engine.rollout_at`), winding as
  commanded, their end caps at every sample of the window.
"""

from __future__ import annotations

import numpy as np
import torch

from identification.data.end_caps import rod_states_from_nodes
from tensegrity_env.engine import substeps_for
from tensegrity_env.engine.winch import initial_winch_state, winch_step
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology


def local_linear(nodes: np.ndarray, times: np.ndarray, smoothing: float) -> tuple[np.ndarray, np.ndarray]:
    """Each end cap's position and velocity at each sample: a weighted line fit over
    the samples at their own times, Gaussian weights of std ``smoothing`` [s].

    ``nodes`` (T + 1, 2R, 3) [m] (NaN unseen: left out of the fits), ``times`` (T + 1,)
    [s]. Returns positions and velocities (T + 1, 2R, 3) [m, m/s]; NaN where fewer than
    two seen samples fall within three ``smoothing`` of the sample.
    """
    T1 = len(times)
    pos, vel = np.full(nodes.shape, np.nan), np.full(nodes.shape, np.nan)
    seen = np.isfinite(nodes).all(-1)  # (T + 1, 2R)
    for k in range(T1):
        dt = times - times[k]
        near = np.abs(dt) <= 3 * smoothing
        w = np.exp(-0.5 * (dt / smoothing) ** 2) * near
        for c in range(nodes.shape[1]):
            wc = w * seen[:, c]
            if np.count_nonzero(wc) < 2:
                continue
            sw, st, stt = wc.sum(), (wc * dt).sum(), (wc * dt * dt).sum()
            den = sw * stt - st * st
            if den <= 1e-12 * sw * sw * smoothing**2:
                continue
            x = np.where(seen[:, c, None], nodes[:, c], 0.0)
            sx, stx = (wc[:, None] * x).sum(0), (wc[:, None] * dt[:, None] * x).sum(0)
            vel[k, c] = (sw * stx - st * sx) / den
            pos[k, c] = (sx - vel[k, c] * st) / sw
    return pos, vel


def states_at_times(nodes: np.ndarray, times: np.ndarray, topology: Topology, smoothing: float) -> dict[str, np.ndarray]:
    """Rod states (T + 1, R, ·) at each sample from end caps (T + 1, 2R, 3) [m] at
    ``times`` (T + 1,) [s]: positions and orientations from the smoothed end caps
    (:func:`local_linear`), the centre of mass moving as the caps do, the angular
    velocity perpendicular to the axis ``a × ȧ`` (spin about the axis is not seen)."""
    pos, vel = local_linear(nodes, times, smoothing)
    st = rod_states_from_nodes(pos[None], topology, 1.0)  # velocities replaced below
    x0, x1 = pos[:, 0::2], pos[:, 1::2]
    v0, v1 = vel[:, 0::2], vel[:, 1::2]
    ends = topology.end_offsets
    d_rod = ends[:, 1] - ends[:, 0]
    s = -np.sum(ends[:, 0] * d_rod, axis=-1) / np.sum(d_rod * d_rod, axis=-1)  # (R,)
    d = x1 - x0
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    a = d / length
    dd = v1 - v0
    a_dot = (dd - a * np.sum(a * dd, -1, keepdims=True)) / length
    return {"p": st["p"][0], "v": v0 + s[:, None] * (v1 - v0), "q": st["q"][0],
            "omega": np.cross(a, a_dot)}  # fmt: skip


def winch_at_times(
    topology: Topology, params: Params, times: torch.Tensor, commands: torch.Tensor, physics_dt: float
) -> torch.Tensor:
    """The winch state (T + 1, W, 2) [m, m/s] at each sample time ``times`` (T + 1,) [s]
    under ``commands`` (T, W) held over each interval, from the declared rest lengths at
    rest; each interval in ``ceil(interval / physics_dt)`` equal steps, as the engine
    takes them (:meth:`~tensegrity_env.engine.Engine.advance`). Differentiable in the
    winch parameters and the wound springs' rest lengths."""
    winch = initial_winch_state(topology, params, 1).to(commands)
    out = [winch]
    for k in range(len(times) - 1):
        iv = float(times[k + 1] - times[k])
        n = substeps_for(iv, physics_dt)
        h = torch.full((1, 1), iv / n, dtype=commands.dtype)
        for _ in range(n):
            winch = winch_step(winch, params, commands[k][None], h)
        out.append(winch)
    return torch.cat(out)
