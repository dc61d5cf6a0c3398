"""A cable-driven robot from data to a policy that transfers to its MuJoCo twin.

End to end on a winch-driven robot on a floor (default: the lab 3-bar with six winches,
``tensegrity_env/assets/lab_prism.xml``; ``--robot`` another, e.g. the icosahedron with
twelve, ``icosahedron_winches.xml``, stored under ``--key``):

1. ``tensegrity-sr generate``: MuJoCo data of the robot under random winch commands.
   The identification's regression on rod states models no contact, so the data is the
   robot hung in the air (the file's floor plane removed), as the demo's winch step does.
2. ``tensegrity-sr identify --winch-lag auto``: masses, inertias, cables, winch speeds and
   lags from that data (winch ranges, never reached in it, from the robot file); the
   env's model is the identified parameters with the robot file's floor contact.
3. ``tensegrity-sr train ppo --env TensegritySR-v0 --model params.json --seeds ...``:
   PPO (``policies/hyperparams/ppo.yml``, or ``--hyperparams``: task and goal distances
   in its ``env_kwargs``, the goal-distance curriculum) on the identified model, one run
   per seed (``--workers`` at a time).
4. ``tensegrity-sr transfer``: every seed over the same seeded episodes in
   ``TensegritySR-v0`` and in its twin ``TensegrityMJ-v0`` (the robot file in MuJoCo):
   success rate, transfer ratio (twin return / identified-env return), IQM with 95 %
   bootstrap intervals over the seeds (rliable).
5. ``python -m policies.results --robot lab_prism_winch=...``: stored in
   ``docs/results/policies.json`` under ``lab_prism_winch``; ``policies.md`` regenerated.

    python benchmarks/bench_policies_robot.py -o runs/policies_robot --workers 2
    python benchmarks/bench_policies_robot.py --robot tensegrity_env/assets/icosahedron_winches.xml \
        --key icosahedron_winch --timesteps 300000 \
        --hyperparams docs/results/ppo_robot_gamma099.yml -o runs/policies_icosahedron

Every command is printed before it runs. Steps whose outputs exist in the output folder
are reused (training runs are resumed to their budget), so an interrupted run continues.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import sys
from pathlib import Path

from identification.data.dataset import read_ground_truth
from tensegrity_env.io_utils import atomic_write_text
from tensegrity_env.model import Model
from tensegrity_sr.cli import main as cli

ROBOT = Path(__file__).resolve().parent.parent / "tensegrity_env" / "assets" / "lab_prism.xml"
#: the key of the results in policies.json
KEY = "lab_prism_winch"


def shown(path: Path) -> Path:
    """``path`` relative to the working folder where it lies below it (for the record)."""
    try:
        return path.resolve().relative_to(Path.cwd())
    except ValueError:
        return path


def run(argv: list[object], commands: list[str]) -> None:
    """Run ``tensegrity-sr ARGV``, printing and recording the command; exit on failure."""
    args = [str(a) for a in argv]
    line = shlex.join(["tensegrity-sr", *args])
    print(f"\n$ {line}", flush=True)
    commands.append(line)
    saved, sys.argv = sys.argv, ["tensegrity-sr", *args]  # the command a run record keeps
    try:
        code = cli(args)
    finally:
        sys.argv = saved
    if code:
        raise SystemExit(code)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("-o", "--output", type=Path, default=Path("runs/policies_robot"))
    p.add_argument("--robot", type=Path, default=ROBOT, help="the robot's MJCF (with a floor)")
    p.add_argument("--key", default=KEY, help="its key in policies.json (default %(default)s)")
    p.add_argument("--seeds", default="0-2", help="training seeds (default %(default)s)")
    p.add_argument("--hyperparams", type=Path, default=None,
                   help="PPO settings (default: the shipped policies/hyperparams/ppo.yml)")  # fmt: skip
    p.add_argument("--workers", type=int, default=1,
                   help="seeds trained at once, one process each (default %(default)s)")  # fmt: skip
    p.add_argument("--timesteps", type=int, default=None,
                   help="budget per seed (default: the hyperparameters')")  # fmt: skip
    p.add_argument("--episodes", type=int, default=100, help="evaluation episodes per env")
    p.add_argument("--n-train", type=int, default=8, help="training trajectories of the data")
    p.add_argument("--results", type=Path, default=Path("docs/results/policies"),
                   help="results stem (.json, .md) to add the robot to (default %(default)s)")  # fmt: skip
    args = p.parse_args(argv)
    out: Path = args.output
    robot: Path = args.robot
    out.mkdir(parents=True, exist_ok=True)
    commands: list[str] = []

    # 1. data: the robot hung in the air (no floor) under random winch commands
    text, floors = re.subn(r"<geom[^>]*type=\"plane\"[^>]*/>", "", robot.read_text())
    if floors != 1:
        raise SystemExit(f"{robot}: expected one floor plane, found {floors}")
    hung = atomic_write_text(out / f"{robot.stem}_hung.xml", text)
    data = out / "data.h5"
    if not data.exists():
        run(["generate", "--mjcf", hung, "--n-train", args.n_train, "--n-val", 0,
             "--n-test", 1, "--steps", 600, "--seed", 4, "--control-std", 1,
             "--no-progress", "-o", data], commands)  # fmt: skip
    # 2. identify; the env's model adds the robot file's floor contact
    truth = read_ground_truth(data)
    if truth is None:
        raise SystemExit(f"{data}: no ground truth to anchor the mass scale")
    identified = out / "params_hung.json"
    if not identified.exists():
        rod0 = Model.read(robot).topology.rods[0].name
        run(["identify", data, "--anchor", f"mass[{rod0}]={float(truth.params.mass[0])!r}",
             "--params", shown(robot), "--winch-lag", "auto", "-o", identified], commands)  # fmt: skip
    params = out / "params.json"
    Model.load(identified).replace(effects=Model.read(robot).effects).save(params)
    print(f"env model: {identified} with {robot.name}'s floor contact -> {params}")

    # 3. PPO on the identified model, one run per seed (resumed where one exists)
    runs = out / "runs"
    train = ["train", "ppo", "--env", "TensegritySR-v0", "--model", params,
             "--seeds", args.seeds, "-o", runs, "--resume", "--no-tensorboard"]  # fmt: skip
    if robot.resolve() != ROBOT:  # the default robot is the env's own default
        train += ["--robot", shown(robot)]
    if args.timesteps is not None:
        train += ["--timesteps", args.timesteps]
    if args.hyperparams is not None:
        train += ["--hyperparams", shown(args.hyperparams)]
    if args.workers != 1:
        train += ["--workers", args.workers]
    run(train, commands)

    # 4. every seed in the identified env and in the twin, same episodes
    from policies.seeds import parse_seeds, seed_folder

    folders = [seed_folder(runs, s) for s in parse_seeds(args.seeds)]
    transfer = out / "transfer"
    run(["transfer", *folders, "--episodes", args.episodes, "-o", transfer, "--force"],
        commands)  # fmt: skip

    # 5. into the committed results
    this = shlex.join(["python", "benchmarks/bench_policies_robot.py", *sys.argv[1:]])
    pipeline = {
        "summary": (
            f"`{robot.name}` ({len(Model.read(robot).topology.winches)} winches) identified "
            "from MuJoCo data under "
            "random winch commands (the robot hung in the air: the regression models no "
            "contact; the env's model adds the robot file's floor contact), PPO trained on "
            "`TensegritySR-v0` with that model, evaluated in `TensegrityMJ-v0` (the robot "
            f"file in MuJoCo). Reproduce: `{this}`; the steps it ran:"
        ),
        "commands": commands,
    }
    pipe_path = atomic_write_text(out / "pipeline.json", json.dumps(pipeline, indent=2) + "\n")
    from policies.results import main as results

    return results(["--robot", f"{args.key}={transfer / 'transfer.json'}", "--pipeline",
                    str(pipe_path), "-o", str(args.results)])  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
