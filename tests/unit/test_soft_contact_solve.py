"""The per-rod contact problem: a batch solved only where its active set still changes."""

from __future__ import annotations

import torch

from tensegrity_env.effects.ground_contact import solve_soft_contacts


def _problems(seed: int, batch: tuple[int, ...], n: int = 8):
    g = torch.Generator().manual_seed(seed)
    M = torch.randn(*batch, n, n, generator=g, dtype=torch.float64)
    H = M @ M.transpose(-1, -2) + 0.5 * torch.eye(n, dtype=torch.float64)
    b = torch.randn(*batch, n, generator=g, dtype=torch.float64)
    mask = torch.rand(*batch, n, generator=g) < 0.6
    mask[0] = False  # a rod with no cap touching
    return H, b, mask


def test_batched_solution_meets_the_optimality_conditions():
    H, b, mask = _problems(0, (40, 6))
    f = solve_soft_contacts(H, b, mask)
    w = (H @ f.unsqueeze(-1)).squeeze(-1) + b
    assert f.shape == b.shape
    assert bool((f[~mask] == 0).all())  # no force off the mask
    assert bool((f >= 0).all())
    on = mask & (f > 0)
    assert float(w[on].abs().max()) < 1e-9  # stationary where the force acts
    assert float(w[mask & (f == 0)].min()) > -1e-9  # pushing would not lower the cost


def test_each_problem_solved_as_if_alone():
    H, b, mask = _problems(1, (30,))
    together = solve_soft_contacts(H, b, mask)
    alone = torch.stack([solve_soft_contacts(H[i : i + 1], b[i : i + 1], mask[i : i + 1])[0]
                         for i in range(30)])  # fmt: skip
    assert torch.allclose(together, alone, rtol=0, atol=1e-12)


def test_gradients_flow_through_the_subset_solves():
    H, b, mask = _problems(2, (10,))
    b = b.clone().requires_grad_(True)
    f = solve_soft_contacts(H, b, mask)
    f.sum().backward()
    assert b.grad is not None and bool(torch.isfinite(b.grad).all())
    assert float(b.grad[~mask].abs().max()) == 0.0  # off the mask nothing depends on b
    assert float(b.grad[mask & (f.detach() > 0)].abs().max()) > 0
