"""Koopman+Int: a linear operator on lifted observables predicts accelerations.

Two dictionaries of observables (per rod; float64), chosen by ``KoopmanConfig.basis``:

``"polynomial"`` (the baseline, extended dynamic mode decomposition with a generic
dictionary): for every spring on the rod's end caps, the relative position and velocity
of its far end seen from the rod's end cap, ``Δp = σ (x_b - x_a)`` and ``Δv`` (``σ`` =
+1 at node a, -1 at node b), standardised per rod and slot, in the world frame (for the
linear acceleration) and in the rod frame (for the angular one); their monomials up to
``degree`` (3 by default: the spring force is cubic to leading order in Δp, since
``|Δp| - l0 ≈ (|Δp|² - l0²) / 2 l0``) that are at most linear in Δv (damping), with no
cross terms between springs (spring forces add up); the rod-frame
angular velocity ``ω_l`` and its quadratic monomials (gyroscopic term); a constant. This
is what one designs knowing only that springs couple end caps: a polynomial can
approximate the spring law ``K (|Δp| - l0) Δp/|Δp|`` near the training states but not
express it.

``"spring_law"`` (an ablation, not a baseline): the paper's 3-D to 1-D reduction built
in: for every incident spring, the monomials up to ``degree`` of its standardised
elongation ``δ = l - l̄`` (``l̄``: the training mean length) and rate ``l̇`` —
``1, δ, l̇, δ², δ l̇, l̇², ...`` — each times the spring direction projected on the world
axes (``σ e_s``) and on the rod axes (``R^T σ e_s``), plus ``ω_l``, its quadratics and a
constant. These contain the linear spring law exactly, so with enough data this model
becomes ours up to round-off: it shows what the basis, not the regression, contributes.

For rod ``r`` the operator ``A_r`` (6 x n_features) maps the observables to
``[a, α_l]``: linear acceleration [m/s^2] (world) and angular acceleration [rad/s^2]
(rod frame), which the integration module
(:func:`~tensegrity_env.engine.integration.semi_implicit_euler`) turns into the next
state. ``A_r`` is fitted by ridge regression on standardised observables, with the ridge
weight picked from a grid by the validation error; the regression is solved through a
QR factor accumulated chunk by chunk (exact fits stay exact, and all training
transitions fit in memory).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from identification.data.dataset import Dataset
from identification.experiments.baselines.common import (
    Geometry,
    local_angular_velocity,
    sample_transitions,
)
from tensegrity_env.engine import State
from tensegrity_env.engine.forces import spring_frames
from tensegrity_env.engine.integration import semi_implicit_euler
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.io_utils import InputError

#: The dictionaries of observables (see the module docstring) and the model name of each.
BASES: dict[str, str] = {
    "polynomial": "Koopman+Int",
    "spring_law": "Koopman+Int (spring-law basis)",
}

#: Ridge weights tried, relative to unit-variance observables.
RIDGE_GRID: tuple[float, ...] = (1e-12, 1e-10, 1e-8, 1e-6, 1e-4, 1e-2, 1.0, 100.0)


@dataclass(frozen=True)
class KoopmanConfig:
    """Hyperparameters of Koopman+Int.

    Attributes:
        basis: ``"polynomial"`` (generic dictionary, the baseline) or ``"spring_law"``
            (the spring law built in, an ablation); see the module docstring.
        degree: highest total degree of the monomials per spring (the spring-law basis
            is exact from degree 1; the polynomial one needs 3 for the leading order).
        ridge_grid: ridge weights tried (the validation error picks one).
        max_train: training transitions (random subset; None: all).
        max_val: validation transitions for choosing the ridge weight.
        seed: seed of the subsets.
        chunk: transitions per chunk while accumulating the QR factor.
    """

    basis: str = "polynomial"
    degree: int = 3
    ridge_grid: tuple[float, ...] = RIDGE_GRID
    max_train: int | None = None
    max_val: int | None = 20_000
    seed: int = 0
    chunk: int = 10_000

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class RidgeCurve:
    """Validation error (mean standardised squared error) for each ridge weight."""

    ridge: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    best: float = float("nan")
    seconds: float = 0.0
    n_train: int = 0
    n_val: int = 0
    n_features: int = 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def incident_springs(geometry: Geometry) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per rod, the springs on its end caps: indices, signs and a mask, each (R, K)."""
    R = geometry.n_rods
    lists: list[list[tuple[int, float]]] = [[] for _ in range(R)]
    for s, (a, b) in enumerate(
        zip(geometry.node_a.tolist(), geometry.node_b.tolist(), strict=True)
    ):
        if a < 2 * R:
            lists[a // 2].append((s, 1.0))
        if b < 2 * R:
            lists[b // 2].append((s, -1.0))
    K = max(1, max(len(x) for x in lists))
    idx = torch.zeros(R, K, dtype=torch.long)
    sign = torch.zeros(R, K, dtype=torch.float64)
    for r, x in enumerate(lists):
        for k, (s, sg) in enumerate(x):
            idx[r, k], sign[r, k] = s, sg
    return idx, sign, sign != 0


def monomial_indices(degree: int) -> list[tuple[int, ...]]:
    """Monomials of (Δp, Δv) (variables 0-2 and 3-5) of degree 1..``degree``, at most
    linear in Δv (forces that depend on velocity through damping), as variable indices."""
    return [
        c
        for d in range(1, degree + 1)
        for c in itertools.combinations_with_replacement(range(6), d)
        if sum(i >= 3 for i in c) <= 1
    ]


def monomial_powers(degree: int) -> list[tuple[int, int]]:
    """Exponents (i, j) of ``δ^i l̇^j`` with ``i + j <= degree``, constant first."""
    return [(i, d - i) for d in range(degree + 1) for i in range(d, -1, -1)]


class KoopmanInt:
    """Koopman operator on lifted observables + the integration module.

    Args:
        config: hyperparameters (:class:`KoopmanConfig`); ``config.basis`` picks the
            dictionary and the model's name (:data:`BASES`).
    """

    def __init__(self, config: KoopmanConfig | None = None) -> None:
        self.config = config or KoopmanConfig()
        if self.config.basis not in BASES:
            raise InputError(f"Koopman+Int: unknown basis {self.config.basis!r} ({sorted(BASES)})")
        self.name = BASES[self.config.basis]

    # -------------------------------------------------------------- observables
    def observables(self, state: State, kin: Kinematics | None = None) -> torch.Tensor:
        """Lifted observables per rod, (B, R, n_features), float64."""
        kin = self.geometry_.kinematics(state) if kin is None else kin
        wl = local_angular_velocity(state, kin.rot)
        quad = torch.stack([wl[..., i] * wl[..., j] for i in range(3) for j in range(i, 3)], -1)
        if self.config.basis == "polynomial":
            per_spring = self._polynomial_observables(kin)
        else:
            per_spring = self._spring_law_observables(kin)
        return torch.cat([per_spring, wl, quad], dim=-1)

    def _relative_motion(self, kin: Kinematics) -> torch.Tensor:
        """Far spring ends seen from each rod's end caps, (B, R, K, 12): Δp, Δv world, rod."""
        g = self.geometry_
        idx, sign, _ = self.incident_
        dp = (kin.x[:, g.node_b] - kin.x[:, g.node_a])[:, idx] * sign[..., None]  # (B,R,K,3)
        dv = (kin.xd[:, g.node_b] - kin.xd[:, g.node_a])[:, idx] * sign[..., None]
        world = torch.cat([dp, dv], dim=-1)
        local = torch.einsum("brji,brkcj->brkci", kin.rot, world.unflatten(-1, (2, 3)))
        return torch.cat([world, local.flatten(-2)], dim=-1)

    def _polynomial_observables(self, kin: Kinematics) -> torch.Tensor:
        """Monomials of the standardised relative motion per spring, (B, R, K * 2 * M)."""
        z = (self._relative_motion(kin) - self.motion_mean_) / self.motion_std_
        mask = self.incident_[2].to(z.dtype)[..., None]
        feats = []
        by_degree: dict[int, list[tuple[int, ...]]] = {}
        for c in self.monomials_:
            by_degree.setdefault(len(c), []).append(c)
        for part in (z[..., :6], z[..., 6:]):  # world frame, rod frame
            for monos in by_degree.values():  # one gather and product per degree
                idx = torch.tensor(monos, device=part.device)  # (M_d, d)
                feats.append(part[..., idx].prod(-1) * mask)
        B, R = z.shape[:2]
        return torch.cat(feats, dim=-1).reshape(B, R, -1)

    def _spring_law_observables(self, kin: Kinematics) -> torch.Tensor:
        """Monomials of (δ, l̇) times projected spring directions, (B, R, K * M * 6)."""
        g = self.geometry_
        frame = spring_frames(kin, g.node_a, g.node_b)
        delta = (frame.length - self.length_mean_) / self.length_std_  # (B, S)
        rate = frame.rate / self.rate_std_
        idx, sign, mask = self.incident_
        d, r = delta[:, idx], rate[:, idx]  # (B, R, K)
        mono = torch.stack([d**i * r**j for i, j in self.powers_], dim=-1)  # (B, R, K, M)
        mono = mono * mask.to(mono.dtype)[..., None]
        u = frame.axis[:, idx] * sign[..., None]  # (B, R, K, 3) world
        w = torch.einsum("brji,brkj->brki", kin.rot, u)  # rod frame
        per_spring = torch.cat(
            [mono[..., None] * u[..., None, :], mono[..., None] * w[..., None, :]], dim=-1
        )  # (B, R, K, M, 6)
        B, R = per_spring.shape[:2]
        return per_spring.reshape(B, R, -1)

    def _targets(self, s0: State, s1: State, kin: Kinematics) -> torch.Tensor:
        w0 = local_angular_velocity(s0, kin.rot)
        w1 = local_angular_velocity(s1)
        return torch.cat([(s1.v - s0.v) / self.dt_, (w1 - w0) / self.dt_], dim=-1)

    def _chunks(self, s0: State, s1: State, chunk: int | None = None) -> Any:
        c = chunk or self.config.chunk
        for lo in range(0, s0.batch_size, c):
            a, b = s0.index(slice(lo, lo + c)), s1.index(slice(lo, lo + c))
            kin = self.geometry_.kinematics(a)
            yield self.observables(a, kin), self._targets(a, b, kin)

    # -------------------------------------------------------------- fitting
    def fit(self, dataset: Dataset, split: str = "train", val_split: str = "val") -> KoopmanInt:
        """Ridge regression of accelerations on observables; ridge weight by validation."""
        t0 = time.perf_counter()
        cfg = self.config
        if val_split not in dataset.splits:
            raise InputError(f"{self.name}: needs a '{val_split}' split to pick the ridge weight")
        self.geometry_ = Geometry(dataset.topology)
        self.dt_ = float(dataset.dt)
        self.incident_ = incident_springs(self.geometry_)
        self.powers_ = monomial_powers(cfg.degree)
        self.monomials_ = monomial_indices(cfg.degree)
        s0, s1, _ = sample_transitions(dataset.split(split), cfg.max_train, cfg.seed)
        va0, va1, _ = sample_transitions(dataset.split(val_split), cfg.max_val, cfg.seed + 1)
        self._spring_scales(s0)
        self._standardisation(s0, s1)
        tri = self._accumulate(s0, s1)
        curve = RidgeCurve(
            n_train=s0.batch_size, n_val=va0.batch_size, n_features=int(self.x_mean_.shape[-1])
        )
        solutions = self._ridge_solutions(tri, cfg.ridge_grid, s0.batch_size)
        losses = self._val_losses(va0, va1, solutions)
        best = int(np.nanargmin(losses))
        self.weight_, self.bias_ = solutions[best]
        curve.ridge, curve.val_loss = list(cfg.ridge_grid), [float(x) for x in losses]
        curve.best = float(cfg.ridge_grid[best])
        curve.seconds = time.perf_counter() - t0
        self.history_ = curve
        return self

    def _spring_scales(self, s0: State) -> None:
        g = self.geometry_
        sub = s0.index(slice(0, 50_000))
        kin = g.kinematics(sub)
        motion = self._relative_motion(kin)  # (n, R, K, 12)
        self.motion_mean_ = motion.mean(0)
        spread = torch.nan_to_num(motion.std(0, correction=0))
        self.motion_std_ = spread.clamp_min(1e-9)
        frame = spring_frames(kin, g.node_a, g.node_b)
        self.length_mean_ = frame.length.mean(0)
        self.length_std_ = torch.nan_to_num(frame.length.std(0, correction=0)).clamp_min(1e-9)
        self.rate_std_ = torch.nan_to_num(frame.rate.std(0, correction=0)).clamp_min(1e-9)

    def _standardisation(self, s0: State, s1: State, n: int = 20_000) -> None:
        """Observable and target means / stds (per rod) from a subset of the transitions."""
        x, y = next(self._chunks(s0.index(slice(0, n)), s1.index(slice(0, n)), chunk=n))
        self.x_mean_ = x.mean(0)  # (R, F)
        std = torch.nan_to_num(x.std(0, correction=0))  # one transition: no spread
        self.x_std_ = torch.where(std > 1e-12, std, torch.ones_like(std))
        ystd = torch.nan_to_num(y.std(0, correction=0))  # (R, 6); floor as in Standardizer
        self.target_std_ = ystd.clamp_min(1e-3 * float(ystd.max()) + 1e-30)

    def _accumulate(self, s0: State, s1: State) -> torch.Tensor:
        """Per rod, the triangular factor of ``[1 Z | Y]`` (R, F+7, F+7) by chunked QR.

        ``1`` is the intercept column, ``Z`` the standardised observables and ``Y`` the
        accelerations; QR (not normal equations) keeps the exact fits exact.
        """
        tri = None
        for x, y in self._chunks(s0, s1):
            z = (x - self.x_mean_) / self.x_std_
            rows = torch.cat([torch.ones_like(z[..., :1]), z, y], dim=-1).transpose(0, 1)
            if tri is not None:
                rows = torch.cat([tri, rows], dim=1)
            tri = torch.linalg.qr(rows, mode="r")[1]
        assert tri is not None
        return tri

    def _ridge_solutions(
        self, tri: torch.Tensor, ridges: Sequence[float], n: int
    ) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Weights (R, F, 6) and biases (R, 6) minimising ``|Zw + b - Y|² + lam n |w|²``.

        With the factor of ``[1 Z | Y]``, its first row fixes the (unshrunk) intercept for
        any ``w``, and the rows below are a ridge problem in ``w`` alone, solved for every
        weight from one SVD of the (F, F) triangle: ``w = V diag(s / (s² + lam n)) Uᵀ c``.
        """
        R, F = tri.shape[0], tri.shape[-1] - 7
        if tri.shape[1] < tri.shape[2]:  # fewer transitions than columns: pad the factor
            tri = torch.cat([tri, tri.new_zeros(R, tri.shape[2] - tri.shape[1], tri.shape[2])], 1)
        r00, r0z, c0 = tri[:, 0, 0], tri[:, 0, 1 : F + 1], tri[:, 0, F + 1 :]
        a, c = tri[:, 1 : F + 1, 1 : F + 1], tri[:, 1 : F + 1, F + 1 :]
        u, sv, vh = torch.linalg.svd(a)
        uc = u.transpose(1, 2) @ c  # (R, F, 6)
        out = []
        for lam in ridges:
            gain = sv / (sv**2 + lam * n)
            w = vh.transpose(1, 2) @ (gain[..., None] * uc)  # standardised weights
            b = (c0 - torch.einsum("rf,rfk->rk", r0z, w)) / r00[:, None]
            weight = w / self.x_std_[:, :, None]
            out.append((weight, b - torch.einsum("rf,rfk->rk", self.x_mean_, weight)))
        return out

    def _val_losses(
        self, s0: State, s1: State, solutions: Sequence[tuple[torch.Tensor, torch.Tensor]]
    ) -> np.ndarray:
        sq = np.zeros(len(solutions))
        for x, y in self._chunks(s0, s1):
            for i, (w, b) in enumerate(solutions):
                pred = torch.einsum("brf,rfk->brk", x, w) + b
                sq[i] += float((((pred - y) / self.target_std_) ** 2).sum())
        n = s0.batch_size * self.geometry_.n_rods * 6
        sq = sq / n
        sq[~np.isfinite(sq)] = np.nan
        return sq

    # -------------------------------------------------------------- prediction
    def predict(self, state: State) -> State:
        """One step: observables -> [a, α_l] -> semi-implicit Euler (float64)."""
        if not hasattr(self, "weight_"):
            raise RuntimeError(f"{self.name}: call fit(dataset) first")
        kin = self.geometry_.kinematics(state)
        out = torch.einsum("brf,rfk->brk", self.observables(state, kin), self.weight_) + self.bias_
        omega_l = local_angular_velocity(state, kin.rot)
        return semi_implicit_euler(state, out[..., :3], out[..., 3:], omega_l, self.dt_)
