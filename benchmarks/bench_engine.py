"""Speed of the PyTorch engine on a floor, the way the trajectory fits step it.

The fits on floor data (``identify``, ``diagnose``) spend their time stepping the
engine on batches of about a thousand perturbed copies of the structure (forward-
difference Jacobians), most of them touching the floor. This script times one
sample interval (120 Hz, 9 physics steps of <= 1 ms) of such a batch: states of the
measured benchmark's floor plant (``measured_plant.py``, MuJoCo's default contact),
float64, one thread. The reference, timed in the same run and in alternation (best of
``--repeats`` per side), is MuJoCo stepping the same plant from the same states one
after the other (``mj_step`` with ``nstep`` = 9); the engine without its ground
contact shows what the contact costs, the engine with the contact law in PyTorch
(where a gradient is wanted; ``tensegrity_env.effects.kernel.USE_NATIVE``)
what its C kernel saves, and the engine built with ``native=True`` (as the trajectory
fits build it: without gradients the whole step runs in the environments' C kernel,
:mod:`tensegrity_env.native.engine_step`) what that saves. Ratios are printed, never
asserted::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_engine.py
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_engine.py --batch 4000 --repeats 5
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable

import mujoco
import numpy as np
import torch
from measured_plant import Cell, initial_states, simulate, true_model

from tensegrity_env.engine import Engine, State
from tensegrity_env.mjcf import from_mjcf
from tensegrity_env.mjcf_checks import IgnoredFeatureWarning
from tensegrity_env.native import kernel
from tensegrity_env.rotations import np_quat_to_matrix


def best_of(fn: Callable[[], None], repeats: int) -> float:
    """The shortest of ``repeats`` timings of ``fn`` [s]."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=1500,
                    help="assemblies stepped at once by the engine (default 1500)")  # fmt: skip
    ap.add_argument("--repeats", type=int, default=3, help="timings per side (best kept)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the plant's trajectories")
    args = ap.parse_args(argv)
    if args.batch < 1 or args.repeats < 1:
        ap.error("--batch and --repeats must be >= 1")
    torch.set_num_threads(1)
    cell = Cell("floor", 120.0, 0.0, 0.0, "none", seed=args.seed)
    truth = true_model(cell)
    rng = np.random.default_rng([args.seed, 5])
    clean = simulate(cell, truth, initial_states(cell, 8, rng), 3.0)
    flat = {k: getattr(clean, k).reshape(-1, *getattr(clean, k).shape[2:])
            for k in ("p", "v", "q", "omega")}  # fmt: skip
    pick = rng.choice(len(flat["p"]), size=args.batch, replace=len(flat["p"]) < args.batch)
    states = {k: x[pick] for k, x in flat.items()}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IgnoredFeatureWarning)
        asm = from_mjcf("<plant>", xml=truth.xml)
    contact = asm.declared_effects()
    radius = asm.topology.rods[0].radius
    touching = np.mean(np.any(clean.nodes[..., 2] < radius, axis=-1))
    state = State.from_numpy(states["p"], states["v"], states["q"], states["omega"])
    with_contact = Engine(asm.topology, 1 / cell.rate, contact, substeps=cell.substeps)
    engines = {  # name: (engine, contact law in C)
        "engine with contact": (with_contact, True),
        "  contact in PyTorch": (with_contact, False),
        "engine without contact": (Engine(asm.topology, 1 / cell.rate, [], substeps=cell.substeps),
                                   True),
        "engine, native path": (Engine(asm.topology, 1 / cell.rate, contact,
                                       substeps=cell.substeps, native=True), True),
    }  # fmt: skip
    model = mujoco.MjModel.from_xml_string(truth.xml)
    data = mujoco.MjData(model)
    R = asm.topology.n_rods
    qpos = np.concatenate([states["p"], states["q"]], -1).reshape(args.batch, -1)
    w_local = np.einsum("brji,brj->bri", np_quat_to_matrix(states["q"]), states["omega"])
    qvel = np.concatenate([states["v"], w_local], -1).reshape(args.batch, 6 * R)

    def mujoco_batch() -> None:
        for b in range(args.batch):
            data.qpos[:], data.qvel[:] = qpos[b], qvel[b]
            mujoco.mj_step(model, data, nstep=cell.substeps)

    def engine_batch(engine: Engine, native: bool) -> Callable[[], None]:
        def run() -> None:
            kernel.USE_NATIVE = native
            try:
                with torch.no_grad():
                    engine.step(state, asm.params)
            finally:
                kernel.USE_NATIVE = True

        return run

    steps = args.batch * cell.substeps
    times = {name: [] for name in ("mujoco", *engines)}
    for _ in range(args.repeats):  # alternate, so background load hits every side alike
        times["mujoco"].append(best_of(mujoco_batch, 1))
        for name, (engine, native) in engines.items():
            times[name].append(best_of(engine_batch(engine, native), 1))
    ref = min(times["mujoco"]) / steps
    print(f"floor plant, {args.batch} assemblies ({touching:.0%} of the plant's samples have a "
          f"cap on the floor), {cell.substeps} physics steps of {1e3 / cell.rate / cell.substeps:.3g}"
          f" ms, one thread")  # fmt: skip
    print(f"  {'mujoco (reference)':24s} {ref * 1e6:8.2f} us per assembly-step")
    for name in engines:
        per = min(times[name]) / steps
        print(f"  {name:24s} {per * 1e6:8.2f} us per assembly-step  ratio to MuJoCo "
              f"{per / ref:6.2f}")  # fmt: skip
    with_c, in_torch, without, native = (min(times[n]) for n in engines)
    print(f"  contact share of the engine's step: {1 - without / with_c:.0%}; the step with the "
          f"contact law in C against PyTorch: ratio {with_c / in_torch:.2f}; the native path "
          f"against the engine with contact: ratio {native / with_c:.3f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
