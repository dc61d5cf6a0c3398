"""Initial rod states of trajectory windows, fitted on growing prefixes.

A state from smoothing is poor where an impact falls inside the filter's span, and on
a long window a fit started there may stop in another basin. So the states are fitted
on the first :data:`GROW` steps of each window, each stage from the last, then on the
whole window. ``spin=True`` fits the rods' axial spins too (friction at an end cap
turns a rod about its axis), for clean data: under noise the fit may step to spins
whose explicit gyroscopic integration blows up on longer windows.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from identification.trajectory.param_vector import ParamVector
from identification.trajectory.windowed_fit import WindowFit, fit_windows
from identification.trajectory.windows import Windows
from tensegrity_env.engine import Engine

#: window prefixes [steps] the initial states are fitted on before the whole window
GROW = (10, 25, 50, 100, 200, 400)


def prefix(windows: Windows, steps: int) -> Windows:
    """The first ``steps`` steps of every window."""
    ctrl = None if windows.control is None else windows.control[:, :steps]
    valid = None if windows.valid is None else windows.valid[:, : steps + 1]
    return replace(windows, obs=windows.obs[:, : steps + 1], control=ctrl, valid=valid)


def fit_states(
    engine: Engine, vec: ParamVector, windows: Windows, iters: int, spin: bool = False,
    roll: bool = False,
) -> WindowFit:  # fmt: skip
    """Only the windows' initial states (``vec``: nothing free), on growing prefixes.

    ``spin``: the axial spins too (from the prefix of 25 steps on); ``roll``: the rods'
    roll about their axes (see :func:`~identification.trajectory.windows.local_basis`).
    Returns the fit on the whole windows (its ``history[-1]``: mean squared end-cap
    error [m^2]).
    """
    empty = torch.zeros(0, dtype=torch.float64)
    for n in (g for g in GROW if g < windows.steps):
        w = fit_windows(engine, vec, prefix(windows, n), empty, iters, tol=0.01,
                        spin=spin and n >= 25, roll=roll)  # fmt: skip
        windows = replace(windows, state=w.windows.state)
    return fit_windows(engine, vec, windows, empty, iters, tol=0.01, spin=spin, roll=roll)
