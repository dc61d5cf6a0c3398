"""The per-rod contact problem: a batch solved only where its active set still changes,
and only for the rods that touch the floor; the C kernel and the PyTorch version agree."""

from __future__ import annotations

import pytest
import torch

from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.ground_contact import solve_soft_contacts
from tensegrity_env.engine import Engine, State
from tensegrity_env.native import kernel
from tensegrity_env.rotations import quat_mul


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


def test_contact_forces_of_a_batch_equal_each_assembly_alone(monkeypatch):
    """Only touching rods are gathered and solved: a batch mixing touching and airborne
    assemblies, with per-assembly masses, gets each one's forces as if stepped alone,
    and the C kernel's forces are PyTorch's."""
    asm = icosahedron()
    topo, params = asm.topology, asm.params
    g = torch.Generator().manual_seed(3)
    B = 12
    p = torch.as_tensor(asm.pose_p, dtype=torch.float64).expand(B, -1, -1)
    turn = torch.nn.functional.normalize(
        torch.tensor([1.0, 0, 0, 0], dtype=torch.float64)
        + 0.1 * torch.randn(B, 1, 4, generator=g, dtype=torch.float64), dim=-1)  # fmt: skip
    q = quat_mul(turn.expand(B, topo.n_rods, 4), torch.as_tensor(asm.pose_q).expand(B, -1, -1))
    v = 0.5 * torch.randn(B, topo.n_rods, 3, generator=g, dtype=torch.float64)
    w = 2.0 * torch.randn(B, topo.n_rods, 3, generator=g, dtype=torch.float64)
    engine = Engine(topo, dt=1e-3)
    caps = engine.kinematics(State(p=p, v=v, q=q, omega=w)).x[:, : 2 * topo.n_rods, 2]
    # the lowest cap from 5 mm into the floor to 10 cm above it
    height = torch.linspace(-0.005, 0.1, B, dtype=torch.float64) + topo.rods[0].radius
    p = p + torch.nn.functional.pad((height - caps.min(-1).values)[:, None, None], (2, 0))
    state = State(p=p, v=v, q=q, omega=w)
    mass = params.mass * (1 + 0.05 * torch.rand(B, topo.n_rods, generator=g, dtype=torch.float64))
    batched = params.replace(mass=mass)
    contact = GroundContact(topo, friction=0.7)
    engine = Engine(topo, dt=1e-3, effects=[contact])
    kin = engine.kinematics(state)
    force, _ = contact.contact_forces(state, kin, batched)
    touching = force.abs().sum((-1, -2)) > 0  # (B, R)
    assert 0 < int(touching.any(-1).sum()) < B  # some assemblies touch, some do not
    monkeypatch.setattr(kernel, "USE_NATIVE", False)
    in_torch, arm_torch = contact.contact_forces(state, kin, batched)
    monkeypatch.setattr(kernel, "USE_NATIVE", True)
    _, arm = contact.contact_forces(state, kin, batched)
    assert torch.allclose(force, in_torch, rtol=0, atol=1e-12)
    assert torch.allclose(arm, arm_torch, rtol=0, atol=1e-15)
    for b in range(B):
        one = State(*(x[b : b + 1] for x in state.tensors()))
        alone, _ = contact.contact_forces(one, engine.kinematics(one),
                                          params.replace(mass=mass[b : b + 1]))  # fmt: skip
        assert torch.allclose(force[b : b + 1], alone, rtol=0, atol=1e-12)


def test_c_kernel_and_torch_step_the_same_rolling_icosahedron(monkeypatch):
    """A second of the icosahedron dropped spinning from 2 cm onto a floor (impacts,
    sliding and rolling) at a 1 ms step: the engine with the C kernel's contact forces
    and with PyTorch's stays within 1e-9 m of each other at every step."""
    if kernel.usable_kernel(torch.zeros(1, dtype=torch.float64)) is None:
        pytest.skip("no C compiler here: the engine uses the PyTorch contact law")
    asm = icosahedron()
    topo = asm.topology
    p = torch.as_tensor(asm.pose_p, dtype=torch.float64)[None].clone()
    q = torch.as_tensor(asm.pose_q, dtype=torch.float64)[None]
    v = torch.tensor([0.8, 0.3, 0.0], dtype=torch.float64).expand(1, topo.n_rods, 3)
    w = torch.tensor([0.0, 2.0, 1.0], dtype=torch.float64).expand(1, topo.n_rods, 3)
    engine = Engine(topo, dt=1e-3, effects=[GroundContact(topo, friction=0.8)])
    lowest = float(engine.kinematics(State(p=p, v=v, q=q, omega=w)).x[..., 2].min())
    p[..., 2] += 0.02 + topo.rods[0].radius - lowest  # the lowest cap 2 cm above the floor
    start = State(p=p, v=v.clone(), q=q.clone(), omega=w.clone())
    paths, lows = [], []
    for native in (True, False):
        monkeypatch.setattr(kernel, "USE_NATIVE", native)
        state, low = start, []
        for _ in range(1000):
            state = engine.step(state, asm.params)
            low.append(float(engine.kinematics(state).x[..., 2].min()))
        paths.append(engine.kinematics(state).x)
        lows.append(low)
    assert min(lows[0]) < topo.rods[0].radius  # it came down onto the floor
    assert max(abs(a - b) for a, b in zip(*lows, strict=True)) < 1e-9
    assert float((paths[0] - paths[1]).abs().max()) < 1e-9
