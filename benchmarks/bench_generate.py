"""Dataset-generation throughput: the tool's generate function against bare MuJoCo.

Both sides roll out the same model from the same initial states with the same
controls and the same number of threads; the bare side is one call of
``mujoco.rollout`` (thread pool made outside the timing) that returns raw
``mjSTATE_FULLPHYSICS`` vectors, while the tool also samples the initial states,
checks for divergence and converts everything to rod states and end caps. Runs
alternate and the best of ``--repeats`` is kept on each side, so background load
hits both alike. The ratio (tool / bare steps per second) should be >= 0.8.

Example::

    .venv/bin/python benchmarks/bench_generate.py
    .venv/bin/python benchmarks/bench_generate.py --trajectories 1000 --write
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

from identification.data.dataset import write_dataset
from identification.simulation.generate import (
    GenerateSpec,
    ctrl_vectors,
    generate,
    split_inputs,
)
from identification.simulation.rollout import default_threads
from identification.simulation.truth import load_truth
from tensegrity_env.mujoco_state import rod_state_to_mj


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--assembly", choices=("icosahedron", "element"), default="icosahedron")
    ap.add_argument("--trajectories", type=int, default=256, help="trajectories (default 256)")
    ap.add_argument("--steps", type=int, default=736, help="steps per trajectory (default 736)")
    ap.add_argument("--threads", type=int, default=None, help="rollout threads (default: all)")
    ap.add_argument("--repeats", type=int, default=4, help="timed runs per side (default 4)")
    ap.add_argument("--control-std", type=float, default=1.0, help="random control (default 1)")
    ap.add_argument("--write", action="store_true", help="also time writing the HDF5 file")
    args = ap.parse_args(argv)

    threads = args.threads or default_threads()
    spec = GenerateSpec(
        assembly=args.assembly,
        n_train=args.trajectories,
        n_val=0,
        n_test=0,
        steps=args.steps,
        control_std=args.control_std,
        threads=threads,
    )
    n_steps = args.trajectories * args.steps

    # the same initial states and controls the tool draws for its train split
    truth = load_truth(spec)
    states, commands, cables, winches = split_inputs(truth, spec, "train", args.trajectories)
    qpos, qvel = rod_state_to_mj(truth.asm, **states)
    m = truth.model
    data = mujoco.MjData(m)
    template = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, data, template, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    init = np.tile(template, (args.trajectories, 1))
    init[:, 1 : 1 + m.nq], init[:, 1 + m.nq : 1 + m.nq + m.nv] = qpos, qvel
    ctrl = ctrl_vectors(truth, commands, cables, winches)
    datas = [mujoco.MjData(m) for _ in range(threads)]

    bare_s, tool_s, bare_cpu, tool_cpu, bare_state, result = [], [], [], [], None, None
    with rollout.Rollout(nthread=threads) as pool:
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            bare_state, _ = pool.rollout(m, datas, init, ctrl)
            bare_s.append(time.perf_counter() - t0)
            bare_cpu.append(time.process_time() - c0)
            t0, c0 = time.perf_counter(), time.process_time()
            result = generate(spec)
            tool_s.append(time.perf_counter() - t0)
            tool_cpu.append(time.process_time() - c0)
    assert result is not None and bare_state is not None
    train = result.dataset.splits["train"]
    same = np.allclose(train.p[:, 0], states["p"]) and np.allclose(
        train.p[:, -1], bare_state[:, -1, 1 : 1 + m.nq].reshape(-1, m.nq // 7, 7)[..., :3]
    )

    bare_rate, tool_rate = n_steps / min(bare_s), n_steps / min(tool_s)
    print(
        f"model: {args.assembly} ({truth.topology.n_rods} rods, {truth.topology.n_springs} "
        f"springs), {args.trajectories} trajectories x {args.steps} steps = {n_steps:,} steps, "
        f"{threads} threads, MuJoCo {mujoco.__version__}; same initial states and final "
        f"states on both sides: {same}"
    )
    print(f"bare mujoco.rollout   : {bare_rate:10,.0f} steps/s  (best of {args.repeats})")
    print(
        f"tensegrity-sr generate: {tool_rate:10,.0f} steps/s  (best of {args.repeats}; last run "
        f"{result.seconds:.2f} s, {result.rollout_seconds:.2f} s of it in mujoco.rollout calls)"
    )
    print(f"ratio generate / bare: {tool_rate / bare_rate:.2f}  (target >= 0.80)")
    cpu_ratio = min(bare_cpu) / min(tool_cpu)
    print(
        f"CPU time per step (all threads): bare {min(bare_cpu) / n_steps * 1e6:.2f} us, "
        f"generate {min(tool_cpu) / n_steps * 1e6:.2f} us; ratio {cpu_ratio:.2f} (what the "
        "wall-clock ratio tends to on an idle machine with enough cores)"
    )
    if args.write:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            path = write_dataset(Path(tmp) / "bench.h5", result.dataset, result.ground_truth)
            write_s = time.perf_counter() - t0
            size = path.stat().st_size
        print(
            f"write HDF5: {write_s:.2f} s for {size / 1e6:.0f} MB; end to end "
            f"{n_steps / (min(tool_s) + write_s):,.0f} steps/s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
