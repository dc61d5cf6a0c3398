"""Identification wall time at paper scale, and MuJoCo's own sysid toolbox on the same data.

1. The paper-scale icosahedron dataset (1000 training trajectories x 736 steps =
   736,000 transitions, preset ``paper``) is read from ``--dataset``, or generated
   there first with ``--seed`` (generation and writing are timed separately and are
   not part of the identification time).
2. ``SpringRodIdentifier(anchors=...).fit`` on every training transition is timed
   separately from reading the HDF5 file; the fit time is compared with the 5 s
   target (meant for 2 cores: run under ``taskset -c 0,1`` to pin it). The PyTorch
   backend (design blocks in chunks) is timed on ``--profile-fraction`` of the data in
   the same run, as the reference for the C backend's speed-up. If the fit is slower
   than the target, it is profiled and the time per stage is reported.
3. ``mujoco.sysid`` (MuJoCo's nonlinear least-squares toolbox: it rolls the MuJoCo
   model out from each trajectory's first state and fits the parameters to the
   recorded free-joint poses, with finite-difference Jacobians) starts from the
   ground-truth MJCF with every identified quantity perturbed by a random factor
   ``exp(U(-p, p))`` and fits the same quantities on ``--sysid-trajectories``
   trajectories of the test split: per-tendon stiffness, damping and rest length,
   per-rod mass (rod0 held at the anchor, as for us) and inertia (Ixx = Iyy tied,
   since MuJoCo refuses inertias that break the triangle inequality). Our method is
   also fitted on exactly those trajectories, and both results are rolled out on the
   whole test split with our engine.

The anchor (the scale that motion alone cannot give) defaults to rod0's true mass,
read from the dataset's ground truth and printed as such: it stands in for a rod
weighed on a scale. Needs the ``bench`` extra (``pip install -e ".[bench]"``) for
``mujoco.sysid``; without it, the reason is printed and the rest still runs.

Example::

    .venv/bin/python benchmarks/bench_identify.py --dataset /tmp/paper.h5
    taskset -c 0,1 .venv/bin/python benchmarks/bench_identify.py --dataset /tmp/paper.h5
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import os
import pstats
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from identification.data.dataset import Dataset, GroundTruth, Split, read_dataset, read_ground_truth
from identification.data.dataset import write_dataset as write_h5
from identification.linear.anchors import parse_anchor
from identification.linear.regression import SpringRodIdentifier, evaluate_params
from identification.report.tables import group_errors
from identification.simulation.generate import GenerateSpec, generate
from tensegrity_env.mjcf import MjcfAssembly, from_mjcf
from tensegrity_env.mujoco_state import rod_state_to_mj
from tensegrity_env.params import Params

TARGET_S = 5.0
GROUPS = ("mass", "inertia", "stiffness", "rest_length", "damping")
LABELS = {"mass": "M", "inertia": "I", "stiffness": "K", "rest_length": "l0", "damping": "c"}

#: Profiled functions: (module suffix, function name) -> stage label.
STAGES = {
    ("features.py", "transitions_of"): "gather transitions (indexing the arrays)",
    ("features.py", "transition_features"): "features (accelerations, spring kinematics)",
    ("design.py", "rod_blocks"): "design blocks per rod (A)",
    ("design.py", "accumulate_normal"): "normal matrix A^T A",
    ("native_normal.py", "local_gram_native"): "normal matrix in one C pass (native backend)",
    ("solve.py", "solve_constrained"): "constrained least-squares solve",
    ("regression.py", "_to_params"): "parameters and table",
}


def cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def load() -> str:
    """The 1/5/15-minute load averages, as text."""
    try:
        return "/".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


# ---------------------------------------------------------------------- our side
def ensure_dataset(path: Path, seed: int) -> None:
    """Generate the paper-scale dataset at ``path`` if it does not exist (timed)."""
    if path.exists():
        print(f"dataset: {path} ({path.stat().st_size / 1e6:,.0f} MB, reused)")
        return
    print(f"dataset: {path} does not exist; generating preset 'paper' with seed {seed} ...")
    result = generate(GenerateSpec.from_preset("paper", seed=seed))
    t0 = time.perf_counter()
    write_h5(path, result.dataset, result.ground_truth)
    write_s = time.perf_counter() - t0
    print(
        f"  generation {result.seconds:.1f} s ({result.threads} threads, "
        f"{result.steps_per_second:,.0f} steps/s), writing {write_s:.1f} s, "
        f"{path.stat().st_size / 1e6:,.0f} MB  (one-off, not part of identification)"
    )


def n_free(est: SpringRodIdentifier) -> int:
    """Unknowns the fit identified (anchored and unidentifiable ones not counted)."""
    sol = est.solution_
    return int(np.sum(np.asarray(sol.identifiable) & ~np.asarray(sol.fixed)))


def errors_of(rows: Any, truth: Params) -> dict[str, float]:
    return {g: e for g, e in group_errors(rows, truth).items() if g in GROUPS}


def profile_stages(fit: Callable[[], Any]) -> tuple[float, list[tuple[str, float]]]:
    """Run ``fit`` under cProfile: wall time and cumulative time per stage [s]."""
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.runcall(fit)
    wall = time.perf_counter() - t0
    stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
    found: dict[str, float] = {}
    for (file, _, func), (_, _, _, cum, _) in stats.items():
        for (suffix, name), label in STAGES.items():
            if func == name and file.endswith(suffix):
                found[label] = found.get(label, 0.0) + cum
    return wall, [(label, found.get(label, 0.0)) for label in STAGES.values()]


def head(split: Split, n: int, steps: int) -> Split:
    """The first ``n`` trajectories of ``split``, cut to ``steps`` transitions."""
    cut = {
        k: (None if getattr(split, k) is None else getattr(split, k)[:n, : steps + 1])
        for k in ("nodes", "p", "v", "q", "omega")
    }
    return Split(control=split.control[:n, :steps], **cut)


# ---------------------------------------------------------------------- mujoco.sysid
def load_sysid() -> tuple[Any, str]:
    """``mujoco.sysid`` and '' if it works, else (None, why not)."""
    try:
        from mujoco import sysid
    except ImportError as e:
        return None, f"import mujoco.sysid failed: {e!r}"
    if not hasattr(sysid, "optimize"):
        # mujoco.sysid swallows ModuleNotFoundError of its optional dependencies
        try:
            import mujoco.sysid._src.optimize  # noqa: F401
        except ImportError as e:
            return None, (
                f"mujoco.sysid is missing its optional dependencies ({e!r}); install "
                "them with: pip install 'mujoco[sysid]' (or this project's .[bench] extra)"
            )
        return None, "mujoco.sysid imported but has no 'optimize' (unsupported MuJoCo version?)"
    return sysid, ""


def sysid_problem(
    sysid: Any,
    asm: MjcfAssembly,
    mjcf: str,
    split: Split,
    dt: float,
    anchor_mass: float,
    perturb: float,
    seed: int,
    threads: int,
) -> tuple[Any, Callable[..., Any], dict[str, np.ndarray]]:
    """Parameters (perturbed start), residual function and true values for mujoco.sysid.

    Measurements are the free-joint qpos of every rod at every sample (the dataset's
    rod states converted back to MuJoCo coordinates); controls are the recorded ones.
    """
    model = asm.model
    rods = [model.body(int(b)).name for b in asm.rod_bodies]
    # mujoco.sysid 4.0.0's TimeSeries.from_names resolves a *named* free joint to width 1
    # (it looks numpy joint types up in a dict keyed by the enum), so give the layout.
    layout = {
        f"{r}_qpos": (sysid.SignalType.MjStateQPos, np.arange(7 * j, 7 * j + 7))
        for j, r in enumerate(rods)
    }
    T = split.n_transitions
    times = np.arange(T + 1) * dt
    act = asm.actuators
    has = act >= 0
    inits, controls, measured = [], [], []
    for i in range(split.n_trajectories):
        qpos, qvel = rod_state_to_mj(asm, split.p[i], split.v[i], split.q[i], split.omega[i])
        ctrl = np.zeros((T + 1, model.nu))  # one control per sample; the last is unused
        ctrl[:T, act[has]] = split.control[i][:, has]
        inits.append(sysid.create_initial_state(model, qpos[0], qvel[0]))
        controls.append(sysid.TimeSeries.from_control_names(times, ctrl, model))
        cols = np.concatenate([qpos[:, a : a + 7] for a in asm.rod_qpos], axis=1)
        measured.append(sysid.TimeSeries.create(times, cols, layout))

    spec = mujoco.MjSpec.from_string(mjcf)
    rng = np.random.default_rng(seed)
    params = sysid.ParameterDict()
    truth: dict[str, np.ndarray] = {}

    def add(name: str, true: np.ndarray, modifier: Callable[[Any, Any], None]) -> None:
        start = true * np.exp(rng.uniform(-perturb, perturb, true.shape))
        params.add(sysid.Parameter(name, start, 0.5 * start, 2.0 * start, modifier=modifier))
        truth[name] = true

    def set_tendon(attr: str, n: str, make: Callable[[float], list[float]]) -> Any:
        return lambda s, p: setattr(s.tendon(n), attr, make(float(p.value[0])))

    for t in range(model.ntendon):
        n = model.tendon(t).name
        add(f"stiffness[{n}]", np.array([model.tendon_stiffness[t]]),
            set_tendon("stiffness", n, lambda v: [v, 0.0, 0.0]))  # fmt: skip
        add(f"damping[{n}]", np.array([model.tendon_damping[t]]),
            set_tendon("damping", n, lambda v: [v, 0.0, 0.0]))  # fmt: skip
        add(f"rest_length[{n}]", np.array([model.tendon_lengthspring[t, 0]]),
            set_tendon("springlength", n, lambda v: [v, v]))  # fmt: skip
    for j, (r, b) in enumerate(zip(rods, asm.rod_bodies, strict=True)):
        if j == 0:
            spec.body(r).mass = anchor_mass  # the anchor: a weighed rod
        else:
            add(f"mass[{r}]", np.array([model.body_mass[b]]),
                lambda s, p, r=r: setattr(s.body(r), "mass", float(p.value[0])))  # fmt: skip
        inertia = model.body_inertia[b]
        add(f"inertia[{r}]", np.array([inertia[0], inertia[2]]),
            lambda s, p, r=r: setattr(s.body(r), "inertia", [p.value[0], p.value[0], p.value[1]]))  # fmt: skip
    sysid.apply_param_modifiers_spec(params, spec)  # the starting model is the perturbed one
    sequences = sysid.ModelSequences(
        "icosahedron", spec, [f"test{i}" for i in range(len(inits))], inits, controls, measured,
        allow_missing_sensors=True,  # measurements are qpos, not MuJoCo sensors
    )  # fmt: skip
    residual = sysid.build_residual_fn(models_sequences=[sequences], n_threads=threads)
    return params, residual, truth


def sysid_errors(params: Any, truth: dict[str, np.ndarray]) -> dict[str, float]:
    out: dict[str, float] = {}
    for name in params.keys():
        g = name.split("[")[0]
        e = float(np.max(np.abs(params[name].value - truth[name]) / np.abs(truth[name])))
        out[g] = max(out.get(g, 0.0), e)
    return out


def sysid_to_params(
    params: Any, asm: MjcfAssembly, anchor_mass: float, gravity: np.ndarray
) -> Params:
    """Our Params from mujoco.sysid's values (the control gain kept from the start model)."""
    model = asm.model
    rods = [model.body(int(b)).name for b in asm.rod_bodies]
    springs = [model.tendon(t).name for t in range(model.ntendon)]
    val = {k: params[k].value for k in params.keys()}
    inertia = np.array([[val[f"inertia[{r}]"][i] for i in (0, 0, 1)] for r in rods])
    mass = [anchor_mass] + [float(val[f"mass[{r}]"][0]) for r in rods[1:]]
    return Params.create(
        stiffness=[val[f"stiffness[{s}]"][0] for s in springs],
        damping=[val[f"damping[{s}]"][0] for s in springs],
        rest_length=[val[f"rest_length[{s}]"][0] for s in springs],
        mass=mass,
        inertia=inertia,
        control_gain=asm.params.control_gain,
        gravity=gravity,
    )


