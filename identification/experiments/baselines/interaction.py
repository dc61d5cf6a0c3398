"""Interaction: the paper's improved Interaction Network (Battaglia et al. 2016).

Two MLPs, as in the paper's Fig. 6:

* **MLP1 (relation / force model)**, shared by all springs: the spring's 3-D relative
  position and velocity ``Δp^m = x_b - x_a`` [m] and ``Δv^m = ẋ_b - ẋ_a`` [m/s] (world
  frame, standardised) and a one-hot spring id (the relation attribute: springs have
  their own stiffness) -> a 3-D force on the spring's node a; node b receives the
  opposite force (Newton's third law). We use the 3-D form on purpose: the network must
  learn that a spring pulls along its axis, which is what the paper's engine builds in.
* **aggregation**: each rod receives the sum of the forces on its two end caps and
  their torque ``Σ arm × f`` about its centre (world frame).
* **MLP2 (object model)**, shared by all rods: the rod's raw state without its absolute
  position (``v`` [m/s], ``q``, ``ω`` [rad/s], world; the dynamics are translation
  invariant once the springs are given), the received force and torque, and a one-hot
  rod id (rods have their own mass) -> the state change ``S_{t+1} - S_t`` (13 numbers,
  standardised); ``q`` is renormalised after the update.

Trained end to end on the MSE of the standardised next-state change; forces are latent.
:class:`RelationalBaseline` holds what this and
:class:`~identification.experiments.baselines.interaction_int.InteractionInt` share.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from identification.data.dataset import Dataset
from identification.experiments.baselines.common import Geometry, sample_transitions
from identification.experiments.baselines.training import (
    History,
    Standardizer,
    TrainConfig,
    mlp,
    train,
)
from tensegrity_env.engine import State
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.io_utils import InputError


class RelationalCore(nn.Module):
    """MLP1 -> aggregation -> MLP2 on standardised float32 inputs.

    Args:
        geometry: the assembly (spring incidence).
        rod_in: rod features per rod given to MLP2 (besides force, torque and id).
        n_out: outputs per rod.
        hidden, layers: MLP sizes.
        rod_frame_torque: give MLP2 the torque in the rod frame ``R^T τ`` (else world).
    """

    spring_id: torch.Tensor  # buffers: one-hot spring (S, S) and rod (R, R) ids
    rod_id: torch.Tensor

    def __init__(
        self,
        geometry: Geometry,
        rod_in: int,
        n_out: int,
        hidden: int,
        layers: int,
        rod_frame_torque: bool,
    ) -> None:
        super().__init__()
        self.geometry = geometry
        S, R = geometry.n_springs, geometry.n_rods
        self.mlp1 = mlp(6 + S, 3, hidden, layers)
        self.mlp2 = mlp(rod_in + 6 + R, n_out, hidden, layers)
        self.rod_frame_torque = rod_frame_torque
        self.register_buffer("spring_id", torch.eye(S))
        self.register_buffer("rod_id", torch.eye(R))

    def forward(
        self, spring_in: torch.Tensor, rod_in: torch.Tensor, arms: torch.Tensor, rot: torch.Tensor
    ) -> torch.Tensor:
        """Standardised outputs (B, R, n_out).

        Args:
            spring_in: standardised (Δp^m, Δv^m), (B, S, 6).
            rod_in: standardised rod features, (B, R, rod_in).
            arms: world end-cap offsets, (B, R, 2, 3) [m].
            rot: rod rotations R(q), (B, R, 3, 3).
        """
        B = spring_in.shape[0]
        sid = self.spring_id.expand(B, -1, -1)
        force = self.mlp1(torch.cat([spring_in, sid], dim=-1))  # (B, S, 3) on node a
        f_rod, tau = self.geometry.wrench(force, arms)
        if self.rod_frame_torque:
            tau = torch.einsum("brji,brj->bri", rot, tau)
        rid = self.rod_id.expand(B, -1, -1)
        return self.mlp2(torch.cat([rod_in, f_rod, tau, rid], dim=-1))


class RelationalBaseline:
    """Shared fitting and prediction of the two Interaction Networks.

    Subclasses define :meth:`rod_features`, :meth:`targets` and :meth:`advance`.

    Args:
        config: hyperparameters (:class:`TrainConfig`).
        progress: show a progress bar over epochs.
    """

    name = "relational"
    rod_in = 0
    n_out = 0
    rod_frame_torque = False

    def __init__(self, config: TrainConfig | None = None, progress: bool = False) -> None:
        self.config = config or TrainConfig()
        self.progress = progress

    # -------------------------------------------------------------- per subclass
    def rod_features(self, state: State, kin: Kinematics) -> torch.Tensor:
        """Raw MLP2 inputs per rod, (B, R, rod_in), float64."""
        raise NotImplementedError

    def targets(self, s0: State, s1: State, kin: Kinematics) -> torch.Tensor:
        """Raw training targets per rod, (B, R, n_out), float64."""
        raise NotImplementedError

    def advance(self, state: State, kin: Kinematics, out: torch.Tensor) -> State:
        """The next state from raw (de-standardised) outputs (B, R, n_out)."""
        raise NotImplementedError

    # -------------------------------------------------------------- shared
    def _inputs(
        self, state: State
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, Kinematics]:
        kin = self.geometry_.kinematics(state)
        dp, dv = self.geometry_.spring_vectors(kin)
        return torch.cat([dp, dv], dim=-1), self.rod_features(state, kin), kin.arms, kin.rot, kin

    def _tensors(self, s0: State, s1: State, chunk: int = 20_000) -> list[torch.Tensor]:
        parts: list[list[torch.Tensor]] = [[], [], [], [], []]
        for lo in range(0, s0.batch_size, chunk):
            a, b = s0.index(slice(lo, lo + chunk)), s1.index(slice(lo, lo + chunk))
            spring, rod, arms, rot, kin = self._inputs(a)
            for lst, x in zip(
                parts, (spring, rod, arms, rot, self.targets(a, b, kin)), strict=True
            ):
                lst.append(x.float())
        return [torch.cat(p) for p in parts]

    def fit(
        self, dataset: Dataset, split: str = "train", val_split: str = "val"
    ) -> RelationalBaseline:
        """Train on random transitions of ``split``, early-stopping on ``val_split``."""
        cfg = self.config
        if val_split not in dataset.splits:
            raise InputError(f"{self.name}: needs a '{val_split}' split for early stopping")
        torch.manual_seed(cfg.seed)
        self.geometry_ = Geometry(dataset.topology)
        self.dt_ = float(dataset.dt)
        tr0, tr1, _ = sample_transitions(dataset.split(split), cfg.max_train, cfg.seed)
        va0, va1, _ = sample_transitions(dataset.split(val_split), cfg.max_val, cfg.seed + 1)
        tr, va = self._tensors(tr0, tr1), self._tensors(va0, va1)
        self.spring_norm_ = Standardizer(tr[0])
        self.rod_norm_ = Standardizer(tr[1])
        self.target_norm_ = Standardizer(tr[4])
        for data in (tr, va):
            data[0] = self.spring_norm_(data[0])
            data[1] = self.rod_norm_(data[1])
            data[4] = self.target_norm_(data[4])
        self.core_ = RelationalCore(
            self.geometry_, self.rod_in, self.n_out, cfg.hidden, cfg.layers, self.rod_frame_torque
        )

        def loss(batch: Sequence[torch.Tensor]) -> torch.Tensor:
            spring, rod, arms, rot, target = batch
            return F.mse_loss(self.core_(spring, rod, arms, rot), target)

        self.history_: History = train(
            self.core_, loss, tr, va, cfg, desc=self.name, progress=self.progress
        )
        return self

    def predict(self, state: State) -> State:
        """One step from float64 states (B, R, ·); the MLPs run in float32."""
        if not hasattr(self, "core_"):
            raise RuntimeError(f"{self.name}: call fit(dataset) first")
        spring, rod, arms, rot, kin = self._inputs(state)
        with torch.no_grad():
            out = self.core_(
                self.spring_norm_(spring).float(),
                self.rod_norm_(rod).float(),
                arms.float(),
                rot.float(),
            )
        return self.advance(state, kin, self.target_norm_.inverse(out.double()))


class Interaction(RelationalBaseline):
    """The improved Interaction Network: MLP2 predicts the state change directly."""

    name = "Interaction"
    rod_in = 10  # v (3), q (4), omega (3)
    n_out = 13  # Δp (3), Δv (3), Δq (4), Δω (3)

    def rod_features(self, state: State, kin: Kinematics) -> torch.Tensor:
        return torch.cat([state.v, state.q, state.omega], dim=-1)

    def targets(self, s0: State, s1: State, kin: Kinematics) -> torch.Tensor:
        return torch.cat([s1.p - s0.p, s1.v - s0.v, s1.q - s0.q, s1.omega - s0.omega], dim=-1)

    def advance(self, state: State, kin: Kinematics, out: torch.Tensor) -> State:
        dp, dv, dq, dw = out.split((3, 3, 4, 3), dim=-1)
        q = state.q + dq
        return State(
            p=state.p + dp,
            v=state.v + dv,
            q=q / torch.linalg.vector_norm(q, dim=-1, keepdim=True),
            omega=state.omega + dw,
        )
