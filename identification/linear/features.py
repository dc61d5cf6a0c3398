"""Per-transition quantities the regression reads: the 1-D spring frames and rod rates.

For one transition ``t -> t+1`` of MuJoCo's semi-implicit Euler, the accelerations
that produced it are exactly ``a = (v_{t+1} - v_t) / dt`` and
``α_l = (ω_l,{t+1} - ω_l,t) / dt`` in each rod's own frame (MuJoCo integrates the
free joint's body-frame angular velocity coordinate-wise; with a body frame off the
centre of mass, the origin's velocity, see
:func:`tensegrity_env.engine.integration.step_accelerations`), and every force was
evaluated at state ``t``. So every equation of motion is linear in the parameters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from identification.data.dataset import Split
from tensegrity_env.engine.forces import SpringFrame, spring_frames
from tensegrity_env.engine.integration import step_accelerations
from tensegrity_env.engine.kinematics import AttachmentPoints, node_kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.engine.winch import unit_winding
from tensegrity_env.topology import Topology


@dataclass(frozen=True)
class TransitionFeatures:
    """Everything the design matrix needs for ``n`` transitions.

    Attributes:
        accel: linear accelerations (v_{t+1} - v_t)/dt, (n, R, 3) [m/s^2], world.
        alpha_local: angular accelerations in the rod frame, (n, R, 3) [rad/s^2].
        omega_local: angular velocity at t in the rod frame, (n, R, 3) [rad/s].
        rot: R(q_t), (n, R, 3, 3).
        arms: every node's offset from its rod's COM at t (end caps, anchors as zero,
            attachment points), (n, N, 3) [m], world.
        springs: each spring's length, axis and elongation rate at t.
        control: commands f_u at t, (n, R, 3), world.
        control_arm: control arm r_u at t, (n, R, 3) [m], world.
        cables: acting cable commands at t, (n, C); None without cable actuators.
        winding: how far each winch has wound its rest length at t per unit ``v_max``,
            from the trajectory's start, (n, W) [m per m/s]
            (:func:`tensegrity_env.engine.winch.unit_winding`); None without winches.
    """

    accel: torch.Tensor
    alpha_local: torch.Tensor
    omega_local: torch.Tensor
    rot: torch.Tensor
    arms: torch.Tensor
    springs: SpringFrame
    control: torch.Tensor
    control_arm: torch.Tensor
    cables: torch.Tensor | None = None
    winding: torch.Tensor | None = None

    @property
    def n(self) -> int:
        return int(self.accel.shape[0])


def defined_transitions(split: Split) -> np.ndarray:
    """Flat indices ``n T + t`` of the transitions of ``split`` whose two rod states are
    defined (rod states derived from end caps are NaN where a gap is too long to
    bridge); every transition without gaps."""
    defined = np.logical_and.reduce(
        [np.isfinite(getattr(split, k)).all(axis=(2, 3)) for k in ("p", "v", "q", "omega")]
    )  # (N, T+1)
    return np.flatnonzero((defined[:, :-1] & defined[:, 1:]).ravel())


def drawn_transitions(split: Split, most: int, seed: int) -> np.ndarray:
    """At most ``most`` of the :func:`defined_transitions` of ``split``, drawn at random
    with ``seed`` without replacement, sorted (flat indices ``n T + t``)."""
    usable = defined_transitions(split)
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(usable, size=min(len(usable), most), replace=False))


def transitions_of(
    split: Split, index: np.ndarray | None = None
) -> tuple[State, State, torch.Tensor]:
    """Flatten a split into transitions: (state_t, state_{t+1}, control_t), batch n.

    ``index`` selects flat transition indices in ``[0, N*T)`` (all when None).
    """
    if not split.has_states:
        raise ValueError("split has end caps only; derive rod states first")
    N, T = split.n_trajectories, split.n_transitions
    flat = np.arange(N * T) if index is None else np.asarray(index)
    traj, t = flat // T, flat % T

    def pick(arr: np.ndarray, off: int) -> torch.Tensor:
        return torch.as_tensor(arr[traj, t + off])

    s0 = State(*(pick(getattr(split, k), 0) for k in ("p", "v", "q", "omega")))
    s1 = State(*(pick(getattr(split, k), 1) for k in ("p", "v", "q", "omega")))
    return s0, s1, torch.as_tensor(split.control[traj, t])


def cable_commands_at(split: Split, index: np.ndarray | None = None) -> torch.Tensor | None:
    """Cable commands (n, C) of the flat transitions ``index`` (all when None); None
    without cable actuators."""
    if split.cable_control is None:
        return None
    T = split.n_transitions
    flat = np.arange(split.n_trajectories * T) if index is None else np.asarray(index)
    return torch.as_tensor(split.cable_control[flat // T, flat % T])


def split_winding(split: Split, lag: torch.Tensor, dt: float) -> torch.Tensor | None:
    """:func:`~tensegrity_env.engine.winch.unit_winding` of a split's winch commands,
    (N, T+1, W) [m per m/s], from each trajectory's start (winches at rest) with the
    motors' lag ``lag`` (W,) [s], one command per sample interval ``dt`` [s]; None
    without winches."""
    if split.winch_control is None or split.winch_control.shape[-1] == 0:
        return None
    return unit_winding(torch.as_tensor(split.winch_control), lag.double(), dt)


def winding_at(
    split: Split, lag: torch.Tensor, dt: float, index: np.ndarray | None = None
) -> torch.Tensor | None:
    """:func:`split_winding` (n, W) [m per m/s] at the flat transitions ``index`` (all
    when None); None without winches."""
    moved = split_winding(split, lag, dt)
    if moved is None:
        return None
    T = split.n_transitions
    flat = np.arange(split.n_trajectories * T) if index is None else np.asarray(index)
    return moved[flat // T, flat % T]


def transition_features(
    topology: Topology,
    s0: State,
    s1: State,
    control: torch.Tensor,
    dt: float,
    cables: torch.Tensor | None = None,
    winding: torch.Tensor | None = None,
) -> TransitionFeatures:
    """Compute :class:`TransitionFeatures` for a batch of transitions (``cables``: the
    acting cable commands (n, C), needed when the topology has cable actuators;
    ``winding``: :func:`winding_at`, zero when None and the topology has winches)."""
    if topology.n_winches and winding is None:
        winding = torch.zeros(s0.p.shape[0], topology.n_winches, dtype=s0.p.dtype)
    if topology.n_cables and cables is None:
        cables = torch.zeros(s0.p.shape[0], topology.n_cables, dtype=s0.p.dtype)
    dtype = s0.p.dtype
    ends = torch.as_tensor(topology.end_offsets, dtype=dtype)
    anchors = torch.as_tensor(topology.anchor_positions, dtype=dtype)
    kin = node_kinematics(s0, ends, anchors, AttachmentPoints.of(topology, dtype))
    nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long)
    frame = spring_frames(kin, nodes[:, 0], nodes[:, 1])
    origins = topology.frame_origins
    accel, alpha_l, omega_l0, _ = step_accelerations(
        s0, s1, dt, torch.as_tensor(origins, dtype=dtype) if origins.any() else None
    )
    arm_u = torch.einsum(
        "brij,rj->bri", kin.rot, torch.as_tensor(topology.control_arms, dtype=dtype)
    )
    return TransitionFeatures(
        accel=accel,
        alpha_local=alpha_l,
        omega_local=omega_l0,
        rot=kin.rot,
        arms=kin.node_arms,
        springs=frame,
        control=control.to(dtype),
        control_arm=arm_u,
        cables=None if cables is None else cables.to(dtype),
        winding=None if winding is None else winding.to(dtype),
    )
