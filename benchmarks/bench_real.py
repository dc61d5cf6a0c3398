"""Real robots: identify and diagnose on recorded takes, judged by held-out prediction.

For each take of ``--data`` (``../shared/real`` beside the checkout, evaluation data that
is never copied into the repository; skipped with a message when absent) this script
runs what a user would, through the command line:

1. ``import-mocap`` with the robot's NTRT model and nothing else given (the take's
   stretches are found; where a person acts on the robot, the splits are made of pieces
   of the free and resting stretches);
2. ``identify`` and ``diagnose`` starting from the NTRT model (its rod mass fixes the
   scale);
3. each model (``nominal``: the NTRT values as read; ``identified``; ``diagnosed``)
   rolled out open-loop from measured states (Gaussian smoothing, :data:`SMOOTHING`) at
   start times every :data:`START_EVERY` of the held-out pieces (the val and test
   splits), its end caps compared with the measured ones at :data:`HORIZONS`: the RMS
   over starts and seen end caps;
4. the rest shape each model predicts: from a measured resting state with zero
   velocity, :data:`SETTLE` of simulation, against the median of the measured end caps
   over that resting piece (RMS after a rigid alignment);
5. the cross-take check: each take's identified model predicting the other take's
   held-out pieces.

The 3-bar crawl (``bekris_3bar_crawl``, a robot driven by winches, its samples at uneven
times) runs its own steps (``benchmarks/real_crawl.py``) into the same layout. Running
some takes keeps the other takes' records already in ``--json``.

Results go to ``docs/results/real.json``; ``docs/results/real.md`` is generated from it
(:func:`markdown`).

    OMP_NUM_THREADS=1 python benchmarks/bench_real.py --data ../shared/real --quick
    python benchmarks/bench_real.py --report-only          # rewrite real.md from real.json
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from identification.data.dataset import Dataset, read_dataset  # noqa: E402
from identification.data.end_caps import measured_rod_states  # noqa: E402
from identification.data.sample_grid import on_nominal_grid  # noqa: E402
from identification.trajectory.windows import rollout_caps  # noqa: E402
from tensegrity_env.engine import State  # noqa: E402
from tensegrity_env.io_utils import atomic_write_text  # noqa: E402
from tensegrity_env.model import Model  # noqa: E402

#: open-loop horizons [s] at which the end-cap error is read
HORIZONS = (0.1, 0.25, 0.5, 1.0)
#: a rollout starts every this [s] of a held-out piece
START_EVERY = 0.25
#: the measured starting state's Gaussian smoothing [s] (markers of 0.03-0.1 mm noise need
#: little; a short filter leaves a state wherever every cap is seen around a sample)
SMOOTHING = 0.01
#: a model's rest shape is where it settles after this [s] from a measured resting state
SETTLE = 2.0
#: targets of a model worth using: identified at 0.25 s <= 1/3 of nominal and <= 1 cm; rest shape <= 3 mm
TARGET_RATIO, TARGET_RMS, TARGET_REST = 1 / 3, 0.01, 0.003
#: the takes: key -> (file under the data folder, robot under it, what the user adds to
#: ``import-mocap``). T5's cables are wound in by its winches until the jump and no
#: command log was published: the model cannot hold the compressed robot, so the fit
#: uses the stretch from the release on: the jump and landing to fit, the settling held out
TAKES: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "eth_T2_drop": ("eth_jumping_6bar/raw/T2_drop_newnodes_.csv", "eth_jumping_6bar/robot_ntrt/isodrop3Aext.yaml", ()),
    "eth_T5_jump": ("eth_jumping_6bar/raw/T5_3A_thirdcomp.csv", "eth_jumping_6bar/robot_ntrt/isodrop3Aext.yaml",
                    ("--segments", "8.3-14.2", "--piece", "1.9", "--split", "0.34,0.33,0.33")),
}  # fmt: skip
MODELS = ("nominal", "identified", "diagnosed")
#: the winch-driven crawl, run by benchmarks/real_crawl.py
CRAWL = "bekris_3bar_crawl"


def run_cli(args: list[str], log: Path, timeout: float) -> dict[str, Any]:
    """``tensegrity-sr ARGS``: exit code, wall time [s] and last line, the output in ``log``."""
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, "-m", "tensegrity_sr.cli", *args], capture_output=True,
                           text=True, check=False, timeout=timeout, cwd=ROOT)  # fmt: skip
        out, code = r.stdout + r.stderr, r.returncode
    except subprocess.TimeoutExpired as e:
        out, code = f"{e.stdout or ''}\ntimed out after {timeout:g} s", -1
    log.write_text(out)
    lines = [x for x in out.strip().splitlines() if x.strip()]
    return {"returncode": code, "seconds": round(time.perf_counter() - t0, 1), "last": lines[-1] if lines else ""}


def held_out(data: Dataset) -> np.ndarray:
    """End caps (N, T, 2R, 3) [m] of the held-out pieces: the val and test splits."""
    parts = [data.split(s).nodes for s in ("val", "test") if s in data.splits]
    if not parts:
        raise ValueError("no held-out split")
    T = min(p.shape[1] for p in parts)
    return np.concatenate([p[:, :T] for p in parts])


def open_loop(model: Model, nodes: np.ndarray, dt: float,
              horizons: tuple[float, ...]) -> tuple[list[float | None], list[str | None]]:  # fmt: skip
    """End-cap RMS error [m] of ``model`` at each of ``horizons`` [s], rolled out from the
    measured states of ``nodes`` (N, T, 2R, 3) [m] at starts every :data:`START_EVERY`,
    read at the horizon's sample or, where that is a gap, the sample next to it; and per
    horizon why there is no value (None where there is one). No value where no piece is
    long enough for the horizon, where no start has a measured state, and where a
    rollout's end caps are non-finite by then (diverged: never averaged over the others)."""
    _, st = measured_rod_states(nodes, model.topology, dt, "gaussian", SMOOTHING)
    steps = [round(h / dt) for h in horizons]
    every = max(1, round(START_EVERY / dt))
    known = np.isfinite(st["p"]).all((-1, -2)) & np.isfinite(st["omega"]).all((-1, -2))  # (N, T)
    starts = []  # the first measured state in each slot of START_EVERY
    for n in range(nodes.shape[0]):
        for a in range(0, nodes.shape[1] - steps[0], every):
            hit = np.flatnonzero(known[n, a : min(a + every, nodes.shape[1] - steps[0])])
            if hit.size:
                starts.append((n, a + int(hit[0])))
    if not starts:
        return [None] * len(horizons), ["no measured state to start from in the held-out pieces"] * len(horizons)
    idx = tuple(np.array(x) for x in zip(*starts, strict=True))
    init = State(*(torch.as_tensor(st[k][idx]) for k in ("p", "v", "q", "omega")))
    L = min(max(steps) + 1, nodes.shape[1] - 1)  # one step beyond the longest horizon (below)
    engine = model.engine()
    with torch.no_grad():
        pred = rollout_caps(engine, model.params, init,
                            torch.zeros(len(starts), L, model.topology.n_rods, 3, dtype=torch.float64)).numpy()  # fmt: skip
    out: list[float | None] = []
    why: list[str | None] = []
    for s in steps:
        errs, blown = [], 0
        for b, (n, t) in enumerate(starts):
            # at the horizon's sample, or the one next to it where that is a gap (a
            # capture system's repeated frame): a horizon read 1/120 s off
            for k in (s, s - 1, s + 1):
                if 0 < k <= L and t + k < nodes.shape[1] and np.isfinite(nodes[n, t + k]).all(-1).any():
                    blown += int(not np.isfinite(pred[b, : k + 1]).all())
                    d = np.linalg.norm(pred[b, k] - nodes[n, t + k], axis=-1)
                    errs.append(d[np.isfinite(nodes[n, t + k]).all(-1)])
                    break
        e = np.concatenate(errs) if errs else np.array([])
        if blown:
            out.append(None)
            why.append(f"diverged: non-finite end caps in {blown} of {len(errs)} rollouts by then")
        elif not e.size:
            out.append(None)
            why.append("no held-out piece is that long after a start")
        else:
            out.append(float(np.sqrt(np.mean(e**2))))
            why.append(None)
    return out, why


