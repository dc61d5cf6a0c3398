"""The floor fit's window states at the true model of a drawn plant: fitted from the
true states, and from the fit's seeds (smoothing, the window's first samples) with and
without the third, smoothing with each rod's axial spin searched
(:func:`~identification.trajectory.window_states.search_spins`).

Writes the plant's data (``benchmarks/plant_family.py``, the family benchmark's share)
into ``--workdir`` unless there, cuts the floor fit's training windows and prints the
end-cap RMS over the noise of each way (the true states give about 1).

    OMP_NUM_THREADS=1 python benchmarks/bench_spin_search.py --seed 10 --steps 25 --count 21
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from plant_family import draw, write_family_cell

from identification.commands.declared import declared_start as file_start
from identification.data.dataset import read_dataset
from identification.trajectory import floor_fit
from identification.trajectory.end_cap_data import (
    EndCapData,
    TrajectorySettings,
    declared_start,
    held_drag_axis,
)
from identification.trajectory.floor_declared import floor_rows
from identification.trajectory.floor_fit import STATE_ITERS, floor_contact, with_floor
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.window_errors import window_errors
from identification.trajectory.windows import Windows
from tensegrity_env.engine import Engine, State


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=10, help="the floor plant's seed")
    ap.add_argument("--steps", type=int, default=25, help="steps per window")
    ap.add_argument("--count", type=int, default=21, help="training windows")
    ap.add_argument("--share", type=float, default=0.25, help="the family benchmark's share")
    ap.add_argument("--workdir", type=Path, default=Path("spin_search_data"))
    a = ap.parse_args()
    folder = a.workdir / f"family{a.seed}_floor"
    if not (folder / "measured.h5").exists():
        write_family_cell(draw(a.seed, "floor"), folder, a.share)
    ds, clean = read_dataset(folder / "measured.h5"), read_dataset(folder / "clean.h5")
    anchors: dict[str, float] = {}
    start, contact, others = file_start(folder / "true.xml", ds, folder / "true.xml", anchors)
    data = EndCapData(ds, TrajectorySettings(anchors=anchors))
    data.on_floor = True
    vec = declared_start(data, anchors, start, None, rod_keep=floor_rows(data))
    vec = with_floor(vec, others, floor_contact(ds.topology, data.train.nodes, contact),
                     held_drag_axis(data))  # fmt: skip
    theta = vec.theta0()
    noise = float(ds.attrs["measurement_noise_std"])
    win = data.cut("train", a.steps, a.count, 3, lift_off=a.count // 2)
    split = clean.split("train")
    true = replace(win, state=State(*(
        torch.as_tensor(np.stack([getattr(split, k)[t, s] for t, s in zip(win.traj, win.start, strict=True)]))
        for k in ("p", "v", "q", "omega"))))  # fmt: skip
    engine, held = vec.engine(data.engine, theta), vec.held_at(theta)
    n = win.window_residuals()

    def ratio(w: Windows) -> float:
        sse = window_errors(engine, held, w, torch.zeros(0, dtype=torch.float64)).numpy()
        return float(np.sqrt(sse.sum() / n.sum()) / noise)

    print(f"{ds.attrs.get('source', folder)}: {win.size} windows of {a.steps} steps, "
          f"noise {noise * 1e3:.3g} mm; end-cap RMS / noise")  # fmt: skip
    print(f"  true states: {ratio(true):.3f}")
    searched = floor_fit.search_spins

    def unsearched(engine: Engine, vec: ParamVector, windows: Windows, steps: int = 0) -> Windows:
        return windows

    for name, search in (("with the spin-searched seed", searched), ("without it", unsearched)):
        floor_fit.search_spins = search
        t0 = time.perf_counter()
        fit = floor_fit.states_at(data.engine, vec, theta, win, STATE_ITERS)
        print(f"  fitted from the seeds, {name}: {ratio(fit.windows):.3f} "
              f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    floor_fit.search_spins = searched
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
