"""``make demo``: every capability end to end on small embedded defaults.

Generates MuJoCo ground truth, identifies the icosahedron and the one-rod element by
linear regression, finds planted effects, compares the identified env with its MuJoCo
twin and transfers the shipped policy, writing every table and figure into one folder
named at the end. ``--full`` (``make demo-full``) runs the same steps on the larger
defaults of the documentation.

Each step is a function ``step_<name>(demo: Demo)`` listed in :data:`STEPS`; adding a
step is writing one such function and adding it there. ``Demo.size(small, full)``
picks a size, ``Demo.cli(...)`` runs a ``tensegrity-sr`` command.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch

from identification.data.dataset import read_dataset, read_ground_truth, write_dataset
from identification.linear.regression import SpringRodIdentifier
from identification.report.plots import plot_rollout_comparison
from identification.report.tables import group_errors, parameter_table
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.assemblies import node_positions
from tensegrity_env.engine import State
from tensegrity_env.io_utils import (
    InputError,
    atomic_write_text,
    check_output_dir,
    run_reporting,
)
from tensegrity_env.ntrt import EXAMPLE_PRISM
from tensegrity_sr.cli import main as cli

T = TypeVar("T")


@dataclass
class Demo:
    """What every step gets: the output folder and the demo's settings.

    Attributes:
        out: the folder every output goes into.
        full: the larger defaults (``--full``) instead of the small ones.
        force: replace outputs of an earlier run in ``out``.
    """

    out: Path
    full: bool = False
    force: bool = False

    def size(self, small: T, full: T) -> T:
        """``small`` for ``make demo``, ``full`` for ``make demo-full``."""
        return full if self.full else small

    def cli(self, *argv: object, writes: bool = True) -> None:
        """Run ``tensegrity-sr ARGV`` (with ``--force`` under ``--force`` when it writes)."""
        args = [str(a) for a in argv] + (["--force"] if writes and self.force else [])
        code = cli(args)
        if code:
            raise SystemExit(code)


def banner(text: str) -> None:
    print(f"\n{'=' * 78}\n{text}\n{'=' * 78}", flush=True)


def step_generate(demo: Demo) -> None:
    banner("MuJoCo ground truth: free icosahedron (6 rods, 24 springs), no control forces")
    path = demo.out / "icosahedron_small.h5"
    demo.cli("generate", "--preset", "small", "--seed", "0", "--no-progress", "-o", path)
    demo.cli("inspect", path, writes=False)


def step_identify(demo: Demo) -> None:
    banner("Identify K, c, l0, M, I, h by linear regression (rod0 weighed as the anchor)")
    out = demo.out
    data_path = out / "icosahedron_small.h5"
    truth = read_ground_truth(data_path)
    assert truth is not None
    # a user weighs one rod; here the scale gets its anchor from the simulator's rod0
    mass0 = float(truth.params.mass[0])
    demo.cli("identify", data_path, "--anchor", f"mass[rod0]={mass0!r}", "-o", out / "params.json")

    dataset = read_dataset(data_path)
    est = SpringRodIdentifier(anchors={"mass[rod0]": mass0}).fit(dataset)
    atomic_write_text(
        out / "identification_table.md",
        "# Identified icosahedron parameters\n\n"
        + parameter_table(est.table_, truth.params, markdown=True)
        + "\n",
    )
    score = est.score(dataset, "test")
    test = dataset.split("test")
    assert test.p is not None and test.v is not None and test.q is not None
    assert test.omega is not None  # generated data holds the rod states
    init = State.from_numpy(test.p[:1, 0], test.v[:1, 0], test.q[:1, 0], test.omega[:1, 0])
    roll = est.simulate(init, test.n_transitions, torch.as_tensor(test.control[:1]))
    model_nodes = np.stack(
        [
            node_positions(dataset.topology, p, q)
            for p, q in zip(roll.p[0].numpy(), roll.q[0].numpy(), strict=True)
        ]
    )
    plot_rollout_comparison(
        test.nodes[0],
        model_nodes,
        dataset.dt,
        score["rollout_curve"],
        out / "rollout_icosahedron.png",
    )
    print(f"figure: {out / 'rollout_icosahedron.png'}")


def step_element(demo: Demo) -> None:
    banner("The paper's basic element: one rod held by two springs")
    spec = GenerateSpec(
        assembly="element", n_train=8, n_val=0, n_test=2, steps=300, seed=1, control_std=1.0
    )
    dataset, truth = generate_dataset(spec)
    path = write_dataset(demo.out / "element_small.h5", dataset, truth)
    est = SpringRodIdentifier(anchors={"mass[rod0]": float(truth.params.mass[0])}).fit(dataset)
    print(parameter_table(est.table_, truth.params))
    worst = group_errors(est.table_, truth.params)
    print(f"largest relative error: {max(worst.values()):.2e}   (dataset: {path})")


def step_control_gain(demo: Demo) -> None:
    banner("Control gain h: perturbation forces, every other module frozen (paper Sec. 4.4)")
    out = demo.out
    path = out / "icosahedron_perturbed.h5"
    demo.cli("generate", "--preset", "perturbed", "--n-train", 2, "--n-test", 2,
             "--steps", demo.size(2000, 4000), "--seed", 1, "--no-progress", "-o", path)  # fmt: skip
    params_h = out / "params_with_h.json"
    demo.cli("identify", path, "--params", out / "params.json", "--freeze",
             "stiffness,damping,rest_length,mass,inertia", "--horizon", 1000, "-o", params_h)  # fmt: skip
    print("\nBefore (h not identifiable without control, assumed 1) and after (h identified):")
    demo.cli("evaluate", path, "--params", out / "params.json", "--label", "before: h assumed 1",
             "--params", params_h, "--label", "after: h identified", "-o", out / "long_horizon")  # fmt: skip


def step_experiment(demo: Demo) -> None:
    banner("The paper's experiments: ours vs Interaction, Interaction+Int, Koopman+Int")
    demo.cli("experiment", "paper", "--scale", demo.size("small", "full"),
             "-o", demo.out / "experiment")  # fmt: skip


def step_diagnose(demo: Demo) -> None:
    banner("The closed loop: MuJoCo data with an undeclared floor; find it, name it, add it")
    path = demo.out / "planted_contact.h5"
    demo.cli("plant", "ground_contact", "--n-train", 4, "--n-val", 2, "--n-test", 2,
             "--steps", 500, "--seed", 0, "-o", path)  # fmt: skip
    truth = read_ground_truth(path)
    assert truth is not None
    mass0 = float(truth.params.mass[0])  # a weighed rod fixes the scale, as in step 2
    # small: stop at the first effect found; full: also show that nothing else is missing
    demo.cli("diagnose", path, "--anchor", f"mass[rod0]={mass0!r}",
             "--max-effects", demo.size(1, 2),
             "--horizon", 0.5, "-o", demo.out / "diagnose")  # fmt: skip


def step_touchdowns(demo: Demo) -> None:
    banner("The same floor through 1 mm motion-capture noise, from the data alone")
    from identification.experiments.drop_check import DROP_TOLERANCE, drop_check
    from identification.trajectory.end_cap_data import EndCapData, TrajectorySettings
    from identification.trajectory.presets import fit_declared
    from identification.trajectory.touchdown import contact_from_dataset
    from tensegrity_env.effects.ground_contact import MUJOCO_DEFAULT

    out = demo.out
    path = out / "planted_contact_noisy.h5"
    demo.cli("plant", "ground_contact", "--noise", 0.001, "--n-train", demo.size(6, 6),
             "--n-val", 1, "--n-test", 1, "--steps", 500, "--seed", 5, "-o", path)  # fmt: skip
    dataset, truth = read_dataset(path), read_ground_truth(path)
    assert truth is not None
    # the declared model from the airborne stretches of the same data (no calibration),
    # then the contact from the touchdowns
    t0 = time.perf_counter()
    settings = TrajectorySettings(anchors={"mass[rod0]": float(truth.params.mass[0])}, seed=5)
    declared = fit_declared(EndCapData(dataset, settings), settings)[0].params
    lines = [f"declared model from the airborne stretches ({time.perf_counter() - t0:.0f} s), "
             "median error against MuJoCo:"]  # fmt: skip
    for k in ("mass", "stiffness", "damping", "rest_length"):
        err = np.median(np.abs(getattr(declared, k).numpy() / getattr(truth.params, k).numpy() - 1))
        lines.append(f"  {k}: {100 * err:.2f} %")
    print("\n".join(lines))
    found = contact_from_dataset(dataset, declared, log=print)
    if found is None:
        raise SystemExit("no touchdown in the noisy contact data")
    c = found.contact
    lines += ["", "| contact parameter | identified | MuJoCo |", "|---|---|---|"]
    for k in ("stiffness", "damping", "friction", "impedance"):
        lines.append(f"| {k} [{c.PARAMS[k].unit}] | {float(c.values[k]):.4g} ± "
                     f"{c.uncertainty[k]:.2g} | {MUJOCO_DEFAULT[k]:.4g} |")  # fmt: skip
    drop = drop_check(declared, [c])
    verdict = "within" if drop.worst < DROP_TOLERANCE else "NOT within"
    lines.append(f"\n2-s drop and bounce from rest, 3 drops, the identified declared model and "
                 f"contact: worst mean end-cap error {drop.worst * 1e3:.1f} mm ({verdict} "
                 f"{DROP_TOLERANCE * 1e2:g} cm of MuJoCo)")  # fmt: skip
    print("\n".join(lines[-7:]))
    atomic_write_text(out / "contact_from_touchdowns.md",
                      "# Declared model and contact from noisy floor data\n\n"
                      + "\n".join(lines) + "\n")  # fmt: skip


def step_lab_robot(demo: Demo) -> None:
    banner("A robot model as labs write it: sphere end caps, cables off the caps, filtered "
           "cable actuators, on a floor")  # fmt: skip
    from tensegrity_env.model import Model

    robot = Path(__file__).resolve().parent.parent / "tensegrity_env" / "assets" / "lab_prism_force_actuators.xml"
    path = demo.out / "lab_prism.h5"
    demo.cli("generate", "--mjcf", robot, "--n-train", demo.size(4, 8), "--n-val", 1,
             "--n-test", 1, "--steps", 1000, "--seed", 11, "--control-std", 1,
             "--no-progress", "-o", path)  # fmt: skip
    truth = read_ground_truth(path)
    assert truth is not None
    # the floor and the filter are in the file, but the data alone has to show them
    demo.cli("diagnose", path, "--anchor", f"mass[r0]={float(truth.params.mass[0])!r}",
             "--candidates", "ground_contact,control_lag,linear_drag", "--max-effects", 2,
             "-o", demo.out / "diagnose_lab")  # fmt: skip
    found = Model.load(demo.out / "diagnose_lab" / "params.json")
    declared = {e.name: e for e in Model.read(robot).effects}
    lines = ["| effect | parameter | identified | in the file |", "|---|---|---|---|"]
    for e in found.effects:
        for key, spec in e.PARAMS.items():
            if key in ("time_constant", "stiffness", "damping", "impedance", "friction"):
                lines.append(f"| {e.name} | {key} [{spec.unit}] | {float(e.values[key]):.5g} | "
                             f"{float(declared[e.name].values[key]):.5g} |")  # fmt: skip
    print("\n".join(lines))
    atomic_write_text(demo.out / "lab_robot.md", "# Floor contact and actuator filter of "
                      "the lab prism, from its motion\n\n" + "\n".join(lines) + "\n")  # fmt: skip


def step_slack(demo: Demo) -> None:
    banner("Which springs are cables? Segmented regression through 1 mm noise")
    from identification.data.end_caps import RodAxes, smooth_rod_states
    from identification.trajectory.slack_regression import (
        CABLE_LOSS,
        CABLE_SIGNIFICANCE,
        slack_regression,
    )

    path = demo.out / "planted_slack_noisy.h5"
    demo.cli("plant", "slack_springs", "--noise", 0.001, "--n-train", 4, "--n-val", 1,
             "--n-test", 1, "--seed", 3, "-o", path)  # fmt: skip
    dataset, truth = read_dataset(path), read_ground_truth(path)
    assert truth is not None
    topo, train = dataset.topology, dataset.split("train")
    smooth = smooth_rod_states(train.nodes, dataset.dt, RodAxes.of(topo), 101)
    reg = slack_regression(topo, smooth, train.control, {"mass[rod0]": float(truth.params.mass[0])})
    true = set(truth.effects[0]["params"]["springs"])
    lines = [f"knots at the fitted rest lengths after {reg.iterations} updates; a cable loses "
             f"at least {CABLE_LOSS:.0%} of K when compressed, by "
             f"{CABLE_SIGNIFICANCE:g} standard errors", "",
             "| spring | loss of K when compressed | standard errors | named | planted |",
             "|---|---|---|---|---|"]  # fmt: skip
    named = set(reg.cables())
    for i in range(topo.n_springs):
        lines.append(f"| {topo.springs[i].name} | {reg.loss[i]:+.2f} | {reg.significance[i]:.0f} "
                     f"| {'cable' if i in named else ''} | {'cable' if i in true else ''} |")  # fmt: skip
    verdict = "every planted cable and nothing else" if named == true else "NOT the planted set"
    lines += ["", f"named {len(named)} cables: {verdict} (planted {len(true)})"]
    print("\n".join(lines))
    atomic_write_text(demo.out / "slack_cables.md", "# Cables from noisy end caps\n\n"
                      + "\n".join(lines) + "\n")  # fmt: skip


def step_environments(demo: Demo) -> None:
    banner("IcosahedronSR-v0 (identified engine) next to IcosahedronMJ-v0 (MuJoCo twin)")
    from tensegrity_env.envs import IcosahedronMJEnv, IcosahedronSREnv, RenderingUnavailable
    from tensegrity_env.envs.rendering import record_side_by_side

    def push_to_goal(obs: np.ndarray) -> np.ndarray:
        """Every rod pushes along the direction to the goal (observation entries 73-74)."""
        g = obs[73:75] / max(float(np.linalg.norm(obs[73:75])), 1e-9)
        return np.tile([g[0], g[1], 0.0], 6).astype(np.float32)

    kw: dict[str, Any] = {"render_mode": "rgb_array", "width": 400, "height": 300}
    sr, mj = IcosahedronSREnv(**kw), IcosahedronMJEnv(**kw)
    try:
        clip = record_side_by_side(
            sr, mj, demo.out / "envs_side_by_side.mp4", push_to_goal, max_steps=80
        )
        print(f"clip (left: identified engine, right: MuJoCo twin, same start and actions): {clip}")
    except RenderingUnavailable as e:
        print(f"no clip: {e}")
    gap = np.linalg.norm(sr.state[:, :3].mean(axis=0) - mj.state[:, :3].mean(axis=0))
    print(f"at the end the two centres are {1e3 * gap:.1f} mm apart; distance to the goal "
          f"{sr.distance_to_goal:.2f} m (identified) and {mj.distance_to_goal:.2f} m (twin)")  # fmt: skip


def step_transfer(demo: Demo) -> None:
    banner("Sim-to-sim transfer: the shipped PPO policy (trained on IcosahedronSR-v0) in MuJoCo")
    from policies import SHIPPED_POLICY
    from policies.artifacts import load_policy
    from policies.transfer import side_by_side_video, transfer, transfer_table
    from tensegrity_env.envs import RenderingUnavailable

    policy = load_policy(SHIPPED_POLICY)
    print(f"policy: {SHIPPED_POLICY.name}, trained with: {policy.record.get('command', '?')}")
    result = transfer(policy, episodes=demo.size(5, 20), seed=1000)
    table = transfer_table(result, f"shipped {policy.algo}")
    print(table)
    atomic_write_text(demo.out / "transfer.md", f"# Transfer of the shipped policy\n\n{table}\n")
    try:
        clip = side_by_side_video(policy, demo.out / "transfer_side_by_side.mp4", seed=1003)
        print(f"clip (left: identified engine, right: MuJoCo twin, same policy): {clip}")
    except RenderingUnavailable as e:
        print(f"no clip: {e}")


def step_mocap(demo: Demo) -> None:
    banner("Motion capture in: an unlabelled C3D export (120 Hz, 1 mm noise, 1 % dropouts), "
           "a y-up Motive CSV, a cable-driven icosahedron with its command logs")
    from identification.data.mocap.c3d_files import write_c3d
    from identification.simulation.mocap_takes import record_take, simulate_caps

    robot = (
        Path(__file__).resolve().parent.parent
        / "tensegrity_env"
        / "assets"
        / "icosahedron_rolling.xml"
    )
    rng = np.random.default_rng(120)
    files = []
    for k in range(demo.size(3, 8)):
        t, caps, names = simulate_caps(robot.read_text(), 120.0, demo.size(1.0, 3.0), rng)
        take = record_take(
            t, caps, names, rng, noise=1e-3, dropout=0.01, unlabelled=True, ghosts=0.05
        )
        files.append(write_c3d(demo.out / f"take{k}.c3d", take.points, take.names, 120.0))
    data = demo.out / "mocap.h5"
    demo.cli("import-mocap", *files, "--robot", robot, "-o", data)
    demo.cli("inspect", data, "--plot", demo.out / "mocap_quality.png")
    print("a labelled Motive CSV export, y-up, unseen markers written as 0: read as gaps")
    from identification.data.mocap.csv_files import write_motive_csv
    from identification.data.mocap.recording import TO_Z_UP

    t, caps, names = simulate_caps(robot.read_text(), 120.0, demo.size(1.0, 3.0), rng)
    take = record_take(t, caps, names, rng, noise=1e-3, dropout=0.01)
    y_up = np.nan_to_num(take.points, nan=0.0) @ TO_Z_UP["y"]
    motive = write_motive_csv(demo.out / "take_motive.csv", t, y_up, take.names, 120.0)
    demo.cli("inspect", motive, writes=False)  # the lowest marker's narrow band: along y
    demo.cli("import-mocap", motive, "--robot", robot, "--up", "y", "--split", "1,0,0",
             "-o", demo.out / "mocap_motive.h5")  # fmt: skip
    print("a cable-driven icosahedron: takes with their motor command logs (20 Hz), imported "
          "and identified from the end caps (cable gains against the robot file's)")
    from identification.data.mocap.commands import write_commands
    from tensegrity_env.mjcf import from_mjcf
    from tensegrity_env.model import Model

    cabled = robot.parent / "icosahedron_cables.xml"
    takes, logs = [], []
    for k in range(demo.size(6, 12)):
        log_t = np.arange(0.0, 0.6, 0.05)
        log_u = rng.uniform(-0.5, 0.5, (len(log_t), 3))
        t, caps, names = simulate_caps(cabled.read_text(), 120.0, 0.6, rng, commands=(log_t, log_u))
        take = record_take(t, caps, names, rng, noise=1e-3)
        takes.append(write_c3d(demo.out / f"cables_take{k}.c3d", take.points, take.names, 120.0))
        log = write_commands(demo.out / f"cables_commands{k}.csv", log_t, log_u, ["a0", "a1", "a2"])
        logs += ["--commands", log]
    demo.cli("import-mocap", *takes, "--robot", cabled, *logs, "-o", demo.out / "mocap_cables.h5")
    truth = from_mjcf(cabled).params
    demo.cli("identify", demo.out / "mocap_cables.h5", "--anchor", f"mass[rod0]={float(truth.mass[0])!r}",
             "-o", demo.out / "cables_params.json")  # fmt: skip
    got = Model.load(demo.out / "cables_params.json").params.cable_gain.numpy()
    print("cable gains [N/unit]: identified " + ", ".join(f"{g:.2f}" for g in got)
          + "; robot file " + ", ".join(f"{g:.0f}" for g in truth.cable_gain.numpy()))


def step_winch_robot(demo: Demo) -> None:
    banner("A winch-driven cable robot, data to env: the lab 3-bar's six winches (v_max, motor "
           "lag) and cables identified, then TensegritySR-v0 next to TensegrityMJ-v0")  # fmt: skip
    from tensegrity_env.envs import RenderingUnavailable, TensegrityMJEnv, TensegritySREnv
    from tensegrity_env.envs.rendering import record_side_by_side
    from tensegrity_env.model import Model

    out = demo.out
    robot = Path(__file__).resolve().parent.parent / "tensegrity_env" / "assets" / "lab_prism.xml"
    # the regression on rod states models no contact: the data is the robot hung in the
    # air (its floor removed); the env's model takes the floor contact from the robot file
    text, floors = re.subn(r"<geom[^>]*type=\"plane\"[^>]*/>", "", robot.read_text())
    assert floors == 1, f"{robot}: {floors} floor planes"
    hung = out / "lab_prism_hung.xml"
    atomic_write_text(hung, text)
    path = out / "lab_prism_winches.h5"
    demo.cli("generate", "--mjcf", hung, "--n-train", demo.size(3, 8), "--n-val", 0,
             "--n-test", 1, "--steps", 600, "--seed", 4, "--control-std", 1, "--no-progress",
             "-o", path)  # fmt: skip
    truth = read_ground_truth(path)
    assert truth is not None
    identified = out / "lab_prism_params.json"
    # --params: the winches' ranges (never reached in the data) come from the robot file
    demo.cli("identify", path, "--anchor", f"mass[r0]={float(truth.params.mass[0])!r}",
             "--params", robot, "--winch-lag", "auto", "-o", identified)  # fmt: skip
    found = Model.load(identified)
    wound = list(found.topology.winches)
    lines = ["| parameter | largest relative error against MuJoCo |", "|---|---|"]
    for key, idx in (("winch_speed", slice(None)), ("winch_lag", slice(None)),
                     ("stiffness", wound), ("damping", wound)):  # fmt: skip
        got, true = getattr(found.params, key).numpy()[idx], getattr(truth.params, key).numpy()[idx]
        lines.append(f"| {key}{' (wound cables)' if key in ('stiffness', 'damping') else ''} "
                     f"| {np.max(np.abs(got / true - 1)):.1e} |")  # fmt: skip
    print("\n".join(lines))
    atomic_write_text(out / "winch_robot.md", "# The lab 3-bar's winches and cables from rod "
                      "states\n\n" + "\n".join(lines) + "\n")  # fmt: skip
    env_model = found.replace(effects=Model.read(robot).effects)
    env_model.save(out / "lab_prism_env_model.json")
    kw: dict[str, Any] = {"render_mode": "rgb_array", "width": 400, "height": 300}
    sr = TensegritySREnv(model=out / "lab_prism_env_model.json", robot=robot, **kw)
    mj = TensegrityMJEnv(robot=robot, **kw)
    steps = demo.size(40, 200)
    try:
        clip = record_side_by_side(sr, mj, out / "winch_envs_side_by_side.mp4", max_steps=steps)
        print(f"clip (left: identified model, right: MuJoCo twin, same start and random motor "
              f"commands, {steps} steps at 20 Hz): {clip}")  # fmt: skip
    except RenderingUnavailable as e:
        print(f"no clip: {e}")
    gap = np.linalg.norm(sr.state[:, :3] - mj.state[:, :3], axis=1).max()
    print(f"at the end the rod centres of the two envs are at most {1e3 * gap:.2g} mm apart")
    winch_policy_clip(demo, out / "lab_prism_env_model.json")


def winch_policy_clip(demo: Demo, model: Path) -> None:
    """The shipped 3-bar policy walking to a goal in the identified env and in MuJoCo."""
    from policies.artifacts import load_policy, pretrained_path
    from policies.transfer import env_kwargs_of, side_by_side_video
    from tensegrity_env.envs import RenderingUnavailable

    policy = load_policy(pretrained_path("ppo", "TensegritySR-v0"))
    kw = {**env_kwargs_of(policy.record), "model": str(model)}
    try:
        clip = side_by_side_video(policy, demo.out / "winch_policy_side_by_side.mp4", seed=1000,
                                  source="TensegritySR-v0", target="TensegrityMJ-v0",
                                  env_kwargs=kw)  # fmt: skip
        print(f"clip (left: identified model, right: MuJoCo twin, the shipped PPO policy "
              f"walking the 3-bar to a goal from the same start): {clip}")  # fmt: skip
    except RenderingUnavailable as e:
        print(f"no clip: {e}")


def step_ntrt_take(demo: Demo) -> None:
    banner("A lab's export: an NTRT YAML robot (tension-only cables, on a floor) dropped in "
           "the engine, written as an OptiTrack row-format take (unlabelled ids, y up, "
           "0.5 mm noise, dropouts), imported and inspected")  # fmt: skip
    from identification.data.mocap.optitrack_rows import write_optitrack_rows
    from tensegrity_env.model import Model
    from tensegrity_env.ntrt import from_ntrt
    from tensegrity_env.rotations import TO_Z_UP

    rate = 120.0  # [Hz] a common motion-capture rate
    robot = demo.out / "ntrt_prism.yaml"
    atomic_write_text(robot, EXAMPLE_PRISM)
    rest, model = from_ntrt(robot), Model.read(robot, dt=1.0 / rate)
    R, rng = model.topology.n_rods, np.random.default_rng(7)
    # from 0.3 m above its rest pose, turning slowly: free fall, touchdown, rest
    start = State.from_numpy(np.asarray(rest.rest_p)[None] + [0.0, 0.0, 0.3], np.zeros((1, R, 3)),
                             np.asarray(rest.rest_q)[None], rng.normal(0.0, 1.0, (1, R, 3)))  # fmt: skip
    roll = model.engine().rollout(start, model.params, int(1.5 * rate))
    caps = np.stack([node_positions(model.topology, p, q)
                     for p, q in zip(roll.p[0].numpy(), roll.q[0].numpy(), strict=True)])  # fmt: skip
    time_s = np.arange(len(caps)) / rate
    points = (caps + rng.normal(0.0, 5e-4, caps.shape)) @ TO_Z_UP["y"]  # z up -> the file's y up
    ids = np.tile(np.arange(100, 100 + caps.shape[1]), (len(caps), 1))
    lost = rng.random(ids.shape) < 0.01
    points[lost], ids[lost] = np.nan, -1
    take = write_optitrack_rows(demo.out / "ntrt_take.csv", time_s, points, ids)
    data = demo.out / "ntrt_take.h5"
    demo.cli("import-mocap", take, "--robot", robot, "--split", "1,0,0", "-o", data)
    demo.cli("inspect", data, writes=False)

#: the demo's steps, in order: name -> function (steps read what earlier steps wrote)
STEPS: dict[str, Callable[[Demo], None]] = {
    "generate": step_generate,
    "identify": step_identify,
    "mocap": step_mocap,
    "ntrt_take": step_ntrt_take,
    "element": step_element,
    "control_gain": step_control_gain,
    "experiment": step_experiment,
    "diagnose": step_diagnose,
    "touchdowns": step_touchdowns,
    "slack": step_slack,
    "lab_robot": step_lab_robot,
    "environments": step_environments,
    "winch_robot": step_winch_robot,
    "transfer": step_transfer,
}


def run(demo: Demo, steps: list[str]) -> dict[str, float]:
    """Run ``steps`` (names of :data:`STEPS`) in order; returns each one's wall time [s]."""
    seconds: dict[str, float] = {}
    for i, name in enumerate(steps, 1):
        print(f"\n[{i}/{len(steps)}] {name}", flush=True)
        t0 = time.perf_counter()
        STEPS[name](demo)
        seconds[name] = time.perf_counter() - t0
        print(f"[{i}/{len(steps)}] {name}: {seconds[name]:.0f} s", flush=True)
    return seconds


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--out", type=Path, default=Path("demo_out"), help="folder for every output"
    )
    parser.add_argument("--full", action="store_true",
                        help="the larger defaults (make demo-full) instead of the small ones")  # fmt: skip
    parser.add_argument("--force", action="store_true",
                        help="replace the outputs of an earlier run in --out")  # fmt: skip
    parser.add_argument("--steps", default=",".join(STEPS), metavar="NAMES",
                        help=f"comma-separated steps to run, in order (default: all: "
                        f"{','.join(STEPS)}; later steps read what earlier ones wrote)")  # fmt: skip
    args = parser.parse_args(argv)
    steps = [s for s in args.steps.split(",") if s]

    def work() -> int:
        bad = [s for s in steps if s not in STEPS]
        if bad:
            raise InputError(
                f"--steps: unknown step(s) {', '.join(bad)} (known: {', '.join(STEPS)})"
            )
        demo = Demo(check_output_dir(args.out, args.force, option="--out"), args.full, args.force)
        demo.out.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        threads = torch.get_num_threads()
        torch.set_num_threads(1)  # small tensors: more threads only contend, above all on 2 cores
        try:
            seconds = run(demo, steps)
        finally:
            torch.set_num_threads(threads)
        banner(f"Done in {time.perf_counter() - t0:.0f} s "
               f"({', '.join(f'{k} {v:.0f} s' for k, v in seconds.items())}). "
               f"Every output is in: {demo.out.resolve()}")  # fmt: skip
        for f in sorted(demo.out.iterdir()):
            print(f"  {f.name}")
        return 0

    return run_reporting(work)


if __name__ == "__main__":
    sys.exit(main())