# ---------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--dataset", type=Path, default=Path("out/paper.h5"),
                    help="paper-scale dataset; generated there if missing (default out/paper.h5)")  # fmt: skip
    ap.add_argument("--seed", type=int, default=0, help="generation seed if generated (default 0)")
    ap.add_argument("--anchor", metavar="NAME=VALUE",
                    help="scale anchor (default: mass[rod0] from the ground truth, as if weighed)")  # fmt: skip
    ap.add_argument("--profile-fraction", type=float, default=0.1,
                    help="fraction of the data profiled when the fit misses the target (default 0.1)")  # fmt: skip
    ap.add_argument("--sysid-trajectories", type=int, default=3,
                    help="test trajectories given to mujoco.sysid (default 3; 0 skips it)")  # fmt: skip
    ap.add_argument("--sysid-steps", type=int, default=None,
                    help="transitions per trajectory for mujoco.sysid (default: all)")  # fmt: skip
    ap.add_argument("--perturb", type=float, default=0.2,
                    help="mujoco.sysid start: each value times exp(U(-p, p)) (default 0.2)")  # fmt: skip
    ap.add_argument("--max-iters", type=int, default=30,
                    help="mujoco.sysid iterations at most (default 30)")  # fmt: skip
    args = ap.parse_args(argv)

    n_cores = cores()
    print(
        f"machine: {n_cores} cores available to this process, torch {torch.__version__} with "
        f"{torch.get_num_threads()} threads, MuJoCo {mujoco.__version__}; load average "
        f"{load()} (other processes share these cores: timings scale with it)"
    )
    ensure_dataset(args.dataset, args.seed)

    # --- reading, then fitting, timed apart
    t0 = time.perf_counter()
    dataset = read_dataset(args.dataset, splits=("train", "test"))
    read_s = time.perf_counter() - t0
    gt = read_ground_truth(args.dataset)
    train = dataset.split("train")
    n_tr = train.n_trajectories * train.n_transitions
    nbytes = sum(
        getattr(s, k).nbytes
        for s in dataset.splits.values()
        for k in ("nodes", "control", "p", "v", "q", "omega")
        if getattr(s, k) is not None
    )
    print(
        f"read HDF5 (train + test splits, {nbytes / 1e6:,.0f} MB of arrays): {read_s:.2f} s; "
        f"{train.n_trajectories} x {train.n_transitions} = {n_tr:,} training transitions"
    )
    if args.anchor:
        anchor_name, anchor_value = parse_anchor(args.anchor)
        print(f"anchor: {anchor_name} = {anchor_value:g} (given)")
    else:
        if gt is None:
            raise SystemExit("the dataset has no ground truth: pass --anchor NAME=VALUE")
        anchor_name, anchor_value = "mass[rod0]", float(gt.params.mass[0])
        print(
            f"anchor: {anchor_name} = {anchor_value:.6g} kg, taken from the dataset's ground "
            "truth (stands in for weighing one rod)"
        )
    anchors = {anchor_name: anchor_value}

    SpringRodIdentifier(anchors=anchors, max_transitions=100).fit(dataset)  # torch warm-up
    t0 = time.perf_counter()
    est = SpringRodIdentifier(anchors=anchors).fit(dataset)
    fit_s = time.perf_counter() - t0
    ours_err = errors_of(est.table_, gt.params) if gt is not None else {}
    print(
        f"\nSpringRodIdentifier.fit, all {est.n_transitions_:,} transitions: {fit_s:.2f} s "
        f"(after a warm-up fit; target {TARGET_S:g} s on 2 cores: ratio {fit_s / TARGET_S:.2f}, "
        f"{'MET' if fit_s <= TARGET_S else 'MISSED'}); read + fit {read_s + fit_s:.2f} s; "
        f"{fit_s / est.n_transitions_ * 1e6:.1f} us per transition"
    )
    if ours_err:
        print(
            "  largest relative error: "
            + ", ".join(f"{LABELS[g]} {e:.1e}" for g, e in ours_err.items())
            + f"; not identifiable: {', '.join(est.unidentifiable()) or 'none'}"
        )
    print(f"  normal matrix built by the {est.backend_} backend")
    frac = args.profile_fraction
    t0 = time.perf_counter()
    SpringRodIdentifier(anchors=anchors, fraction=frac, backend="torch").fit(dataset)
    torch_s = (time.perf_counter() - t0) / frac
    print(
        f"  the PyTorch backend (design blocks in chunks) on {frac:g} of the transitions, "
        f"extrapolated to all: {torch_s:.1f} s -> the {est.backend_} backend is "
        f"{torch_s / fit_s:.1f}x faster"
    )
    if fit_s > TARGET_S:
        wall, stages = profile_stages(
            lambda: SpringRodIdentifier(anchors=anchors, fraction=frac).fit(dataset)
        )
        print(
            f"  profile of a fit on {frac:g} of the transitions ({wall:.2f} s under cProfile, "
            f"x{1 / frac:g} = {wall / frac:.1f} s extrapolated); cumulative time per stage:"
        )
        for label, sec in stages:
            print(f"    {label:<46s} {sec:7.2f} s  {100 * sec / wall:5.1f} %")

    # --- test-split rollouts of our fit
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    ours_score = est.score(dataset, "test")
    score_s = time.perf_counter() - t0
    rows.append(
        {
            "method": "tensegrity-sr lstsq",
            "data": f"train, {n_tr:,} transitions",
            "n_params": n_free(est),
            "wall": fit_s,
            "errors": ours_err,
            "rollout": ours_score["rollout_mean_position_error"],
        }
    )

    # --- mujoco.sysid on a few test trajectories
    sysid_note = ""
    n_sys = args.sysid_trajectories
    if n_sys > 0 and gt is not None:
        sysid, why = load_sysid()
        test = dataset.split("test")
        steps = min(args.sysid_steps or test.n_transitions, test.n_transitions)
        n_sys = min(n_sys, test.n_trajectories)
        sub = head(test, n_sys, steps)
        what = f"test[:{n_sys}], {n_sys * steps:,} transitions"
        # ours on exactly the same trajectories
        small = Dataset(dataset.topology, dataset.dt, {"train": sub})
        t0 = time.perf_counter()
        est_small = SpringRodIdentifier(anchors=anchors).fit(small)
        small_s = time.perf_counter() - t0
        rows.append(
            {
                "method": "tensegrity-sr lstsq",
                "data": what,
                "n_params": n_free(est_small),
                "wall": small_s,
                "errors": errors_of(est_small.table_, gt.params),
                "rollout": est_small.score(dataset, "test")["rollout_mean_position_error"],
            }
        )
        if sysid is None:
            sysid_note = f"mujoco.sysid not run: {why}"
        else:
            rows += run_sysid(sysid, gt, dataset, sub, what, anchor_value, args, n_cores)
    elif gt is None:
        sysid_note = "mujoco.sysid not run: the dataset has no ground-truth MJCF to start from"

    # --- one table
    print(
        f"\nIdentification on the icosahedron ({dataset.topology.n_rods} rods, "
        f"{dataset.topology.n_springs} springs); relative errors are the largest per group "
        "(rod0's mass is the anchor); rollout = mean rod position error over the whole test "
        f"split ({dataset.split('test').n_trajectories} x {dataset.split('test').n_transitions}"
        " steps) with our engine [m]:\n"
    )
    header = ["method", "data", "params", "wall [s]", *(LABELS[g] for g in GROUPS), "max"]
    header.append("rollout [m]")
    table = [header]
    for r in rows:
        errs = r["errors"]
        table.append(
            [
                r["method"],
                r["data"],
                str(r["n_params"]),
                f"{r['wall']:.2f}" if np.isfinite(r["wall"]) else "—",
                *(f"{errs[g]:.1e}" if g in errs else "—" for g in GROUPS),
                f"{max(errs.values()):.1e}" if errs else "—",
                f"{r['rollout']:.1e}" if np.isfinite(r["rollout"]) else "—",
            ]
        )
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]
    for k, row in enumerate(table):
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)))
        if k == 0:
            print("  ".join("-" * w for w in widths))
    if sysid_note:
        print(f"\n{sysid_note}")
    print(
        f"\nsummary: read {read_s:.2f} s, fit {fit_s:.2f} s (target {TARGET_S:g} s, ratio "
        f"{fit_s / TARGET_S:.2f}), test-split scoring {score_s:.2f} s; load average {load()}"
    )
    return 0


