"""Interaction+Int: the Interaction Network with the paper's integration module appended.

The force model (MLP1) and aggregation are those of
:class:`~identification.experiments.baselines.interaction.Interaction`. MLP2 no longer sees the raw
state: per rod it gets the rod vector ``r`` (world offset from the centre to end cap 1,
[m]), its angular velocity in the rod frame ``ω_l`` [rad/s] (needed for the gyroscopic
term), the received force (world) and torque (in the rod frame, where the angular
acceleration lives) and a one-hot rod id, and predicts accelerations: linear ``a``
[m/s^2] (world) and angular ``α_l`` [rad/s^2] (rod frame). The next state comes from
:func:`tensegrity_env.engine.integration.semi_implicit_euler` (MuJoCo's Euler step).

Trained on the MSE of the standardised accelerations ``(v_{t+1} - v_t)/dt`` and
``(ω_l,{t+1} - ω_l,t)/dt`` — for a fixed integrator the same minimiser as the MSE of the
standardised next velocities.
"""

from __future__ import annotations

import torch

from identification.experiments.baselines.common import local_angular_velocity
from identification.experiments.baselines.interaction import RelationalBaseline
from tensegrity_env.engine import State
from tensegrity_env.engine.integration import semi_implicit_euler
from tensegrity_env.engine.kinematics import Kinematics


class InteractionInt(RelationalBaseline):
    """Interaction Network predicting accelerations, integrated by semi-implicit Euler."""

    name = "Interaction+Int"
    rod_in = 6  # r (3), omega_l (3)
    n_out = 6  # a (3, world), alpha_l (3, rod frame)
    rod_frame_torque = True

    def rod_features(self, state: State, kin: Kinematics) -> torch.Tensor:
        return torch.cat([kin.arms[:, :, 1], local_angular_velocity(state, kin.rot)], dim=-1)

    def targets(self, s0: State, s1: State, kin: Kinematics) -> torch.Tensor:
        w0 = local_angular_velocity(s0, kin.rot)
        w1 = local_angular_velocity(s1)
        return torch.cat([(s1.v - s0.v) / self.dt_, (w1 - w0) / self.dt_], dim=-1)

    def advance(self, state: State, kin: Kinematics, out: torch.Tensor) -> State:
        accel, alpha_l = out[..., :3], out[..., 3:]
        omega_l = local_angular_velocity(state, kin.rot)
        return semi_implicit_euler(state, accel, alpha_l, omega_l, self.dt_)
