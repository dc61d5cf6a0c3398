"""The real crawl of ``bench_real.py``: the Rutgers/Yale 3-bar under its six winches.

What a user would run, through the command line, on ``bekris_3bar/`` of ``--data``
(evaluation data, never copied into the repository):

1. ``benchmarks/bekris_crawl.py``: the lab's JSON to a plain CSV of end caps, a command
   log and a robot MJCF at physical scale with winch cables (written to the work folder);
2. ``import-mocap --commands`` with ``--split 0.7,0.3,0``: the first 70 % of the take is
   the training split, the last 30 % the held-out one, every sample at its own time;
3. ``identify`` from the robot file (the winding fitted at the samples' own times);
4. each model (``nominal``: the lab's configuration values as converted; ``identified``)
   rolled out open-loop from measured states (:func:`~identification.trajectory.timed.
   states_at_times`, smoothing :data:`SMOOTHING`) at starts every :data:`START_EVERY`
   of the held-out part, at the samples' own times with the recorded commands, the
   winches wound by the model from the take's start; its end caps compared with the
   measured ones at the sample nearest each of :data:`HORIZONS` (within half a median
   step): the RMS over starts and end caps.

The record has the layout of ``bench_real.py``'s takes (``heldout``, ``rest_shape_rms_m``,
``stretches``, ``parameters``, ``runs``) and its own ``command``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from identification.data.dataset import Dataset, read_dataset
from identification.trajectory.timed import local_linear, states_at_times, winch_at_times
from tensegrity_env.engine import State
from tensegrity_env.model import Model
from tensegrity_env.rotations import quat_to_matrix

KEY = "bekris_3bar_crawl"
#: the take's folder under the data folder
FOLDER = "bekris_3bar"
#: open-loop horizons [s] at which the end-cap error is read (the crawl moves ~1 cm/s)
HORIZONS = (0.5, 1.0, 2.0)
#: a rollout starts every this [s] of the held-out part
START_EVERY = 0.25
#: the measured starting state's smoothing [s]: a local line over the ~3 samples either
#: side of the 87 ms median step (end caps of ~1-2 mm noise)
SMOOTHING = 0.15
#: the physics step bound [s] of the rollouts (the robot file's timestep)
PHYSICS_DT = 1e-3
#: the step [s] a window shorter than the batch's longest continues by (never read)
PAD = 1e-3
COMMAND = "python benchmarks/bench_real.py --data ../shared/real --takes bekris_3bar_crawl"


def whole_take(data: Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The take again from its splits: end caps (F, 2R, 3) [m], times (F,) [s] from its
    start, winch commands (F - 1, W), and the time the held-out part starts [s] (the
    splits' pieces record where each starts in the take)."""
    pieces = json.loads(data.attrs["pieces"]) if isinstance(data.attrs["pieces"], str) else data.attrs["pieces"]
    parts = sorted((pieces[s][0][1], s) for s in pieces)
    nodes, times, cmds = [], [], []
    for start, s in parts:
        sp = data.split(s)
        nodes.append(sp.nodes[0])
        times.append(sp.time[0] + start)
        u = sp.winch_control[0]
        if cmds:  # the command in force over the step between two splits: the earlier's last
            cmds.append(cmds[-1][-1:])
        cmds.append(u)
    held = float(dict((s, a) for a, s in parts)["val"])
    return np.concatenate(nodes), np.concatenate(times), np.concatenate(cmds), held