def run_sysid(
    sysid: Any,
    gt: GroundTruth,
    dataset: Dataset,
    sub: Split,
    what: str,
    anchor_mass: float,
    args: argparse.Namespace,
    threads: int,
) -> list[dict[str, Any]]:
    """Fit with mujoco.sysid; rows for the perturbed start and the result."""
    from absl import logging as absl_logging

    absl_logging.set_verbosity(absl_logging.ERROR)  # one warning per trajectory otherwise
    asm = from_mjcf("<ground truth>", xml=gt.mjcf)
    gravity = np.asarray(asm.model.opt.gravity, dtype=float)
    nan = float("nan")
    try:
        params, residual, truth = sysid_problem(
            sysid, asm, gt.mjcf, sub, dataset.dt, anchor_mass, args.perturb, args.seed, threads
        )
        start = {
            "method": f"mujoco.sysid start (x exp(U(±{args.perturb:g})))",
            "data": "—",
            "n_params": params.size,
            "wall": nan,
            "errors": sysid_errors(params, truth),
            "rollout": evaluate_params(
                asm.topology, sysid_to_params(params, asm, anchor_mass, gravity), dataset
            )["rollout_mean_position_error"],
        }
        log = io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(log):
            opt, _ = sysid.optimize(
                params, residual, optimizer="mujoco", verbose=False,
                max_iters=args.max_iters, x_scale="jac", output=log,
            )  # fmt: skip
        wall = time.perf_counter() - t0
    except Exception as e:  # report exactly why, keep the rest of the benchmark
        print(f"\nmujoco.sysid failed: {e!r}\n{traceback.format_exc()}")
        return []
    done = [ln.strip() for ln in log.getvalue().splitlines() if ln.startswith("Terminated")]
    print(
        f"\nmujoco.sysid ({threads} rollout threads, x_scale='jac', {sub.n_trajectories} "
        f"trajectories x {sub.n_transitions} steps): {wall:.1f} s; {' '.join(done)}"
    )
    result = {
        "method": "mujoco.sysid (LM, FD Jacobian)",
        "data": what,
        "n_params": opt.size,
        "wall": wall,
        "errors": sysid_errors(opt, truth),
        "rollout": evaluate_params(
            asm.topology, sysid_to_params(opt, asm, anchor_mass, gravity), dataset
        )["rollout_mean_position_error"],
    }
    return [start, result]


if __name__ == "__main__":
    raise SystemExit(main())