def missing(rec: dict[str, Any], key: str, reasons: list[str | None]) -> None:
    """Record in ``rec["missing"]`` why each entry of list ``key`` (``"heldout.x"``) is null."""
    for i, r in enumerate(reasons):
        if r is not None:
            rec.setdefault("missing", {})[f"{key}[{i}]"] = r


def finite_json(x: Any, path: str = "", found: dict[str, str] | None = None) -> Any:
    """``x`` with every non-finite float replaced by None (standard JSON), each noted in
    ``found`` (path -> reason) unless a reason is already recorded there."""
    found = {} if found is None else found
    if isinstance(x, dict):
        return {k: finite_json(v, f"{path}.{k}" if path else str(k), found) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [finite_json(v, f"{path}[{i}]", found) for i, v in enumerate(x)]
    if isinstance(x, float) and not np.isfinite(x):
        found.setdefault(path, f"not a finite number ({x})")
        return None
    return x


def standard(results: dict[str, Any]) -> dict[str, Any]:
    """``results`` as standard JSON: each take's (and each cross-take pair's) non-finite
    numbers null, with a reason in its ``missing`` (path -> reason) where its producer
    gave none."""
    out = {}
    for key, rec in results.items():
        if key == "cross_take":  # a record per pair of takes
            out[key] = standard(rec)
        elif isinstance(rec, dict) and key != "meta":
            found = dict(rec.get("missing", {}))
            body = finite_json({k: v for k, v in rec.items() if k != "missing"}, "", found)
            out[key] = {**body, **({"missing": found} if found else {})}
        else:
            out[key] = finite_json(rec)
    return out


def _kabsch_rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS [m] between point sets ``a`` and ``b`` (N, 3) after the rigid motion that best
    puts ``a`` on ``b``."""
    ca, cb = a - a.mean(0), b - b.mean(0)
    u, _, vt = np.linalg.svd(ca.T @ cb)
    d = np.sign(np.linalg.det(u @ vt))
    r = u @ np.diag([1.0, 1.0, d]) @ vt
    return float(np.sqrt(np.mean(np.sum((ca @ r - cb) ** 2, -1))))


def resting_piece(data: Dataset) -> np.ndarray | None:
    """End caps (T, 2R, 3) [m] of a piece that lies in a resting stretch (held-out first),
    None when the dataset records none."""
    stretches = data.attrs.get("stretches")
    placed = data.attrs.get("pieces")
    if not stretches or not placed:
        return None
    stretches, placed = json.loads(stretches), json.loads(placed)
    for split in ("test", "val", "train"):
        for k, (name, a, b) in enumerate(placed.get(split, [])):
            if any(s["kind"] == "rest" and s["start_s"] <= a and b <= s["end_s"] for s in stretches[name]):
                return data.split(split).nodes[k]
    return None


def rest_shape(model: Model, piece: np.ndarray, dt: float) -> tuple[float | None, str | None]:
    """RMS [m] between the end caps ``model`` settles to from the measured resting state
    at the start of ``piece`` (T, 2R, 3) [m] (velocities zero) and the piece's median
    end caps, after a rigid alignment; or None and why (the rollout diverged)."""
    _, st = measured_rod_states(piece[None], model.topology, dt, "gaussian", SMOOTHING)
    t = int(np.flatnonzero(np.isfinite(st["p"][0]).all((-1, -2)))[0])
    init = State(torch.as_tensor(st["p"][:, t]), torch.zeros_like(torch.as_tensor(st["v"][:, t])),
                 torch.as_tensor(st["q"][:, t]), torch.zeros_like(torch.as_tensor(st["omega"][:, t])))  # fmt: skip
    L = round(SETTLE / dt)
    with torch.no_grad():
        caps = rollout_caps(model.engine(), model.params, init,
                            torch.zeros(1, L, model.topology.n_rods, 3, dtype=torch.float64))[0].numpy()  # fmt: skip
    if not np.isfinite(caps).all():
        return None, f"diverged: non-finite end caps within the {SETTLE:g} s of settling"
    measured = np.nanmedian(piece, axis=0)
    seen = np.isfinite(measured).all(-1)
    return _kabsch_rms(caps[-1][seen], measured[seen]), None


def models(folder: Path, robot: Path, dt: float) -> dict[str, Model]:
    """The take's three models that exist: nominal (the robot file), identified, diagnosed."""
    out = {"nominal": Model.read(robot, dt=dt)}
    for name, path in (("identified", folder / "identified.json"), ("diagnosed", folder / "diagnose" / "params.json")):
        if path.is_file():
            out[name] = Model.read(path, dt=dt)
    return out


def parameter_summary(model: Model) -> dict[str, list[float]]:
    """Per parameter group (mass [kg], stiffness [N/m], damping [N s/m], rest length [m]):
    the model's smallest, median and largest value over its rods or springs."""
    p = model.params
    groups = {"mass": p.mass, "stiffness": p.stiffness, "damping": p.damping, "rest_length": p.rest_length}
    out = {}
    for k, v in groups.items():
        x = np.asarray(v.detach().cpu().numpy() if isinstance(v, torch.Tensor) else v, float).ravel()
        out[k] = [float(x.min()), float(np.median(x)), float(x.max())]
    return out


def run_take(key: str, data_dir: Path, work: Path, quick: bool, timeout: float, reuse: bool = False) -> dict[str, Any]:
    """Import, identify, diagnose and evaluate one take; its JSON record. ``reuse``: the
    commands' outputs in ``work`` from an earlier run are evaluated again, not rerun."""
    file, robot = (data_dir / p for p in TAKES[key][:2])
    folder = work / key
    folder.mkdir(parents=True, exist_ok=True)
    h5 = folder / "take.h5"
    rec: dict[str, Any] = {"file": TAKES[key][0], "robot": TAKES[key][1], "import_options": list(TAKES[key][2]),
                           "runs": {}}  # fmt: skip
    if reuse and (folder / "runs.json").is_file():
        rec["runs"] = json.loads((folder / "runs.json").read_text())
        return evaluate(rec, h5, folder, robot) if h5.is_file() else rec
    rec = run_commands(rec, file, robot, h5, folder, quick, timeout, TAKES[key][2])
    (folder / "runs.json").write_text(json.dumps(rec["runs"]))
    return evaluate(rec, h5, folder, robot) if h5.is_file() and not rec["runs"]["import"]["returncode"] else rec


def run_commands(rec: dict[str, Any], file: Path, robot: Path, h5: Path, folder: Path, quick: bool,
                 timeout: float, options: tuple[str, ...] = ()) -> dict[str, Any]:  # fmt: skip
    """``import-mocap`` (with ``options``), ``identify`` and ``diagnose`` on one take,
    recorded in ``rec``. ``quick``: diagnose adds one effect at most and scores on fewer
    windows; the fits on the floor keep their default windows (with 4, half of them
    start at the drop's impact, and identify's fit on T2 ended at 13.6 mm: diverged)."""
    rec["runs"]["import"] = run_cli(["import-mocap", str(file), "--robot", str(robot), "-o", str(h5), "--force",
                                     *options], folder / "import.log", timeout)  # fmt: skip
    if rec["runs"]["import"]["returncode"]:
        return rec
    rec["runs"]["identify"] = run_cli(["identify", str(h5), "--params", str(robot), "-o",
                                       str(folder / "identified.json"), "--force"],
                                      folder / "identify.log", timeout)  # fmt: skip
    diag = ["--max-effects", "1", "--windows", "4", "--fit-windows", "8"] if quick else []
    rec["runs"]["diagnose"] = run_cli(["diagnose", str(h5), "--params", str(robot), "-o", str(folder / "diagnose"),
                                       *diag], folder / "diagnose.log", timeout)  # fmt: skip
    return rec


def evaluate(rec: dict[str, Any], h5: Path, folder: Path, robot: Path) -> dict[str, Any]:
    """``rec`` with the take's stretches, pieces, held-out errors, rest shapes and
    parameters of the models the commands wrote."""
    data, _ = on_nominal_grid(read_dataset(h5))
    rec["stretches"] = json.loads(data.attrs["stretches"]) if "stretches" in data.attrs else {}
    rec["stretches"] = rec["stretches"].get(Path(rec["file"]).name, [])
    rec["pieces"] = json.loads(data.attrs["pieces"]) if "pieces" in data.attrs else {}
    nodes = held_out(data)
    rec["heldout"] = {"horizon_s": list(HORIZONS), "pieces": int(nodes.shape[0]),
                      "piece_s": round(nodes.shape[1] * data.dt, 3)}  # fmt: skip
    piece = resting_piece(data)
    rec["rest_shape_rms_m"], rec["parameters"] = {}, {}
    rec.pop("missing", None)
    for name, model in models(folder, robot, data.dt).items():
        rec["parameters"][name] = parameter_summary(model)
        rec["heldout"][f"{name}_rms_m"], why = open_loop(model, nodes, data.dt, HORIZONS)
        missing(rec, f"heldout.{name}_rms_m", why)
        if piece is not None:
            rec["rest_shape_rms_m"][name], reason = rest_shape(model, piece, data.dt)
            if reason is not None:
                rec.setdefault("missing", {})[f"rest_shape_rms_m.{name}"] = reason
    return rec


def cross_take(results: dict[str, Any], data_dir: Path, work: Path) -> dict[str, Any]:
    """Each take's identified model predicting every other take's held-out pieces."""
    out: dict[str, Any] = {}
    for fit_on in results:
        path = work / fit_on / "identified.json"
        for other in results:
            h5 = work / other / "take.h5"
            if other == fit_on or not path.is_file() or not h5.is_file():
                continue
            data, _ = on_nominal_grid(read_dataset(h5))
            model = Model.read(path, dt=data.dt)
            nominal = Model.read(data_dir / TAKES[other][1], dt=data.dt)
            nodes = held_out(data)
            rec: dict[str, Any] = {"horizon_s": list(HORIZONS)}
            for name, m in (("identified", model), ("nominal", nominal)):
                rec[f"{name}_rms_m"], why = open_loop(m, nodes, data.dt, HORIZONS)
                missing(rec, f"{name}_rms_m", why)
            out[f"{fit_on}->{other}"] = rec
    return out


def _cm(x: float | None) -> str:
    return "-" if not _finite(x) else f"{100 * x:.2f}"  # type: ignore[operator]


def _finite(x: float | None) -> bool:
    return x is not None and bool(np.isfinite(x))


def missing_lines(missing: dict[str, str], horizons: list[float]) -> list[str]:
    """``- no value: <what>: <reason>`` for a record's ``missing`` (path -> reason), the
    entries of one model and reason on one line."""
    grouped: dict[tuple[str, str], list[str]] = {}
    for path, reason in missing.items():
        m = re.fullmatch(r"(?:heldout\.)?(\w+)_rms_m\[(\d+)\]", path)
        r = re.fullmatch(r"rest_shape_rms_m\.(\w+)", path)
        if m and int(m[2]) < len(horizons):
            grouped.setdefault((m[1], reason), []).append(f"{horizons[int(m[2])]:g} s")
        elif r:
            grouped.setdefault((f"{r[1]} rest shape", reason), [])
        else:
            grouped.setdefault((path, reason), [])
    return [f"- no value: {what}" + (f" at {', '.join(at)}" if at else "") + f": {reason}"
            for (what, reason), at in grouped.items()]  # fmt: skip


def markdown(results: dict[str, Any]) -> str:
    """``real.md`` from ``real.json``'s ``results``: per take the held-out open-loop
    errors, the rest shapes, the stretches, what each command did; the cross-take check;
    each target, met or missed, with the reasons recorded."""
    meta = results.get("meta", {})
    lines = ["# Real robots: held-out prediction", "",
             f"Generated from `real.json` by `benchmarks/bench_real.py` (`{meta.get('command', '')}`, "
             f"{meta.get('seconds', 0):.0f} s). Open-loop end-cap RMS error [cm] from measured "
             "states, on the held-out pieces (val and test splits), at each horizon.", ""]  # fmt: skip
    for key, rec in results.items():
        if key in ("meta", "cross_take"):
            continue
        lines += [f"## {key}", "", f"`{rec['file']}` with `{rec['robot']}`.", ""]
        if "command" in rec:
            lines += [f"`{rec['command']}` ({rec.get('seconds', 0):.0f} s)", ""]
        runs = rec.get("runs", {})
        lines += [f"- `{c}`: exit {r['returncode']} in {r['seconds']:.0f} s" + (f" ({r['last']})" if r["returncode"] else "")
                  for c, r in runs.items()]  # fmt: skip
        if rec.get("stretches"):
            lines += ["- stretches: " + ", ".join(f"{s['kind']} {s['start_s']:.2f}-{s['end_s']:.2f} s"
                                                  for s in rec["stretches"])]  # fmt: skip
        h = rec.get("heldout")
        if h:
            held = (f"{h['pieces']} pieces of {h['piece_s']:g} s" if "pieces" in h else
                    f"the last {h['piece_s']:g} s from {h['from_s']:g} s, {h.get('starts', 0)} starts")  # fmt: skip
            lines += [f"- held out: {held}", "",
                      "| model | " + " | ".join(f"{t:g} s" for t in h["horizon_s"]) + " |",
                      "| --- |" + " --- |" * len(h["horizon_s"])]  # fmt: skip
            for m in MODELS:
                if f"{m}_rms_m" in h:
                    lines.append(f"| {m} | " + " | ".join(_cm(x) for x in h[f"{m}_rms_m"]) + " |")
        lines += missing_lines(rec.get("missing", {}), h["horizon_s"] if h else list(HORIZONS))
        rest = rec.get("rest_shape_rms_m", {})
        if rest:
            lines += ["", "Rest shape, RMS after rigid alignment [mm]: "
                      + ", ".join(f"{m} {'-' if v is None else f'{1e3 * v:.2f}'}" for m, v in rest.items())]  # fmt: skip
        params = rec.get("parameters", {})
        if params:
            lines += ["", "| parameter (min / median / max) | " + " | ".join(params) + " |",
                      "| --- |" + " --- |" * len(params)]  # fmt: skip
            for g in ("mass", "stiffness", "damping", "rest_length"):
                lines.append(f"| {g} | " + " | ".join(" / ".join(f"{x:.4g}" for x in v[g]) for v in params.values()) + " |")
        lines += ["", *targets(rec), *[f"- {n}" for n in rec.get("notes", [])], ""]
    cross = results.get("cross_take", {})
    if "cross_take" in results and not cross:
        lines += ["## Cross-take", "", "Not evaluated: no take has an identified model.", ""]
    if cross:
        lines += ["## Cross-take", "", "| fitted on -> predicted | model | " + " | ".join(f"{t:g} s" for t in HORIZONS) + " |",
                  "| --- | --- |" + " --- |" * len(HORIZONS)]  # fmt: skip
        for k, r in cross.items():
            for m in ("nominal", "identified"):
                lines.append(f"| {k} | {m} | " + " | ".join(_cm(x) for x in r[f"{m}_rms_m"]) + " |")
        for k, r in cross.items():
            lines += [x.replace("- no value: ", f"- no value ({k}): ", 1)
                      for x in missing_lines(r.get("missing", {}), list(HORIZONS))]  # fmt: skip
        lines.append("")
    notes = meta.get("notes", [])
    if notes:
        lines += ["## Notes", "", *[f"- {n}" for n in notes], ""]
    return "\n".join(lines)


def targets(rec: dict[str, Any]) -> list[str]:
    """Lines saying which targets a take's record meets, and by how much it misses the others."""
    h = rec.get("heldout", {})
    if 0.25 not in h.get("horizon_s", HORIZONS):
        return []
    k = HORIZONS.index(0.25)
    out = []
    ident, nom = h.get("identified_rms_m"), h.get("nominal_rms_m")
    if ident is None or nom is None:
        return ["Targets: not evaluated (no identified model)."]
    i, n = ident[k], nom[k]
    ok = _finite(i) and _finite(n) and i <= TARGET_RATIO * n
    out.append(f"- target identified <= 1/3 of nominal at 0.25 s: {'met' if ok else 'missed'} "
               f"({_cm(i)} cm against {_cm(n)} cm)")  # fmt: skip
    ok = _finite(i) and i <= TARGET_RMS
    out.append(f"- target identified <= 1 cm at 0.25 s: {'met' if ok else 'missed'} ({_cm(i)} cm)")
    rest = rec.get("rest_shape_rms_m", {}).get("identified")
    if rest is not None:
        out.append(f"- target rest shape <= 3 mm: {'met' if rest <= TARGET_REST else 'missed'} ({1e3 * rest:.2f} mm)")
    return out


def write_results(path: Path, md: Path, results: dict[str, Any]) -> None:
    """``results`` as standard JSON at ``path`` (:func:`standard`) and ``md`` generated from it."""
    results = standard(results)
    atomic_write_text(path, json.dumps(results, indent=1, allow_nan=False) + "\n")
    atomic_write_text(md, markdown(results))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "real", help="the real recordings' folder")
    every = ",".join([*TAKES, CRAWL])
    ap.add_argument("--takes", default=every, help=f"comma-separated takes (default {every})")
    ap.add_argument("--quick", action="store_true", help="fewer fit windows and one effect at most in diagnose")
    ap.add_argument("--workdir", type=Path, help="keep the imported takes and fitted models here")
    ap.add_argument("--timeout", type=float, default=1800.0, help="per command [s]")
    ap.add_argument("--json", type=Path, default=ROOT / "docs" / "results" / "real.json")
    ap.add_argument("--note", action="append", default=[], help="a note for real.md (repeatable)")
    ap.add_argument("--report-only", action="store_true", help="rewrite real.md from real.json")
    ap.add_argument("--reuse", action="store_true",
                    help="evaluate again what an earlier run left in --workdir, without rerunning the commands")  # fmt: skip
    args = ap.parse_args(argv)
    md = args.json.with_suffix(".md")
    if args.report_only:
        atomic_write_text(md, markdown(json.loads(args.json.read_text())))
        print(f"wrote {md}")
        return 0
    if not args.data.is_dir():
        print(f"skipped: no real recordings at {args.data} (evaluation data kept beside the checkout)")
        return 0
    t0 = time.perf_counter()
    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_real_"))
    results: dict[str, Any] = json.loads(args.json.read_text()) if args.json.is_file() else {}
    keys = args.takes.split(",")
    for key in keys:
        print(f"{key}: import, identify, diagnose, evaluate in {work / key}", flush=True)
        if key == CRAWL:
            from real_crawl import run as run_crawl

            results[key] = run_crawl(args.data, work, args.timeout, args.reuse)
        else:
            results[key] = run_take(key, args.data, work, args.quick, args.timeout, args.reuse)
        print(json.dumps(results[key].get("heldout", {})), flush=True)
    ran = [k for k in keys if k in TAKES]
    if len(ran) > 1:
        results["cross_take"] = cross_take({k: results[k] for k in ran}, args.data, work)
    if not ran:  # only the crawl: its record carries its command; the others' meta stays
        write_results(args.json, md, results)
        print(f"wrote {args.json} and {md}")
        return 0
    command = ("python benchmarks/bench_real.py --data ../shared/real" + (" --quick" if args.quick else "")
               + (" (its commands' outputs evaluated again with --reuse)" if args.reuse else ""))  # fmt: skip
    results["meta"] = {"command": command, "seconds": round(time.perf_counter() - t0, 1), "notes": args.note}
    write_results(args.json, md, results)
    print(f"wrote {args.json} and {md}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