def starts_of(states: dict[str, np.ndarray], times: np.ndarray, held: float) -> tuple[list[int], list[int]]:
    """Rollout starts (the first measured state from ``held`` [s] on in each slot of
    :data:`START_EVERY` whose longest horizon fits in the take) and the sample nearest
    that horizon after each."""
    ok = np.all([np.isfinite(states[k]).all((-1, -2)) for k in states], axis=0)
    median = float(np.median(np.diff(times)))
    starts, ends, slot = [], [], -1
    for k in np.flatnonzero(ok & (times >= held)):
        if times[k] + HORIZONS[-1] > times[-1] + median / 2 or int(times[k] // START_EVERY) == slot:
            continue
        slot = int(times[k] // START_EVERY)
        starts.append(int(k))
        ends.append(int(np.argmin(np.abs(times - times[k] - HORIZONS[-1]))))
    return starts, ends


def open_loop(model: Model, nodes: np.ndarray, times: np.ndarray, commands: np.ndarray,
              held: float) -> tuple[list[float], int]:  # fmt: skip
    """End-cap RMS error [m] at each of :data:`HORIZONS` of ``model`` rolled out from the
    measured states of the held-out part (from ``held`` [s]) and how many starts.

    The starts roll out in one batch, each at its own sample times (a window shorter than
    the longest is continued by steps of :data:`PAD` that are never read)."""
    topo = model.topology
    states = states_at_times(nodes, times, topo, SMOOTHING)
    u = torch.as_tensor(commands, dtype=torch.float64)
    with torch.no_grad():
        winch = winch_at_times(topo, model.params, torch.as_tensor(times), u, PHYSICS_DT)
    starts, ends = starts_of(states, times, held)
    if not starts:
        return [float("nan")] * len(HORIZONS), 0
    L = max(e - k for k, e in zip(starts, ends, strict=True))
    t = np.zeros((len(starts), L + 1))
    cmd = torch.zeros(len(starts), L, u.shape[-1], dtype=torch.float64)
    for b, (k, e) in enumerate(zip(starts, ends, strict=True)):
        t[b, : e - k + 1] = times[k : e + 1] - times[k]
        t[b, e - k + 1 :] = t[b, e - k] + PAD * np.arange(1, L - (e - k) + 1)
        cmd[b, : e - k] = u[k:e]
    idx = torch.as_tensor(starts)
    init = State(*(torch.as_tensor(states[x])[idx] for x in ("p", "v", "q", "omega"))).with_winch(winch[idx])
    engine = model.engine(physics_dt=PHYSICS_DT)
    with torch.no_grad():
        out = engine.rollout_at(init, model.params, torch.as_tensor(t), winches=cmd)
        arms = torch.einsum("btrij,rkj->btrki", quat_to_matrix(out.q), engine.end_offsets)
        pred = (out.p.unsqueeze(3) + arms).flatten(2, 3).numpy()
    return horizon_rms(lambda b, j: pred[b, j - starts[b]], nodes, times, starts), len(starts)


def horizon_rms(predicted, nodes: np.ndarray, times: np.ndarray, starts: list[int]) -> list[float]:
    """End-cap RMS error [m] at each of :data:`HORIZONS`: ``predicted(b, j)`` (2R, 3) [m]
    for start ``b`` at sample ``j``, compared at the sample nearest each horizon after
    each start (within half a median step)."""
    median = float(np.median(np.diff(times)))
    errors: list[list[np.ndarray]] = [[] for _ in HORIZONS]
    for b, k in enumerate(starts):
        for i, h in enumerate(HORIZONS):
            j = int(np.argmin(np.abs(times - times[k] - h)))
            if abs(times[j] - times[k] - h) <= median / 2:
                d = np.linalg.norm(predicted(b, j) - nodes[j], axis=-1)
                errors[i].append(d[np.isfinite(d)])
    out = []
    for e in errors:
        x = np.concatenate(e) if e else np.array([])
        out.append(float(np.sqrt(np.mean(x**2))) if x.size else float("nan"))
    return out


def held_still(model: Model, nodes: np.ndarray, times: np.ndarray, held: float) -> list[float]:
    """The baseline that predicts no motion: each start's smoothed end caps held, its
    RMS error [m] at each of :data:`HORIZONS` over the starts :func:`open_loop` takes."""
    states = states_at_times(nodes, times, model.topology, SMOOTHING)
    starts, _ = starts_of(states, times, held)
    pos, _ = local_linear(nodes, times, SMOOTHING)
    return horizon_rms(lambda b, j: pos[starts[b]], nodes, times, starts)


def run(data_dir: Path, work: Path, timeout: float, reuse: bool = False) -> dict[str, Any]:
    """Convert, import, identify and evaluate the crawl; its JSON record."""
    from bekris_crawl import convert
    from bench_real import parameter_summary, run_cli

    t0 = time.perf_counter()
    folder = work / KEY
    folder.mkdir(parents=True, exist_ok=True)
    h5, ident = folder / "take.h5", folder / "identified.json"
    files = convert(data_dir / FOLDER, folder)
    rec: dict[str, Any] = {"file": f"{FOLDER}/raw/5d_processed_data.json",
                           "robot": f"{FOLDER}/robot/configs/3_bar_tensegrity_upscaled_5d.json "
                                    "(converted to MJCF by benchmarks/bekris_crawl.py)",
                           "command": COMMAND, "runs": {}}  # fmt: skip
    if reuse and (folder / "runs.json").is_file():
        rec["runs"] = json.loads((folder / "runs.json").read_text())
    else:
        rec["runs"]["import"] = run_cli(["import-mocap", str(files.caps), "--robot", str(files.robot), "--units",
                                         "m", "--commands", str(files.commands), "--split", "0.7,0.3,0", "-o",
                                         str(h5), "--force"], folder / "import.log", timeout)  # fmt: skip
        if not rec["runs"]["import"]["returncode"]:
            rec["runs"]["identify"] = run_cli(["identify", str(h5), "--params", str(files.robot), "-o", str(ident),
                                               "--force"], folder / "identify.log", timeout)  # fmt: skip
        (folder / "runs.json").write_text(json.dumps(rec["runs"]))
    if not h5.is_file() or rec["runs"]["import"]["returncode"]:
        return rec
    data = read_dataset(h5)
    stretches = json.loads(data.attrs["stretches"]) if "stretches" in data.attrs else {}
    rec["stretches"] = stretches.get(files.caps.name, [])
    nodes, times, commands, held = whole_take(data)
    rec["heldout"] = {"horizon_s": list(HORIZONS), "from_s": round(held, 3),
                      "piece_s": round(float(times[-1] - held), 3)}  # fmt: skip
    rec["rest_shape_rms_m"], rec["parameters"] = {}, {}
    models = {"nominal": Model.read(files.robot)}
    if ident.is_file():
        models["identified"] = Model.read(ident)
    for name, model in models.items():
        rec["parameters"][name] = parameter_summary(model)
        rec["parameters"][name]["winch_speed"] = [float(model.params.winch_speed.mean())] * 3
        rec["heldout"][f"{name}_rms_m"], rec["heldout"]["starts"] = open_loop(model, nodes, times, commands, held)
    rec["heldout"]["held_still_rms_m"] = held_still(models["nominal"], nodes, times, held)
    rec["notes"] = notes(rec, ident)
    rec["seconds"] = round(time.perf_counter() - t0, 1)
    if reuse:
        rec["command"] += " --reuse (the evaluation again, on the commands' outputs of an earlier run)"
    return rec


def _cm(x: list[float]) -> str:
    return "/".join(f"{100 * v:.2f}" for v in x)


def notes(rec: dict[str, Any], ident: Path) -> list[str]:
    """What the record's numbers say, from the record and the identified model's file."""
    h = rec["heldout"]
    out = [f"Held out: the last {h['piece_s']:g} s of the take (from {h['from_s']:g} s: the import's split is by "
           f"frames, 70 % of them before). A prediction of no motion (each start's end caps held) misses by "
           f"{_cm(h['held_still_rms_m'])} cm at {'/'.join(f'{x:g}' for x in HORIZONS)} s."]  # fmt: skip
    if ident.is_file():
        doc = json.loads(ident.read_text())
        prov, unseen = doc.get("provenance", {}), doc.get("identifiability", {}).get("not_identifiable", {})
        p = doc["params"]
        lab = rec["parameters"]["nominal"]["winch_speed"][0]
        out.append(f"identify fits the winding to the wound cables' measured lengths: v_max {p['winch_speed'][0]:.4g} m/s "
                   f"(the lab's {lab:.4g}), lag {p['winch_lag'][0]:g} s, the rest lengths at the start; the lengths "
                   f"stay {1e3 * prov.get('cable_length_rms_m', float('nan')):.1f} mm RMS about the fitted winding "
                   f"({1e3 * prov.get('declared_cable_length_rms_m', float('nan')):.1f} mm about the lab's): "
                   "the commands integrated open-loop over the take do not follow the cables to better than "
                   "that, and a rest length fitted to a measured length keeps the cable's stretch in it.")  # fmt: skip
        out += [f"Not identified, kept as the lab's: {k} ({v})." for k, v in unseen.items()]
        out.append("Floor contact (friction, stiffness) is the lab's, not fitted.")
    return out
