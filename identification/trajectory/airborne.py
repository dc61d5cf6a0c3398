"""Where a floor is in the data: the samples and stretches where no end cap touches it.

The declared model is fitted apart from contact on these (contact's gate closed):
fitted through impacts it drifts to make up for contact. End caps are judged by their
measured height less their radius, :data:`AIRBORNE` above the floor at least (5 σ of
1 mm motion-capture noise).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import minimum_filter1d

from identification.data.dataset import Split
from identification.trajectory.windows import STATE_KEYS, Windows
from tensegrity_env.engine import State
from tensegrity_env.topology import Topology

#: clearance [m] of every end cap above the floor that counts as airborne
AIRBORNE = 0.005
#: shortest airborne stretch used as a window [steps]
MIN_STRETCH = 50
#: a floor stops end caps: data whose caps sink deeper than this has none [m] (MuJoCo's
#: soft floor lets a collapsing icosahedron sink ~0.1 m; a free fall goes metres)
FLOOR_DEPTH = 0.3


def cap_radii(topology: Topology) -> np.ndarray:
    """Contact radius of every end cap as the robot file gives it, (2R,) [m]."""
    return topology.cap_radii.reshape(-1)


def contact_gate(split: Split, topology: Topology) -> tuple[bool, str]:
    """Whether end caps reach the floor and the floor stops them, and why (one line).

    Over the seen end-cap samples only: a gap (NaN) is neither low nor deep."""
    radius = np.array([r.radius for r in topology.rods]).repeat(2)
    height = split.nodes[..., 2] - radius
    seen = height[np.isfinite(height)]
    if seen.size == 0:
        return False, "no end cap is seen"
    low, deepest = float((seen <= 0).mean()), float(seen.min())
    if low > 0 and deepest > -FLOOR_DEPTH:
        return True, (
            f"{low:.1%} of end-cap samples at or below z - r = 0; "
            f"none deeper than {-deepest * 1e3:.1f} mm"
        )
    if low == 0:
        return False, "no end cap reaches the floor"
    return False, f"end caps sink {-deepest:.2f} m below z = 0: no floor stops them"


def lowest_seen(gap: np.ndarray) -> np.ndarray:
    """The lowest of the seen values of ``gap`` (..., 2R) over its last axis (end caps),
    (...); NaN only where no end cap is seen (a gap in one end cap hides nothing of the
    others)."""
    return np.fmin.reduce(gap, axis=-1)


def airborne_mask(nodes: np.ndarray, topology: Topology) -> np.ndarray:
    """Samples (N, T+1) whose seen end caps of ``nodes`` (N, T+1, 2R, 3) are all airborne
    (False where none is seen). A marker lost for a sample does not end a flight: the
    fits compare unseen end caps with nothing, and a touchdown shows in the other caps
    and the samples around it."""
    return lowest_seen(nodes[..., 2] - cap_radii(topology)) > AIRBORNE


def airborne_samples(nodes: np.ndarray, topology: Topology, span: int) -> np.ndarray:
    """Samples (N, T) whose end caps all stay :data:`AIRBORNE` above touching the floor
    over the smoothing filter's ``span`` [samples] around them."""
    air = airborne_mask(nodes, topology).astype(np.uint8)
    return minimum_filter1d(air, size=span, axis=1)[:, :-1].astype(bool)


def has_airborne_stretch(
    nodes: np.ndarray, topology: Topology, shortest: int = MIN_STRETCH
) -> bool:
    """Whether some trajectory of ``nodes`` (N, T+1, 2R, 3) [m] stays airborne for at
    least ``shortest`` steps (as :func:`airborne_stretches` counts them)."""
    for row in airborne_mask(nodes, topology):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row.astype(np.int8), [0]])))
        if np.any(edges[1::2] - 1 - edges[::2] >= shortest):
            return True
    return False


def airborne_stretches(
    nodes: np.ndarray,
    control: np.ndarray,
    grid: dict[str, np.ndarray],
    topology: Topology,
    shortest: int = MIN_STRETCH,
) -> Windows | None:
    """Every airborne stretch of at least ``shortest`` steps as one window (None: none).

    ``nodes`` (N, T+1, 2R, 3) [m], ``control`` (N, T, R, 3), ``grid`` rod states
    (N, T+1, R, ·) (where each window's state starts). The windows share one batch,
    as long as the longest stretch; ``valid`` marks each one's own samples. A long
    stretch carries far more about stiffness and damping than the same samples cut
    into short windows (each with its own initial state absorbing part of it).
    """
    air = airborne_mask(nodes, topology)
    runs: list[tuple[int, int, int]] = []  # (trajectory, first sample, steps)
    for i, row in enumerate(air):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row.astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - 1 - a >= shortest:
                runs.append((i, int(a), int(b - 1 - a)))
    if not runs:
        return None
    traj = np.array([i for i, _, _ in runs])
    start = np.array([a for _, a, _ in runs])
    state = State.from_numpy(*(grid[k][traj, start] for k in STATE_KEYS))
    steps = np.array([n for _, _, n in runs])
    return _padded(nodes, control, traj, start, steps, state)


def past_touchdown(stretches: Windows, nodes: np.ndarray, steps: int) -> Windows:
    """``stretches`` (states fitted) run on ``steps`` past their end where the data allows.

    ``nodes`` (N, T+1, 2R, 3) [m]: the measured end caps the stretches were cut from.
    A stretch ends where a cap comes near the floor, so the samples added are the
    touchdown and what follows; only a model with contact can fit them. No control
    (floor data is drops).
    """
    assert stretches.valid is not None
    n = stretches.valid.sum(1).numpy() - 1 + steps  # steps of each window
    n = np.minimum(n, nodes.shape[1] - 1 - stretches.start)
    return _padded(nodes, None, stretches.traj, stretches.start, n, stretches.state)


def _padded(
    nodes: np.ndarray,
    control: np.ndarray | None,
    traj: np.ndarray,
    start: np.ndarray,
    steps: np.ndarray,
    state: State,
) -> Windows:
    """Windows of ``steps`` (B,) from ``start`` (B,) of trajectories ``traj`` (B,), in one
    batch as long as the longest; ``valid`` marks each one's own samples. A window runs
    on past its own end where the trajectory allows (not counted)."""
    T = nodes.shape[1] - 1
    W = int(steps.max())
    span = np.minimum(start[:, None] + np.arange(W + 1), T)
    valid = torch.as_tensor(np.arange(W + 1)[None] <= steps[:, None])
    obs = torch.as_tensor(nodes[traj[:, None], span], dtype=torch.float64)
    ctrl = None if control is None else control[traj[:, None], np.minimum(span[:, :-1], T - 1)]
    ctrl_t = (
        torch.as_tensor(ctrl, dtype=torch.float64)
        if ctrl is not None and np.any(ctrl != 0)
        else None
    )
    return Windows(obs, ctrl_t, state, traj, start, valid)
