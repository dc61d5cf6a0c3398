"""Winches from end caps and the command log, at the samples' own times.

A robot whose motors wind its cables is seen as end caps at uneven times, its motors
commanded. Where a wound cable runs between two end caps, its length is measured in
every sample, and a taut, stiff cable is its rest length plus a stretch of its tension
over its stiffness: millimetres where the rest length moves by centimetres. So the
winding is identified from the measured lengths (:func:`fit_winding`): with the
motors integrated from the take's start at the samples' own times
(:func:`~identification.trajectory.timed.winch_at_times`, as the engine winds them), a
rest length is ``l0(t) = l0(0) + v_max U(t; tau)`` while no range is reached, ``U`` the
winding per unit ``v_max`` under the commands; linear in ``l0(0)`` (one per cable) and
``v_max`` (shared), solved exactly for each motor lag ``tau`` of :data:`LAGS`, the lag
with the smallest residual kept. A winch's range ``[l_min, l_max]`` acts only where the
winding reaches it; :attr:`WindingFit.winding_range` says how far the fitted winding
went, so a range never reached is reported as not seen, not fitted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from identification.trajectory.timed import winch_at_times
from tensegrity_env.engine.winch import REST
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model
from tensegrity_env.params import Params

#: motor lags tried [s]: none, then from below the samples' spacing of a fast capture
#: system to a motor that takes a few tenths of a second to reach its speed
LAGS = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.4)


@dataclass
class WindingFit:
    """What :func:`fit_winding` found.

    Attributes:
        params: the declared parameters with the fitted winch speed, lag and the wound
            cables' rest lengths at the take's start.
        winch_speed: the fitted ``v_max`` [m/s], shared by the winches.
        winch_lag: the lag [s] of :data:`LAGS` with the smallest residual.
        start_rest: (W,) each wound cable's rest length at the take's start [m].
        rms: RMS of the measured wound-cable lengths about the fitted winding [m].
        declared_rms: the same with the declared winding [m].
        lag_rms: the fit's RMS [m] at each lag of :data:`LAGS`.
        winding_range: (W, 2) the shortest and longest fitted rest length of each
            wound cable over the take [m].
    """

    params: Params
    winch_speed: float
    winch_lag: float
    start_rest: np.ndarray
    rms: float
    declared_rms: float
    lag_rms: dict[float, float]
    winding_range: np.ndarray


def cable_lengths(nodes: np.ndarray, model: Model) -> np.ndarray:
    """Measured lengths (T + 1, W) [m] of the wound cables between their end caps; raises
    :class:`InputError` when a wound cable does not run between two end caps."""
    topo = model.topology
    ends = topo.spring_nodes[list(topo.winches)]  # (W, 2)
    if (ends >= 2 * topo.n_rods).any() or topo.off_axis_points():
        raise InputError("a wound cable does not run between two end caps: its length is not measured")
    return np.linalg.norm(nodes[:, ends[:, 0]] - nodes[:, ends[:, 1]], axis=-1)


def winding(model: Model, params: Params, times: np.ndarray, commands: np.ndarray, physics_dt: float) -> np.ndarray:
    """Rest lengths (T + 1, W) [m] of the wound cables at ``times`` under ``commands``."""
    with torch.no_grad():
        w = winch_at_times(model.topology, params, torch.as_tensor(times, dtype=torch.float64),
                           torch.as_tensor(commands, dtype=torch.float64), physics_dt)  # fmt: skip
    return w[..., REST].numpy()


def fit_winding(model: Model, nodes: np.ndarray, times: np.ndarray, commands: np.ndarray,
                physics_dt: float) -> WindingFit:  # fmt: skip
    """Fit ``v_max``, the lag and the rest lengths at the start (module doc).

    Args:
        model: the declared model (its winches and the rest of its parameters).
        nodes: end caps (T + 1, 2R, 3) [m] of one trajectory from the take's start.
        times: (T + 1,) [s], increasing, from the take's start.
        commands: (T, W) winch commands held over each sample interval.
        physics_dt: the longest physics step [s] the motors are integrated with.
    """
    topo, p = model.topology, model.params
    if not topo.n_winches:
        raise InputError("the robot has no winches")
    length = cable_lengths(nodes, model)  # (T + 1, W)
    seen = np.isfinite(length)
    W = topo.n_winches
    free = p.replace(winch_speed=torch.ones(W, dtype=torch.float64),
                     winch_min=torch.full((W,), -np.inf, dtype=torch.float64),
                     winch_max=torch.full((W,), np.inf, dtype=torch.float64),
                     rest_length=p.rest_length.index_fill(0, torch.as_tensor(topo.winches), 0.0))  # fmt: skip
    best: tuple[float, float, np.ndarray, float] | None = None
    lag_rms: dict[float, float] = {}
    for tau in LAGS:
        unit = winding(model, free.replace(winch_lag=torch.full((W,), tau, dtype=torch.float64)), times,
                       commands, physics_dt)  # fmt: skip
        # unknowns: l0(0) per cable, then v_max; one row per seen cable sample
        rows, rhs = [], []
        for c in range(W):
            k = seen[:, c]
            a = np.zeros((int(k.sum()), W + 1))
            a[:, c], a[:, W] = 1.0, unit[k, c]
            rows.append(a)
            rhs.append(length[k, c])
        a, b = np.concatenate(rows), np.concatenate(rhs)
        x, *_ = np.linalg.lstsq(a, b, rcond=None)
        rms = float(np.sqrt(np.mean((a @ x - b) ** 2)))
        lag_rms[tau] = rms
        if x[W] > 0 and (best is None or rms < best[3]):
            best = (float(x[W]), tau, x[:W], rms)
    if best is None:
        raise InputError("the measured cable lengths do not follow the commands (no positive winding speed fits)")
    v, tau, start, rms = best
    idx = torch.as_tensor(topo.winches)
    params = p.replace(winch_speed=torch.full((W,), v, dtype=torch.float64),
                       winch_lag=torch.full((W,), tau, dtype=torch.float64),
                       rest_length=p.rest_length.index_put((idx,), torch.as_tensor(start, dtype=torch.float64)))  # fmt: skip
    rest = winding(model, params, times, commands, physics_dt)
    declared = winding(model, p, times, commands, physics_dt)
    return WindingFit(
        params=params, winch_speed=v, winch_lag=tau, start_rest=np.asarray(start), rms=rms,
        declared_rms=float(np.sqrt(np.nanmean((declared - length) ** 2))), lag_rms=lag_rms,
        winding_range=np.stack([rest.min(0), rest.max(0)], -1),
    )  # fmt: skip
