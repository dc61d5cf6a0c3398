"""Least squares on the normal equations, with identifiability made explicit.

The system ``A θ = 0`` is homogeneous: with no force of known size acting, ``M, I, K,
c, h`` share one unknown scale. Fixing some unknowns (an *anchor* such as a weighed
rod mass, or parameters frozen from an earlier fit) makes it ``A_f θ_f = -A_x θ_x``.
Columns are equilibrated (scaled to unit norm) and the eigen-decomposition of the
scaled normal matrix gives the rank, the condition number and the directions the
data cannot see. A parameter is *not identifiable* when it has a component along
such a direction, or when its whole contribution to the equations is round-off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

#: eigenvalues of the equilibrated normal matrix below this fraction of the largest
#: are null directions (singular values below ~1e-7 of the largest).
NULL_EIG_RTOL = 1e-14
#: a parameter whose contribution ‖A_i θ_i‖ is below this fraction of the largest
#: contribution only explains round-off: it was never excited.
EXCITATION_RTOL = 1e-9
#: an unknown whose squared share in the null directions exceeds this is not
#: identifiable (a component of 1e-3 of a direction the data does not see)
NULL_SHARE = 1e-6


@dataclass(frozen=True)
class Solution:
    """Result of :func:`solve_constrained`.

    Attributes:
        theta: all unknowns, fixed ones included, (P,); NaN where not identifiable.
        stderr: standard error of each free unknown from the residual variance (floored
            at the round-off of the normal equations: > 0 even on exact data), (P,);
            0 for fixed ones, NaN where not identifiable.
        identifiable: bool mask, (P,); fixed unknowns count as identifiable.
        fixed: bool mask of unknowns that were given (anchors, frozen), (P,).
        condition_number: of the equilibrated design on the identifiable subspace.
        null_dims: number of directions the data cannot see.
        rss: residual sum of squares of the equations.
        n_rows: number of equations.
    """

    theta: np.ndarray
    stderr: np.ndarray
    identifiable: np.ndarray
    fixed: np.ndarray
    condition_number: float
    null_dims: int
    rss: float
    n_rows: int


@dataclass(frozen=True)
class Equilibrated:
    """The eigen-decomposition of a symmetric positive semi-definite matrix ``N`` (P, P)
    after equilibration, ``N_s = D⁻¹ N D⁻¹`` with ``D = diag(N)^½`` (unit diagonal):
    units and scales of the unknowns drop out, so the eigenvalues measure how far the
    unknowns are from collinear, not how large their columns are.

    Attributes:
        scale: ``diag(N)^½`` (P,), 1 where the diagonal is 0.
        vectors: eigenvectors of ``N_s`` kept (seen), (P, k).
        values: their eigenvalues, (k,).
        unseen: bool (P,): unknowns with a share above :data:`NULL_SHARE` in a null
            direction (eigenvalue below ``rtol`` of the largest) or a zero diagonal.
        null_dims: number of null directions.
    """

    scale: torch.Tensor
    vectors: torch.Tensor
    values: torch.Tensor
    unseen: torch.Tensor
    null_dims: int

    @classmethod
    def of(cls, N: torch.Tensor, rtol: float = NULL_EIG_RTOL) -> Equilibrated:
        diag = torch.diagonal(N).clamp_min(0)
        excited = diag > 0
        d = torch.where(excited, diag.sqrt(), torch.ones_like(diag))
        Ns = N / (d[:, None] * d[None, :])
        lam, V = torch.linalg.eigh(0.5 * (Ns + Ns.T))
        lam_max = float(lam.max()) if lam.numel() else 1.0
        keep = lam > rtol * lam_max
        Vn = V[:, ~keep]
        unseen = ((Vn * Vn).sum(1) > NULL_SHARE) | ~excited
        return cls(d, V[:, keep], lam[keep], unseen, int((~keep).sum()))

    def solve(self, b: torch.Tensor) -> torch.Tensor:
        """``N⁺ b`` (P,) on the seen subspace, for ``b`` (P,)."""
        V, d = self.vectors, self.scale
        return (V @ ((V.T @ (b / d)) / self.values)) / d

    def inverse(self) -> torch.Tensor:
        """``N⁺`` (P, P) on the seen subspace (the covariance up to the noise variance)."""
        V, d = self.vectors, self.scale
        return (V / self.values) @ V.T / (d[:, None] * d[None, :])

    @property
    def condition_number(self) -> float:
        """Of the equilibrated design (square root of the eigenvalues' ratio) on the
        seen subspace; inf when nothing is seen."""
        lam = self.values
        return float(np.sqrt(float(lam.max()) / float(lam.min()))) if lam.numel() else float("inf")


def solve_constrained(normal: torch.Tensor, fixed: dict[int, float], n_rows: int) -> Solution:
    """Solve ``min ‖A θ‖²`` subject to ``θ_i = fixed[i]``, given ``N = AᵀA`` (P, P)."""
    N = normal.double()
    P = N.shape[0]
    is_fixed = np.zeros(P, dtype=bool)
    is_fixed[list(fixed)] = True
    theta_x = torch.zeros(P, dtype=torch.float64)
    for i, v in fixed.items():
        theta_x[i] = v
    f_idx = torch.as_tensor(np.flatnonzero(~is_fixed))
    x_idx = torch.as_tensor(np.flatnonzero(is_fixed))
    Nff = N[f_idx][:, f_idx]
    b = -(N[f_idx][:, x_idx] @ theta_x[x_idx])

    eq = Equilibrated.of(Nff)
    theta_f = eq.solve(b)
    # parameters with a component along a null direction are not identifiable
    unknown = eq.unseen

    theta = theta_x.clone()
    theta[f_idx] = theta_f
    contribution = theta.abs() * torch.diagonal(N).clamp_min(0).sqrt()
    weak = contribution < EXCITATION_RTOL * contribution.max()
    unknown = unknown | weak[f_idx]

    rss = float(theta @ N @ theta)
    dof = max(n_rows - len(f_idx), 1)
    # θᵀNθ cancels to round-off of the largest squared column on exact data (it can come
    # out negative): floor it there, so an exact fit states round-off errors, not 0
    floor = float(np.finfo(np.float64).eps * torch.diagonal(N).clamp_min(0).max())
    sigma2 = max(rss, floor) / dof
    stderr_f = torch.sqrt(sigma2 * torch.diagonal(eq.inverse()).clamp_min(0))

    theta_np = theta.numpy().copy()
    stderr = np.zeros(P)
    stderr[f_idx.numpy()] = stderr_f.numpy()
    ident = np.ones(P, dtype=bool)
    ident[f_idx.numpy()[unknown.numpy()]] = False
    theta_np[~ident] = np.nan
    stderr[~ident] = np.nan
    return Solution(
        theta=theta_np,
        stderr=stderr,
        identifiable=ident,
        fixed=is_fixed,
        condition_number=eq.condition_number,
        null_dims=eq.null_dims,
        rss=rss,
        n_rows=n_rows,
    )


def fit_linear_network(
    normal: torch.Tensor,
    fixed: dict[int, float],
    n_rows: int,
    epochs: int = 50,
    seed: int = 0,
) -> np.ndarray:
    """The paper's solver: a single linear layer (no activation) trained on the MSE loss.

    The layer's weights are the free unknowns; its inputs are the (equilibrated)
    design columns and its target the known-parameter side of each equation. The MSE
    over all ``n_rows`` equations is evaluated exactly on ``P`` compressed equations
    ``C = Lᵀ`` with ``AᵀA = L Lᵀ`` (Cholesky), which have the same loss up to a constant
    and keep the residual numerically exact, so an epoch costs O(P²), not O(rows).
    Minimised with L-BFGS. Returns θ (P,) with the fixed values in place.
    """
    N = normal.double()
    P = N.shape[0]
    free = np.array([i not in fixed for i in range(P)])
    f_idx, x_idx = torch.as_tensor(np.flatnonzero(free)), torch.as_tensor(np.flatnonzero(~free))
    theta_x = torch.tensor([fixed[int(i)] for i in x_idx], dtype=torch.float64)
    Nff = N[f_idx][:, f_idx]
    b = -(N[f_idx][:, x_idx] @ theta_x)
    diag = torch.diagonal(Nff).clamp_min(0)
    d = torch.where(diag > 0, diag.sqrt(), torch.ones_like(diag))
    Ns, bs = Nff / (d[:, None] * d[None, :]), b / d
    chol = torch.linalg.cholesky(Ns + 1e-13 * torch.eye(len(f_idx), dtype=torch.float64))
    inputs = chol.T  # compressed equations: ‖A_s w - y‖² = ‖Lᵀ w - z‖² + const
    target = torch.linalg.solve_triangular(chol, bs[:, None], upper=False)[:, 0]

    torch.manual_seed(seed)
    layer = torch.nn.Linear(len(f_idx), 1, bias=False, dtype=torch.float64)
    torch.nn.init.zeros_(layer.weight)
    opt = torch.optim.LBFGS(
        layer.parameters(), lr=1.0, max_iter=200, tolerance_grad=1e-300,
        tolerance_change=1e-300, history_size=50, line_search_fn="strong_wolfe",
    )  # fmt: skip

    def closure() -> torch.Tensor:
        opt.zero_grad()
        # n_rows * MSE, up to a constant (the 1/n_rows factor would only shrink gradients)
        loss = ((layer(inputs)[:, 0] - target) ** 2).sum()
        loss.backward()
        return loss

    previous = float("inf")
    for _ in range(epochs):  # each L-BFGS call runs up to max_iter iterations
        loss = float(opt.step(closure).detach())
        if previous - loss <= 1e-12 * abs(previous):
            break
        previous = loss
    theta = torch.zeros(P, dtype=torch.float64)
    theta[x_idx] = theta_x
    theta[f_idx] = layer.weight.detach()[0] / d
    return theta.numpy()
