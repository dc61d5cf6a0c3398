"""Rest lengths balanced where a robot rests: a check of the idea, not part of ``identify``.

A robot at rest neither moves nor accelerates: at each measured resting pose the net
force and torque on every rod (springs, gravity, the effects that act at zero velocity,
the floor's reaction at the caps it stands on) are zero. Spring forces are linear in
``K`` and ``K l0``, so the rest lengths that balance the rods there follow from a
linear least-squares fit (:func:`fit_rest_equilibrium`):

* **Linear.** At a fixed pose and zero velocity every rod's net wrench is ``w0 + J δl0``,
  ``J`` by autograd through the engine (tension-only cables enter as the engine applies
  them). One pose shows only the tensions, so the stiffnesses are held.
* **Floor reaction.** Every end cap within :data:`TOUCH` of touching the floor (at its
  contact radius) carries an unknown force at its contact point inside the Coulomb
  cone (a pyramid of :data:`PYRAMID` edges, non-negative coefficients).
* **Fit.** Rows: each rod's net force and torque at every resting state, scaled by the
  equilibrium's noise (:func:`wrench_noise`); among the adjustments that balance the
  rods, the smallest (a prior of weight :data:`PRIOR` per spring). Bounded linear least
  squares; a rest length stays between :data:`SHORTEST` of its value and the spring's
  shortest length at rest (the law is linear up to slack).

The script measures what the adjustment does to the rest shape and to held-out
prediction (docs/decisions.md has the numbers and why it is not in ``identify``):

    python benchmarks/rest_balance.py take W/eth_T2_drop   # a bench_real take folder
    python benchmarks/rest_balance.py take W/eth_T2_drop --params robot.yaml
    python benchmarks/rest_balance.py plant                # the MuJoCo plant of the tests
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import lsq_linear

from identification.trajectory.cap_radius_fit import rest_states
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import Engine, State
from tensegrity_env.params import Params
from tensegrity_env.vec3 import rotate

#: an end cap this close [m] to touching the floor at its contact radius may carry the
#: floor's reaction: a soft contact carries its load at a fraction of a millimetre of
#: penetration, and a fitted model's caps sit within a few millimetres of their
#: measured heights (its radii are fitted by rollouts that settle)
TOUCH = 0.005
#: edges of the friction pyramid that stands in for the Coulomb cone
PYRAMID = 8
#: weight of a spring's rest-length change against the equilibrium rows, both in units
#: of the pose noise: small, so that the rods are balanced (to their noise) by the
#: smallest change rather than by a compromise with the fitted rest lengths
PRIOR = 1e-3
#: a rest length moves no lower than this fraction of its value
SHORTEST = 0.5


@dataclass(frozen=True)
class RestEquilibrium:
    """What :func:`fit_rest_equilibrium` found.

    Attributes:
        rest_length: the adjusted rest lengths (S,) [m].
        change: the adjustment the fit found, (S,) [m].
        before, after: the rods' median unbalanced acceleration [m/s²] at the resting
            states with the best floor reaction, before and after.
        states: resting states balanced.
        touching: end caps carrying floor force, summed over the states.
        kept: whether the adjustment lowered the rods' net wrench (in noise units);
            :attr:`rest_length` is the given one where not.
    """

    rest_length: np.ndarray
    change: np.ndarray
    before: float
    after: float
    states: int
    touching: int
    kept: bool

    def lines(self) -> list[str]:
        """What the adjustment did, in a few lines."""
        verdict = "kept" if self.kept else "not kept (no better)"
        return [f"springs balanced at {self.states} resting states ({self.touching} end caps on the floor): "
                f"unbalanced acceleration {self.before:.3g} -> {self.after:.3g} m/s² (median over rods), "
                f"rest lengths moved by up to {1e3 * float(np.abs(self.change).max()):.2f} mm "
                f"(median {1e3 * float(np.median(np.abs(self.change))):.2f} mm), {verdict}"]  # fmt: skip


def rod_wrench(engine: Engine, params: Params, state: State) -> torch.Tensor:
    """Net force and torque on each rod, (B, R, 6) [N, N*m] (world frame; torque about
    its centre of mass) at ``state`` (velocities zero) from everything in ``engine``
    (springs, gravity, its effects): ``M a`` and ``R I α_l``."""
    accel, alpha_l, _ = engine.accelerations(state, params)
    rot = engine.kinematics(state).rot
    torque = rotate(rot, params.inertia * alpha_l)
    return torch.cat([params.mass.unsqueeze(-1) * accel, torque], -1)


def wrench_noise(engine: Engine, params: Params, state: State, noise: float) -> np.ndarray:
    """Standard deviation (R, 6) [N, N*m] of each rod's net wrench from a pose noise of
    ``noise`` [m] on every end cap, through a typical spring: the springs' median
    stiffness ``K`` moves a tension by ``K √2 σ``, on each of the rod's springs; torques by
    that times the rod's half length. (A link far stiffer than the springs, whose
    tension the pose does not fix, is balanced through its rest length, which moves
    by a small fraction of the pose noise.)"""
    topo = engine.topology
    count = np.zeros(topo.n_rods)
    for node in [*engine.node_a.tolist(), *engine.node_b.tolist()]:
        if node < 2 * topo.n_rods:
            count[node // 2] += 1
    K = float(np.median(params.stiffness.detach().cpu().numpy()))
    f = noise * K * np.sqrt(2 * np.maximum(count, 1))
    arms = engine.kinematics(state).arms.detach().cpu().numpy()  # (B, R, 2, 3)
    half = np.linalg.norm(arms, axis=-1).max((0, 2))
    return np.concatenate([np.repeat(f[:, None], 3, 1), np.repeat((f * half)[:, None], 3, 1)], 1)


def reaction_columns(
    state: State, kin_arms: torch.Tensor, contact: GroundContact, b: int
) -> np.ndarray:
    """Columns (R*6, n) [N, N*m per N] of the floor's reaction at state ``b``: for each end
    cap within :data:`TOUCH` of the floor, the :data:`PYRAMID` edges of its friction cone
    (normal component 1 N) applied at its contact point below the cap."""
    arms = kin_arms[b].detach().cpu().numpy()  # (R, 2, 3) end caps from the centres of mass
    R = arms.shape[0]
    caps = arms + state.p[b].detach().cpu().numpy()[:, None]
    radius = contact.radius.detach().cpu().numpy()
    mu = float(contact.values["friction"].reshape(-1)[0])
    gap = caps[..., 2] - radius - contact.floor_height()
    ang = 2 * np.pi * np.arange(PYRAMID) / PYRAMID
    edges = np.stack([mu * np.cos(ang), mu * np.sin(ang), np.ones(PYRAMID)], 1)
    cols = []
    for i, e in zip(*np.nonzero(gap < TOUCH), strict=True):
        arm = arms[i, e] - np.array([0.0, 0.0, radius[i, e]])
        for edge in edges:
            c = np.zeros((R, 6))
            c[i, :3], c[i, 3:] = edge, np.cross(arm, edge)
            cols.append(c.reshape(-1))
    return np.array(cols).T if cols else np.zeros((R * 6, 0))


def fit_rest_equilibrium(
    engine: Engine,
    params: Params,
    effects: Sequence[PhysicalEffect],
    pieces: Sequence[np.ndarray],
    noise: float,
) -> RestEquilibrium | None:
    """Rest lengths that balance every rod at the resting states of ``pieces`` (module
    docstring).

    ``engine``: the engine without effects (its ``dt`` the pieces' sample interval [s]);
    ``params`` the fitted declared parameters; ``effects`` the fitted effects, the
    :class:`GroundContact` among them (its radii, floor height and friction place the
    reaction; its contact law is not used); ``pieces``: resting pieces' end caps
    (T, 2R, 3) [m]; ``noise``: the end caps' measurement noise [m]. None where there is
    no contact or no resting state.
    """
    contact = next((e for e in effects if isinstance(e, GroundContact)), None)
    start = None if contact is None else rest_states(pieces, engine)
    if contact is None or start is None:
        return None
    state = start[0]
    free = engine.with_effects([e for e in effects if not e.constraint])
    B, R = state.p.shape[:2]
    l0 = params.rest_length.detach().clone()
    S, noise = l0.shape[0], max(noise, 1e-9)
    K = np.maximum(params.stiffness.detach().cpu().numpy(), 1e-12)

    def wrench(rest: torch.Tensor) -> torch.Tensor:
        return rod_wrench(free, params.replace(rest_length=rest), state).reshape(-1)

    w0 = wrench(l0).detach().cpu().numpy()
    # unknowns in newtons: each spring's tension change u = -K δl0, then the reactions
    J = -torch.autograd.functional.jacobian(wrench, l0).detach().cpu().numpy() / K  # (B*R*6, S)
    arms = free.kinematics(state).arms
    blocks = [reaction_columns(state, arms, contact, b) for b in range(B)]
    C = np.zeros((B * R * 6, sum(c.shape[1] for c in blocks)))
    col = 0
    for b, c in enumerate(blocks):
        C[b * R * 6 : (b + 1) * R * 6, col : col + c.shape[1]] = c
        col += c.shape[1]
    A = np.hstack([J, C])
    scale = 1.0 / np.tile(wrench_noise(engine, params, state, noise).reshape(-1), B)
    prior = np.hstack([PRIOR * np.diag(1.0 / (K * noise)), np.zeros((S, C.shape[1]))])
    with torch.no_grad():
        kin = free.kinematics(state)
        length = torch.linalg.vector_norm(kin.x[:, free.node_b] - kin.x[:, free.node_a], dim=-1)
    l0n = l0.cpu().numpy()
    lo = np.concatenate(
        [-K * np.maximum(length.min(0).values.cpu().numpy() - l0n, 0.0), np.zeros(C.shape[1])]
    )
    hi = np.concatenate(
        [np.maximum(K * (1 - SHORTEST) * l0n, lo[:S] + 1e-12), np.full(C.shape[1], np.inf)]
    )
    x = lsq_linear(np.vstack([A * scale[:, None], prior]), np.concatenate([-w0 * scale, np.zeros(S)]),
                   bounds=(lo, hi), method="bvls").x  # fmt: skip
    change = -x[:S] / K

    def unbalanced(u: np.ndarray) -> tuple[float, float]:
        """The rods' net wrench in noise units (RMS) and their median unbalanced
        acceleration [m/s²], with the floor reaction that balances them best."""
        left = w0 + J @ u
        if C.shape[1]:
            left = left + C @ lsq_linear(C * scale[:, None], -left * scale, bounds=(0, np.inf)).x
        force = left.reshape(B, R, 6)[..., :3]
        acc = np.linalg.norm(force, axis=-1) / params.mass.detach().cpu().numpy()
        return float(np.sqrt(np.mean((left * scale) ** 2))), float(np.median(acc))

    (w_before, before), (w_after, after) = unbalanced(np.zeros(S)), unbalanced(x[:S])
    kept = w_after < w_before
    touching = C.shape[1] // PYRAMID
    return RestEquilibrium(l0n + change if kept else l0n, change, before, after, B, touching, kept)


def check_take(folder: Path, params: Path | None = None) -> None:
    """The identified model of a ``bench_real`` take folder (``take.h5``,
    ``identified.json``; ``params`` another model file) with and without the balanced
    rest lengths: the fit, the rest shape and the held-out end-cap RMS at each horizon,
    printed."""
    import bench_real as br

    from identification.data.dataset import read_dataset
    from identification.data.sample_grid import on_nominal_grid
    from identification.trajectory.cap_radius_fit import resting_pieces
    from identification.trajectory.stage_check import noise_level
    from tensegrity_env.model import Model

    data, _ = on_nominal_grid(read_dataset(folder / "take.h5"))
    model = Model.read(params or folder / "identified.json", dt=data.dt)
    engine = model.engine()
    noise = noise_level(data.split("train").nodes, rods=True)
    found = fit_rest_equilibrium(engine.with_effects([]), model.params, list(engine.effects),
                                 resting_pieces(data, "train"), noise)  # fmt: skip
    if found is None:
        print(f"{folder}: no resting piece in the training split, or no ground contact")
        return
    print(*found.lines(), sep="\n")
    piece, nodes = br.resting_piece(data), br.held_out(data)
    balanced = model.params.replace(
        rest_length=torch.as_tensor(found.rest_length + (0 if found.kept else found.change))
    )
    for name, params in (("given", model.params), ("balanced", balanced)):
        m = model.replace(params=params)
        shape, _ = br.rest_shape(m, piece, data.dt) if piece is not None else (None, None)
        rms, _ = br.open_loop(m, nodes, data.dt, br.HORIZONS)
        print(f"{name}: rest shape {1e3 * shape:.2f} mm; held-out end-cap RMS at "
              + ", ".join(f"{h:g} s {1e2 * r:.2f} cm" for h, r in zip(br.HORIZONS, rms, strict=True)))  # fmt: skip


def check_plant() -> None:
    """The tests' MuJoCo icosahedron at rest after three drops, its rest lengths moved
    by 3 mm (standard deviation): the balanced rest lengths against the true ones, and
    the rest shape of each, printed."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "unit"))
    from test_cap_radii import DT, rest_error
    from test_rest_equilibrium import ANGLES, OFF, plant, resting

    asm = plant()
    rests = [resting(asm, a) for a in ANGLES]
    contact, drag = asm.declared_effects()
    engine = Engine(asm.topology, dt=DT, substeps=round(DT / asm.model.opt.timestep), native=True)
    truth = asm.params.rest_length.numpy()
    for name, given in (
        ("true", truth),
        ("moved", truth + np.random.default_rng(0).normal(0.0, OFF, truth.shape)),
    ):
        found = fit_rest_equilibrium(engine, asm.params.replace(rest_length=torch.as_tensor(given)),
                                     [drag, contact], rests, noise=1e-5)  # fmt: skip
        assert found is not None
        balanced = given + found.change
        print(f"{name} rest lengths: " + found.lines()[0])
        print(f"  error against the truth: given {1e3 * np.sqrt(np.mean((given - truth) ** 2)):.2f} mm, "
              f"balanced {1e3 * np.sqrt(np.mean((balanced - truth) ** 2)):.2f} mm RMS over springs")  # fmt: skip
        for i, rest in enumerate(rests):
            shape = {k: 1e3 * rest_error(engine.with_effects([drag, contact]),
                                         asm.params.replace(rest_length=torch.as_tensor(x)), rest)
                     for k, x in (("given", given), ("balanced", balanced), ("true", truth))}  # fmt: skip
            print(
                f"  rest {i}: rest shape " + ", ".join(f"{k} {v:.3f} mm" for k, v in shape.items())
            )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    take = sub.add_parser("take", help="a bench_real take folder (take.h5, identified.json)")
    take.add_argument("folder", type=Path)
    take.add_argument(
        "--params", type=Path, help="the model file (default: the folder's identified.json)"
    )
    sub.add_parser("plant", help="the tests' MuJoCo icosahedron at rest")
    args = ap.parse_args(argv)
    if args.what == "plant":
        check_plant()
        return 0
    for path in (args.folder / "take.h5", args.params or args.folder / "identified.json"):
        if not path.is_file():
            print(f"rest_balance: {path}: no such file (a bench_real --workdir take folder has take.h5 and identified.json)",
                  file=sys.stderr)  # fmt: skip
            return 2
    check_take(args.folder, args.params)
    return 0


if __name__ == "__main__":
    sys.exit(main())
