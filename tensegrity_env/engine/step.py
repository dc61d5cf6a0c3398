"""The engine: one step is force generation -> acceleration -> integration.

The physics step need not be the data's sample interval: an engine built with
``substeps = n`` advances ``dt`` per :meth:`Engine.step` in ``n`` physics steps of
``dt / n`` (commands held), so a model fitted to samples ``dt`` apart integrates at
the step its physics needs (:func:`substeps_for`).

Measured samples need not be evenly spaced: :meth:`Engine.advance` integrates over any
interval (per assembly) in physics steps of at most ``physics_dt`` that end exactly on
the interval's end, and :meth:`Engine.rollout_at` gives the states at a trajectory's own
sample times, never on a grid the data does not have.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch

from tensegrity_env.defaults import PHYSICS_DT
from tensegrity_env.engine.acceleration import angular_acceleration_local, linear_acceleration
from tensegrity_env.engine.effects import Effect
from tensegrity_env.engine.forces import (
    hooke_tension,
    kinematics_wrench,
    point_force_wrench,
    spring_frames,
    tension_to_node_forces,
)
from tensegrity_env.engine.integration import semi_implicit_euler
from tensegrity_env.engine.kinematics import AttachmentPoints, Kinematics, node_kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.engine.winch import initial_winch_state, winch_step, wound_rest_lengths
from tensegrity_env.native.engine_step import NativeEngineStep
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology
from tensegrity_env.vec3 import rotate, rotate_t


def substeps_for(interval: float, physics_dt: float = PHYSICS_DT) -> int:
    """Physics steps per sample interval so that each is at most ``physics_dt`` [s].

    ``ceil(interval / physics_dt)`` (a relative 1e-9 of slack, so 1 ms samples take one
    1 ms step): 120 Hz samples and a 1 ms physics step give 9 steps of 0.926 ms.
    """
    if not (interval > 0 and physics_dt > 0):
        raise ValueError(f"interval and physics step must be > 0, got {interval}, {physics_dt}")
    return max(1, math.ceil(interval / physics_dt * (1 - 1e-9)))


class Engine:
    """Differentiable spring-rod engine for one topology.

    Holds the topology as index/offset tensors on one dtype and device; parameters
    are passed to every call so they can be fitted (make them ``requires_grad``).

    Args:
        topology: the assembly graph.
        dt: time advanced by one :meth:`step` [s] (the sample interval of the data).
        effects: extra force modules (see :mod:`tensegrity_env.engine.effects`).
        dtype: dtype of the topology tensors; states and params must match.
        device: device of the topology tensors; states and params must match.
        substeps: physics steps per :meth:`step`, each ``dt / substeps`` [s] long
            (see :func:`substeps_for`); commands are held over them.
        native: step by the C kernel where it computes the same and no gradient is
            wanted (:mod:`tensegrity_env.native.engine_step`; elsewhere it logs why
            not): the same physics to round-off, for the many small no-gradient
            rollouts of trajectory fits.
    """

    def __init__(
        self,
        topology: Topology,
        dt: float = 1e-3,
        effects: Sequence[Effect] = (),
        dtype: torch.dtype = torch.float64,
        device: str | torch.device = "cpu",
        substeps: int = 1,
        native: bool = False,
    ) -> None:
        if int(substeps) < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        self.topology = topology
        self.dt = float(dt)
        self.substeps = int(substeps)
        self.native = bool(native)
        self.physics_dt = self.dt / self.substeps
        self.effects = tuple(effects)
        names = [e.name for e in self.effects]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:  # effects add their forces: one given twice acts twice
            raise ValueError(f"effects named twice: {twice}")
        self.dtype, self.device = dtype, torch.device(device)
        kw: dict[str, Any] = {"dtype": dtype, "device": self.device}
        self.end_offsets = torch.as_tensor(topology.end_offsets, **kw)  # (R, 2, 3)
        self.anchors = torch.as_tensor(topology.anchor_positions, **kw)  # (A, 3)
        self.control_arms = torch.as_tensor(topology.control_arms, **kw)  # (R, 3)
        self.points = AttachmentPoints.of(topology, dtype, self.device)
        origins = topology.frame_origins
        # body-frame origins (R, 3) for the integration step; None when all at the COM
        self.frame_origins = torch.as_tensor(origins, **kw) if origins.any() else None
        nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long, device=self.device)
        self.node_a, self.node_b = nodes[:, 0], nodes[:, 1]
        incidence = torch.zeros(topology.n_nodes, topology.n_springs, **kw)
        idx = torch.arange(topology.n_springs, device=self.device)
        incidence[self.node_a, idx] = 1.0
        incidence[self.node_b, idx] = -1.0
        self.incidence = incidence  # (N, S): +1 at node a, -1 at node b
        self.cable_springs = torch.as_tensor(
            topology.cable_actuators, dtype=torch.long, device=self.device
        )  # (C,): the spring each cable actuator drives
        self.winch_springs = torch.as_tensor(
            topology.winches, dtype=torch.long, device=self.device
        )  # (W,): the spring each winch winds
        # the step by the C kernel where it applies, with its cache of packed models
        self.native_step = (
            NativeEngineStep(topology, self.effects, self.substeps, self.physics_dt,
                             bool(self.cable_springs.numel()))
            if self.native
            else None
        )  # fmt: skip

    def with_effects(self, effects: Sequence[Effect]) -> Engine:
        return Engine(self.topology, self.dt, effects, self.dtype, self.device, self.substeps,
                      self.native)  # fmt: skip

    def kinematics(self, state: State) -> Kinematics:
        """Every node's position and velocity (end caps, anchors, attachment points)."""
        return node_kinematics(state, self.end_offsets, self.anchors, self.points)

    # ------------------------------------------------------------------ one step
    def accelerations(
        self,
        state: State,
        params: Params,
        control: torch.Tensor | None = None,
        cables: torch.Tensor | None = None,
        h: float | torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Force generation and acceleration generation.

        Args:
            state: rod states (B, R, ·).
            params: physical parameters.
            control: control commands f_u per rod, world frame, (B, R, 3) [command units];
                the applied force is ``h * f_u`` at each rod's control arm.
            cables: the acting command of each cable actuator, (B, C) [command units]
                (after any actuator filter); the driven spring's tension changes by
                ``-h_c u``, after the effects' tension hooks (a slack cable still
                transmits its actuator's force, as in MuJoCo).
            h: the physics step [s] implicit damping integrates over (``physics_dt`` if
                None; (B, 1, 1) for a step per assembly).

        Returns:
            a (B, R, 3) [m/s^2] world frame, α_l (B, R, 3) [rad/s^2] and ω_l (B, R, 3)
            [rad/s] in each rod's frame.
        """
        # kinematics: end caps and their velocities
        kin = self.kinematics(state)
        # force generation: every spring reduced to a scalar tension along its axis
        frame = spring_frames(kin, self.node_a, self.node_b)
        tension = hooke_tension(frame, params.stiffness, params.damping, params.rest_length)
        for effect in self.effects:
            tension = effect.tension(frame, tension, kin)
        if cables is not None and self.cable_springs.numel():
            tension = tension.index_add(1, self.cable_springs, -params.cable_gain * cables)
        force, torque = kinematics_wrench(
            tension_to_node_forces(tension, frame, self.incidence), kin
        )
        # control forces h * f_u at the arm r_u
        if control is not None:
            arm = rotate(kin.rot, self.control_arms)
            f_u, t_u = point_force_wrench(params.control_gain * control, arm)
            force, torque = force + f_u, torque + t_u
        constraints = [e for e in self.effects if e.constraint]
        for effect in self.effects:
            if effect in constraints:
                continue
            extra = effect.wrench(state, kin, params)
            if extra is not None:
                force, torque = force + extra[0], torque + extra[1]
        for effect in constraints:  # contact reacts to everything applied so far
            extra = effect.wrench(state, kin, params, applied=(force, torque))
            if extra is not None:
                force, torque = force + extra[0], torque + extra[1]
        # acceleration generation: Newton-Euler through M, I and R
        accel = linear_acceleration(force, params.mass, params.gravity)
        alpha_l, omega_l = angular_acceleration_local(torque, state.omega, kin.rot, params.inertia)
        damped = [d for d in (e.implicit_damping(accel) for e in self.effects) if d is not None]
        if damped:
            accel, alpha_l = self._implicit(accel, alpha_l, kin.rot, params, damped, h)
        return accel, alpha_l, omega_l

    def _implicit(
        self,
        accel: torch.Tensor,
        alpha_l: torch.Tensor,
        rot: torch.Tensor,
        params: Params,
        damped: list[tuple[torch.Tensor, torch.Tensor]],
        h: float | torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Implicit integration of linear damping over one physics step ``h`` [s]
        (``physics_dt`` if None; a (B, 1, 1) tensor steps each assembly by its own).

        With the damping's wrench already among the forces, ``M a = f - b v`` (explicit)
        becomes ``(M + h b) a = f - b v`` per rod axis, i.e. ``(M + h b) v' = M v + h f``;
        likewise ``(I + h β) α_l = I α_l(explicit)``: MuJoCo's Euler integrator with joint
        damping. ``b``, ``β``: sums over ``damped``, each (3,) or (R, 3) in the rod frame.
        """
        h = self.physics_dt if h is None else h
        b = sum(d[0] for d in damped)
        beta = sum(d[1] for d in damped)
        mass = params.mass.unsqueeze(-1)  # (R, 1)
        a_l = rotate_t(rot, accel) * (mass / (mass + h * b))
        accel = rotate(rot, a_l)
        inertia = params.inertia
        return accel, alpha_l * (inertia / (inertia + h * beta))

    def step(
        self,
        state: State,
        params: Params,
        control: torch.Tensor | None = None,
        cables: torch.Tensor | None = None,
        winches: torch.Tensor | None = None,
    ) -> State:
        """Advance every assembly in the batch by ``dt``, in ``substeps`` physics steps.

        ``winches``: the winch motors' commands, (B, W) in [-1, 1] (clipped; None holds
        them at 0). With winches the returned state carries the winch state
        (:attr:`State.winch`); a state without one starts from
        :func:`~tensegrity_env.engine.winch.initial_winch_state`.
        """
        if self.native_step is not None:
            winch = state.winch
            if winch is None and self.winch_springs.numel():
                winch = initial_winch_state(self.topology, params, state.batch_size)
            out = self.native_step(state.tensors(), params, control, cables, winch, winches)
            if out is not None:
                x, wound = out
                return State(x[..., 0:3], x[..., 3:6], x[..., 6:10], x[..., 10:13], wound)
        return self._integrate(
            state, params, self.substeps, self.physics_dt, control, cables, winches
        )

    def _integrate(
        self,
        state: State,
        params: Params,
        n: int,
        h: float | torch.Tensor,
        control: torch.Tensor | None,
        cables: torch.Tensor | None,
        winches: torch.Tensor | None,
    ) -> State:
        """``n`` physics steps of ``h`` [s] (a float, or (B, 1, 1) per assembly), the
        commands held."""
        winch = state.winch
        if winch is None and self.winch_springs.numel():
            winch = initial_winch_state(self.topology, params, state.batch_size)
        h_winch = h if isinstance(h, float) else h.reshape(-1, 1)  # (B, 1) against (B, W)
        for _ in range(n):
            # forces with the rest lengths at the step's start (wound springs from the winch state)
            acting = (
                params if winch is None else wound_rest_lengths(params, self.winch_springs, winch)
            )
            accel, alpha_l, omega_l = self.accelerations(state, acting, control, cables, h)
            # integration: semi-implicit Euler (MuJoCo's Euler integrator)
            state = semi_implicit_euler(state, accel, alpha_l, omega_l, h, self.frame_origins)
            # winding: the rest lengths follow the motors
            if winch is not None:
                winch = winch_step(winch, params, winches, h_winch)
        return state if winch is None else state.with_winch(winch)

    def advance(
        self,
        state: State,
        params: Params,
        interval: float | torch.Tensor,
        control: torch.Tensor | None = None,
        cables: torch.Tensor | None = None,
        winches: torch.Tensor | None = None,
    ) -> State:
        """Advance every assembly by its own ``interval`` [s] (a float, or (B,)), the
        commands held (as :meth:`step`).

        ``n = substeps_for(max interval, physics_dt)`` physics steps, each assembly's
        ``interval / n`` long: at most ``physics_dt`` and ending exactly on the
        interval's end (never rounded to a grid). Steps by PyTorch (the C kernel's
        step length is fixed when it is packed).
        """
        iv = torch.as_tensor(interval, dtype=self.dtype, device=self.device).reshape(-1)
        if not bool((iv > 0).all()):
            raise ValueError(f"intervals must be > 0, got {iv.min().item():g} s")
        n = substeps_for(float(iv.max()), self.physics_dt)
        h = (iv / n).reshape(-1, 1, 1).expand(state.batch_size, 1, 1)
        return self._integrate(state, params, n, h, control, cables, winches)

    def rollout_at(
        self,
        state: State,
        params: Params,
        times: torch.Tensor | Sequence[float],
        control: torch.Tensor | None = None,
        cables: torch.Tensor | None = None,
        winches: torch.Tensor | None = None,
    ) -> State:
        """States at each sample time, stacked on dim 1: (B, T + 1, R, ·).

        ``times`` (T + 1,) or (B, T + 1) [s], increasing, the first the time of
        ``state``; the interval to each next sample is integrated by :meth:`advance`.
        Commands as in :meth:`rollout` ((B, T, ·), each held over its sample interval).
        """
        t = torch.as_tensor(times, dtype=self.dtype, device=self.device)
        t = t.expand(state.batch_size, -1) if t.dim() == 1 else t
        if self.winch_springs.numel() and state.winch is None:
            state = state.with_winch(initial_winch_state(self.topology, params, state.batch_size))
        states = [state]
        for k in range(t.shape[1] - 1):
            state = self.advance(
                state, params, t[:, k + 1] - t[:, k],
                None if control is None else control[:, k],
                None if cables is None else cables[:, k],
                None if winches is None else winches[:, k],
            )  # fmt: skip
            states.append(state)
        return State.stack(states, dim=1)

    def rollout(
        self,
        state: State,
        params: Params,
        n_steps: int,
        control: torch.Tensor | None = None,
        cables: torch.Tensor | None = None,
        winches: torch.Tensor | None = None,
    ) -> State:
        """States at steps 0..n_steps, stacked on dim 1: (B, n_steps + 1, R, ·).

        ``control`` is (B, n_steps, R, 3) or None; ``cables`` the acting cable commands
        (B, n_steps, C) or None; ``winches`` the winch motors' commands (B, n_steps, W)
        or None. With winches, the stacked winch states are (B, n_steps + 1, W, 2).
        """
        if self.winch_springs.numel() and state.winch is None:
            state = state.with_winch(initial_winch_state(self.topology, params, state.batch_size))
        states = [state]
        for t in range(n_steps):
            state = self.step(
                state,
                params,
                None if control is None else control[:, t],
                None if cables is None else cables[:, t],
                None if winches is None else winches[:, t],
            )
            states.append(state)
        return State.stack(states, dim=1)
