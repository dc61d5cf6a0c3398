"""The changing state of a batch of spring-rod assemblies."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from tensegrity_env.rotations import quat_to_matrix


@dataclass(frozen=True)
class State:
    """Rod states, batched over a leading dimension ``B``.

    Attributes:
        p: centre-of-mass positions, (B, R, 3) [m], world frame.
        v: centre-of-mass linear velocities, (B, R, 3) [m/s], world frame.
        q: orientations of each rod's principal frame, unit quaternions (w, x, y, z),
            (B, R, 4); ``x_world = R(q) x_rod``.
        omega: angular velocities, (B, R, 3) [rad/s], **world frame**.
        winch: the winches' state, (B, W, 2): each wound spring's rest length [m] and its
            motor's winding speed [m/s] (:mod:`tensegrity_env.engine.winch`); None
            without winches, or for winches at rest at their declared rest lengths.
    """

    p: torch.Tensor
    v: torch.Tensor
    q: torch.Tensor
    omega: torch.Tensor
    winch: torch.Tensor | None = None

    @classmethod
    def from_numpy(
        cls,
        p: np.ndarray,
        v: np.ndarray,
        q: np.ndarray,
        omega: np.ndarray,
        dtype: torch.dtype = torch.float64,
        device: str | torch.device = "cpu",
    ) -> State:
        def t(x: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.asarray(x), dtype=dtype, device=device)

        return cls(t(p), t(v), t(q), t(omega))

    def numpy(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k).detach().cpu().numpy() for k in ("p", "v", "q", "omega")}

    @property
    def batch_size(self) -> int:
        return int(self.p.shape[0])

    def to(
        self, dtype: torch.dtype | None = None, device: str | torch.device | None = None
    ) -> State:
        winch = None if self.winch is None else self.winch.to(dtype=dtype, device=device)
        p, v, q, omega = (x.to(dtype=dtype, device=device) for x in self.tensors())
        return State(p, v, q, omega, winch=winch)

    def rotation(self) -> torch.Tensor:
        """``R(q)``, (B, R, 3, 3): the matrix the integrator computed for this state
        (:meth:`remember_rotation`) if it did, else computed here."""
        rot = self.__dict__.get("_rotation")
        return quat_to_matrix(self.q) if rot is None else rot

    def remember_rotation(self, rot: torch.Tensor) -> State:
        """This state, keeping ``rot`` = ``R(q)`` (B, R, 3, 3) for :meth:`rotation` (the
        next step's kinematics need the matrix the integration step just computed)."""
        object.__setattr__(self, "_rotation", rot)
        return self

    def with_winch(self, winch: torch.Tensor | None) -> State:
        """This rod state with the winch state ``winch`` (B, W, 2) (keeps :meth:`rotation`)."""
        out = State(self.p, self.v, self.q, self.omega, winch=winch)
        rot = self.__dict__.get("_rotation")
        return out if rot is None else out.remember_rotation(rot)

    def tensors(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The rod tensors ``(p, v, q, omega)`` (not the winch state)."""
        return (self.p, self.v, self.q, self.omega)

    def index(self, idx: torch.Tensor | slice | int) -> State:
        """Select batch entries (keeps the batch dimension for tensor/slice indices)."""
        winch = None if self.winch is None else self.winch[idx]
        p, v, q, omega = (x[idx] for x in self.tensors())
        return State(p, v, q, omega, winch=winch)

    @staticmethod
    def stack(states: list[State], dim: int = 1) -> State:
        """Stack a sequence of states along a new time dimension: (B, T, R, ·); the winch
        states too where every state has one."""
        winches = [s.winch for s in states if s.winch is not None]
        winch = torch.stack(winches, dim=dim) if len(winches) == len(states) else None
        p, v, q, omega = (
            torch.stack(xs, dim=dim) for xs in zip(*(s.tensors() for s in states), strict=True)
        )
        return State(p, v, q, omega, winch=winch)
