"""What every baseline shares: the assembly geometry, transition sampling, a predictor API.

A *predictor* maps a batch of rod states to the next one: ``predict(state) -> State``
with every tensor (B, R, ·) in float64 (see :class:`tensegrity_env.engine.State`).
Rollouts feed predictions back (:mod:`identification.experiments.baselines.evaluate`).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
import torch

from identification.data.dataset import Split
from identification.linear.features import transitions_of
from tensegrity_env.engine import Engine, State
from tensegrity_env.engine.forces import node_forces_to_wrench
from tensegrity_env.engine.kinematics import Kinematics, node_kinematics
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params
from tensegrity_env.rotations import quat_integrate, quat_to_matrix
from tensegrity_env.topology import Topology


@runtime_checkable
class Predictor(Protocol):
    """One step of a dynamics model: rod states (B, R, ·) -> next rod states (float64)."""

    name: str

    def predict(self, state: State) -> State: ...


class Geometry:
    """The fixed assembly description as tensors, and the per-spring 3-D quantities.

    Args:
        topology: the assembly graph.
        dtype: dtype of the offset/anchor tensors (float64: states are float64).
    """

    def __init__(self, topology: Topology, dtype: torch.dtype = torch.float64) -> None:
        if topology.n_points:
            raise InputError(
                f"{topology.name}: the baselines take springs at rod end caps only"
                f" ({topology.n_points} attachment points elsewhere)"
            )
        self.topology = topology
        self.n_rods, self.n_springs = topology.n_rods, topology.n_springs
        self.end_offsets = torch.as_tensor(topology.end_offsets, dtype=dtype)  # (R, 2, 3) [m]
        self.anchors = torch.as_tensor(topology.anchor_positions, dtype=dtype)  # (A, 3) [m]
        nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long)
        self.node_a, self.node_b = nodes[:, 0], nodes[:, 1]
        inc = torch.zeros(topology.n_nodes, topology.n_springs)
        idx = torch.arange(topology.n_springs)
        inc[self.node_a, idx] = 1.0
        inc[self.node_b, idx] = -1.0
        self.incidence = inc  # (N, S): +1 at node a, -1 at node b (Newton's third law)

    def kinematics(self, state: State) -> Kinematics:
        """End caps, arms and rotations of a float64 state batch."""
        return node_kinematics(state, self.end_offsets, self.anchors)

    def spring_vectors(self, kin: Kinematics) -> tuple[torch.Tensor, torch.Tensor]:
        """The paper's Δp^m, Δv^m in 3-D: ``x_b - x_a`` [m] and ``ẋ_b - ẋ_a`` [m/s], (B, S, 3)."""
        return (
            kin.x[:, self.node_b] - kin.x[:, self.node_a],
            kin.xd[:, self.node_b] - kin.xd[:, self.node_a],
        )

    def wrench(
        self, spring_force: torch.Tensor, arms: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Force and torque on each rod from per-spring forces.

        Args:
            spring_force: force of each spring on its node a, (B, S, 3) (node b gets the
                opposite), any unit.
            arms: world end-cap offsets from each rod's centre, (B, R, 2, 3) [m].

        Returns:
            Summed force (B, R, 3) and torque about the centre ``Σ arm × f`` (B, R, 3),
            world frame; forces on anchors are dropped.
        """
        inc = self.incidence.to(spring_force.dtype)
        nodes = torch.einsum("ns,bsk->bnk", inc, spring_force)
        return node_forces_to_wrench(nodes, arms.to(spring_force.dtype))


def sample_transitions(split: Split, n: int | None, seed: int) -> tuple[State, State, np.ndarray]:
    """``n`` random transitions of a split (all when None or larger than the split).

    Returns the states at t and t+1 (batch n, float64) and the flat indices used.
    """
    total = split.n_trajectories * split.n_transitions
    if n is None or n >= total:
        index = np.arange(total)
    else:
        index = np.sort(np.random.default_rng(seed).choice(total, size=n, replace=False))
    s0, s1, _ = transitions_of(split, index)
    return s0, s1, index


def local_angular_velocity(state: State, rot: torch.Tensor | None = None) -> torch.Tensor:
    """ω in each rod's frame ``R(q)^T ω``, (B, R, 3) [rad/s]."""
    rot = quat_to_matrix(state.q) if rot is None else rot
    return torch.einsum("brji,brj->bri", rot, state.omega)


class ConstantVelocity:
    """The reference every baseline must beat: no forces, no gravity.

    ``p' = p + dt v``, ``v' = v``, the orientation turned by the rod-frame angular
    velocity, ``ω' = ω``.
    """

    name = "constant velocity"

    def __init__(self, dt: float) -> None:
        self.dt = float(dt)

    def predict(self, state: State) -> State:
        omega_l = local_angular_velocity(state)
        q = quat_integrate(state.q, omega_l, self.dt)
        return State(p=state.p + self.dt * state.v, v=state.v, q=q, omega=state.omega)


class EnginePredictor:
    """Our identified engine (:class:`~tensegrity_env.engine.Engine`) as a predictor."""

    def __init__(self, engine: Engine, params: Params, name: str = "Ours") -> None:
        self.engine, self.params, self.name = engine, params, name

    def predict(self, state: State) -> State:
        return self.engine.step(state, self.params)
