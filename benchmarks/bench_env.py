"""Environment speed and fidelity: the identified env against its MuJoCo twin.

Three measurements, both sides at the same physics step (1 ms), control rate
(``frame_skip`` 50: 20 Hz), task code and thread count, timed in alternation with
the best of ``--repeats`` kept per side, so background load hits both alike:

1. **Batched**: ``IcosahedronSR-v0``'s vector env (one native call steps all N
   assemblies, OpenMP over the batch) against the twin's vector env, which steps
   through MuJoCo's multi-threaded ``mujoco.rollout`` (the fastest way to run N
   MuJoCo copies), both through the Gymnasium ``VectorEnv.step`` API with the same
   random actions. Target: ratio >= 10 at N = 4096.
2. **Single env**: ``env.step`` latency of ``IcosahedronSR-v0`` against
   ``IcosahedronMJ-v0`` (``mj_step`` with ``nstep = 50``). Target: ratio >= 1.
3. **Fidelity**: from the same state (the identified env's seeded reset, copied into
   the twin) under the same random actions, the distance between the two
   structures' centres after 1 s and 5 s, over ``--episodes`` episodes. The same for
   the engine with the *true* parameters and MuJoCo's default contact, which
   separates identification error from what the model leaves out, and with no
   control at all.

4. **Generic robot**: ``TensegritySR-v0`` (the shipped lab 3-bar with six winches, the
   C kernel winding them) against ``TensegrityMJ-v0``: the single-env ``env.step``
   latency (target: ratio >= 10; beside it the twin's 50 ``mj_step`` alone, without its
   winding, task or observation), and a batch of N robots (one kernel call, OpenMP over
   the batch) against N twins through ``mujoco.rollout`` (the winding as tendon forces,
   :mod:`tensegrity_env.envs.robot_rollout`), the same threads a side (target: ratio
   >= 50 at N = 4096).

5. **Kernel builds** (``--sections lanes``): the C kernel alone, one control step of
   the lab 3-bar (50 physics steps, its winches winding) through its 8-lane build and
   its 4-lane build (:data:`~tensegrity_env.native.kernel.NARROW_LANES`), for one robot
   and for a batch of 1024 on one thread: why one environment steps through the narrow
   build and a batch through the wide one (the same numbers bit for bit).

Ratios are printed, never asserted::

    .venv/bin/python benchmarks/bench_env.py
    .venv/bin/python benchmarks/bench_env.py --num-envs 1024 --repeats 2
    .venv/bin/python benchmarks/bench_env.py --sections robot --robot-num-envs 4096
    .venv/bin/python benchmarks/bench_env.py --sections lanes
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

import tensegrity_env  # noqa: F401  (registers the envs, MUJOCO_GL)
from tensegrity_env.effects import GroundContact
from tensegrity_env.envs import (
    IcosahedronMJEnv,
    IcosahedronMJVectorEnv,
    IcosahedronSREnv,
    IcosahedronSRVectorEnv,
    TensegrityMJEnv,
    TensegrityMJVectorEnv,
    TensegritySREnv,
    TensegritySRVectorEnv,
)
from tensegrity_env.envs.physics import NativeStepper, default_threads
from tensegrity_env.envs.robot_physics import SRRobotSimulator
from tensegrity_env.envs.twin import twin_assembly
from tensegrity_env.model import Model
from tensegrity_env.native.kernel import LANES, NARROW_LANES, load_kernel


def per_step(
    step: Callable[[np.ndarray], object],
    actions: np.ndarray,
    reset: Callable[[], object] | None = None,
) -> Callable[[], float]:
    """A timing function: ``reset()`` (if given), then ``step(a)`` for each of ``actions``
    (T, ...); it returns the mean wall time per call [s]."""

    def timed() -> float:
        if reset is not None:
            reset()
        t0 = time.perf_counter()
        for a in actions:
            step(a)
        return (time.perf_counter() - t0) / len(actions)

    return timed


def best_of(fns: list[Callable[[], float]], repeats: int) -> list[float]:
    """Run each timing function ``repeats`` times in alternation; the best (lowest) of each."""
    best = [np.inf] * len(fns)
    for _ in range(repeats):
        for k, fn in enumerate(fns):
            best[k] = min(best[k], fn())
    return best


def batched(num_envs: int, steps: int, mj_steps: int, threads: int, repeats: int) -> None:
    sr = IcosahedronSRVectorEnv(num_envs, threads=threads)
    mj = IcosahedronMJVectorEnv(num_envs, threads=threads)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (max(steps, mj_steps), num_envs, 18)).astype(np.float32)
    sr.reset(seed=0)
    mj.reset(seed=0)
    sr.step(actions[0])  # warm up (first touch of the buffers, the kernel's threads)
    mj.step(actions[0])

    t_sr, t_mj = best_of([per_step(sr.step, actions[:steps]), per_step(mj.step, actions[:mj_steps])],
                         repeats)  # fmt: skip
    r_sr, r_mj = num_envs / t_sr, num_envs / t_mj
    print(
        f"\n1. Batched, N = {num_envs}, {threads} thread(s) each (env-steps/s, 50 physics steps each)"
    )
    print(f"   IcosahedronSR-v0 vector env (native kernel):   {r_sr:12,.0f}")
    print(f"   IcosahedronMJ-v0 vector env (mujoco.rollout):  {r_mj:12,.0f}")
    print(f"   ratio SR / MJ: {r_sr / r_mj:.1f}x   (target >= 10)")
    sr.close()
    mj.close()


def single(steps: int, repeats: int) -> None:
    sr, mj = IcosahedronSREnv(), IcosahedronMJEnv()
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1, 1, (steps, 18)).astype(np.float32)

    def run(env: IcosahedronSREnv | IcosahedronMJEnv) -> Callable[[], float]:
        return per_step(env.step, actions, lambda: env.reset(seed=0))

    t_sr, t_mj = best_of([run(sr), run(mj)], repeats)
    print("\n2. Single env, env.step latency (50 physics steps + observation + reward)")
    print(f"   IcosahedronSR-v0: {t_sr * 1e3:8.3f} ms")
    print(f"   IcosahedronMJ-v0: {t_mj * 1e3:8.3f} ms")
    print(f"   ratio MJ / SR latency: {t_mj / t_sr:.1f}x   (target >= 1)")


def divergence(
    sr: IcosahedronSREnv, mj: IcosahedronMJEnv, episodes: int, scale: float
) -> np.ndarray:
    """Centre distance [m] after 1 s and 5 s, (episodes, 2)."""
    out = np.zeros((episodes, 2))
    marks = {round(1.0 / sr.sim.control_dt): 0, round(5.0 / sr.sim.control_dt): 1}
    for e in range(episodes):
        sr.reset(seed=e)
        mj.reset(options={"state": sr.state, "goal": sr.goal})
        rng = np.random.default_rng(1000 + e)
        for k in range(1, max(marks) + 1):
            a = (scale * rng.uniform(-1, 1, 18)).astype(np.float32)
            sr.step(a)
            mj.step(a)
            if k in marks:
                c_sr, c_mj = sr.state[:, :3].mean(axis=0), mj.state[:, :3].mean(axis=0)
                out[e, marks[k]] = np.linalg.norm(c_sr - c_mj)
    return out


def fidelity(episodes: int) -> None:
    mj = IcosahedronMJEnv(goal_distance=(100.0, 100.0))  # far goal: no episode ends early
    with tempfile.TemporaryDirectory() as tmp:
        a = twin_assembly()
        true_path = Path(tmp) / "true_params.json"
        Model(a.topology, a.params, [GroundContact(a.topology)]).save(true_path)
        rows = [
            ("identified params, random actions", IcosahedronSREnv(goal_distance=(100.0, 100.0)), 1.0),
            ("identified params, no control", IcosahedronSREnv(goal_distance=(100.0, 100.0)), 0.0),
            ("true params + MuJoCo's contact, random actions",
             IcosahedronSREnv(true_path, goal_distance=(100.0, 100.0)), 1.0),
        ]  # fmt: skip
        print(f"\n3. Centre (COM) divergence, identified env vs twin from the same state and "
              f"actions, {episodes} episodes [mm]")  # fmt: skip
        print(
            f"   {'model':<48} {'1 s median':>10} {'1 s max':>9} {'5 s median':>11} {'5 s max':>9}"
        )
        for label, sr, scale in rows:
            d = 1e3 * divergence(sr, mj, episodes, scale)
            med, mx = np.median(d, axis=0), d.max(axis=0)
            print(f"   {label:<48} {med[0]:10.3f} {mx[0]:9.3f} {med[1]:11.3f} {mx[1]:9.3f}")


def robot(num_envs: int, steps: int, mj_steps: int, single_steps: int, threads: int,
          repeats: int) -> None:  # fmt: skip
    sr, mj = TensegritySREnv(), TensegrityMJEnv()
    W = sr.action_space.shape[0]
    rng = np.random.default_rng(2)
    actions = rng.uniform(-1, 1, (max(steps, mj_steps, single_steps), num_envs, W))
    actions = actions.astype(np.float32)

    def run(env: TensegritySREnv | TensegrityMJEnv) -> Callable[[], float]:
        return per_step(env.step, actions[:single_steps, 0], lambda: env.reset(seed=0))

    def mj_steps_alone(_: np.ndarray) -> None:  # the twin's MuJoCo physics: no winding, task
        mujoco.mj_step(mj.sim.model, mj.sim.data, nstep=mj.sim.frame_skip)

    bare = per_step(mj_steps_alone, actions[:single_steps, 0], lambda: mj.reset(seed=0))
    t_sr, t_mj, t_bare = best_of([run(sr), run(mj), bare], repeats)
    print("\n4. Generic robot (lab 3-bar, 6 winches), env.step latency (50 physics steps)")
    print(f"   TensegritySR-v0 (C kernel, {sr.sim.stepper.backend}): {t_sr * 1e3:8.3f} ms")
    print(f"   TensegrityMJ-v0 (MuJoCo):              {t_mj * 1e3:8.3f} ms")
    print(f"   its 50 mj_step alone (no winding):     {t_bare * 1e3:8.3f} ms")
    print(f"   ratio MJ / SR latency: {t_mj / t_sr:.1f}x   (target >= 10); bare mj_step / SR: "
          f"{t_bare / t_sr:.1f}x")  # fmt: skip
    venv = TensegritySRVectorEnv(num_envs, threads=threads)
    twins = TensegrityMJVectorEnv(num_envs, threads=threads)
    venv.reset(seed=0)
    twins.reset(seed=0)
    venv.step(actions[0])  # warm up (first touch of the buffers, the threads)
    twins.step(actions[0])

    b_sr, b_mj = best_of([per_step(venv.step, actions[:steps]),
                          per_step(twins.step, actions[:mj_steps])], repeats)  # fmt: skip
    how = type(twins.sim).__name__
    print(f"   batched, N = {num_envs}, {threads} thread(s) each (env-steps/s)")
    print(f"   TensegritySR-v0 vector env (C kernel):        {num_envs / b_sr:12,.0f}")
    print(f"   TensegrityMJ-v0 vector env ({how}): {num_envs / b_mj:12,.0f}")
    print(f"   ratio SR / MJ: {b_mj / b_sr:.1f}x   (target >= 50)")
    venv.close()
    twins.close()


def kernel_timing(
    build: int, stepper: NativeStepper, x0: np.ndarray, w0: np.ndarray, commands: np.ndarray
) -> Callable[[], float]:
    """A timing function: the build with ``build`` lanes winding copies of ``x0`` (B, R,
    13), ``w0`` (B, W, 2) under each of ``commands`` (T, B, W), one thread."""
    lib, t = load_kernel(build)[0], stepper.topology
    x, w = x0.copy(), w0.copy()

    def one(c: np.ndarray) -> None:
        lib.tsr_step(len(x), t.n_rods, t.n_springs, t.n_anchors, stepper.frame_skip,
                     stepper.dt, stepper.iterations, x.ctypes.data, None, stepper._model_ptr,
                     stepper._springs_ptr, 1, w.ctypes.data,
                     np.ascontiguousarray(c).ctypes.data)  # fmt: skip

    def reset() -> None:
        x[...], w[...] = x0, w0

    return per_step(one, commands, reset)


def lanes(steps: int, repeats: int) -> None:
    """The kernel's two builds on one robot and on 1024, one thread (see the docstring)."""
    sim = SRRobotSimulator()
    stepper = sim.stepper
    if not isinstance(stepper, NativeStepper):
        print("\n5. Kernel builds: the C kernel does not build here")
        return
    t = sim.topology
    rng = np.random.default_rng(3)
    print("\n5. Kernel builds, lab 3-bar, one control step (50 physics steps), one thread")
    for B, n in ((1, steps), (1024, max(2, steps // 100))):
        x0 = np.repeat(sim.rest_pose()[None], B, axis=0)
        x0[..., 3:6] += rng.normal(0, 0.05, x0[..., 3:6].shape)
        w0 = np.repeat(sim.rest_winch[None], B, axis=0)
        commands = rng.uniform(-1, 1, (n, B, t.n_winches))
        wide, narrow = best_of([kernel_timing(b, stepper, x0, w0, commands)
                                for b in (LANES, NARROW_LANES)], repeats)  # fmt: skip
        print(f"   {B:5d} robot(s): {LANES} lanes {wide * 1e3:9.3f} ms, {NARROW_LANES} lanes "
              f"{narrow * 1e3:9.3f} ms (narrow / wide {narrow / wide:.2f})")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--num-envs", type=int, default=4096, help="batch size N (default 4096)")
    ap.add_argument("--threads", type=int, default=None, help="threads per side (default: all)")
    ap.add_argument("--steps", type=int, default=10, help="timed batched SR steps (default 10)")
    ap.add_argument("--mj-steps", type=int, default=2, help="timed batched MJ steps (default 2)")
    ap.add_argument("--single-steps", type=int, default=200, help="timed single-env steps")
    ap.add_argument("--repeats", type=int, default=3, help="alternating timed runs (default 3)")
    ap.add_argument("--episodes", type=int, default=16, help="fidelity episodes (default 16)")
    ap.add_argument("--robot-num-envs", type=int, default=4096, help="generic robot batch N")
    ap.add_argument("--robot-steps", type=int, default=10, help="timed batched robot SR steps")
    ap.add_argument("--robot-mj-steps", type=int, default=2, help="timed batched robot MJ steps")
    ap.add_argument("--sections", default="batched,single,fidelity,robot",
                    help="comma-separated sections to run (default: these four; also: lanes)")  # fmt: skip
    args = ap.parse_args(argv)
    threads = args.threads or default_threads()
    sections = set(args.sections.split(","))
    print(f"bench_env: {default_threads()} CPU core(s) available, physics dt 1 ms, 20 Hz control")
    if "batched" in sections:
        batched(args.num_envs, args.steps, args.mj_steps, threads, args.repeats)
    if "single" in sections:
        single(args.single_steps, args.repeats)
    if "fidelity" in sections:
        fidelity(args.episodes)
    if "robot" in sections:
        robot(args.robot_num_envs, args.robot_steps, args.robot_mj_steps, args.single_steps,
              threads, args.repeats)  # fmt: skip
    if "lanes" in sections:
        lanes(args.single_steps, args.repeats)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
