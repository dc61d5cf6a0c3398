"""Measured sample times onto the nominal grid the engine steps on.

A motion-capture file gives each frame its time; the engine steps at the dataset's
nominal ``dt``. :func:`on_nominal_grid` puts every sample at the grid time ``k dt``
nearest to its measured time, so model and data are compared at the measured times
to within ``max_offset`` of a step:

* a frame the system dropped leaves its grid time without a sample: a gap (NaN end
  caps), never an interpolated one;
* a trajectory whose samples would fill less than 1/:data:`MAX_STEPS_PER_SAMPLE` of
  its grid (a timestamp glitch, a pause of minutes) is refused, naming the pause;
* a sample further than ``max_offset * dt`` from every grid time, or a second sample
  at one grid time, is left out (the error of comparing it at the grid time, its
  offset times the marker's speed, is then bounded by ``max_offset * dt`` times the
  speed: 0.1 of a step at 120 Hz and 1 m/s is 0.8 mm);
* control commands are held over the steps between two samples (zero-order hold,
  what a command applied from one sample to the next is).

Datasets without stored times, or with times already on the grid, are returned as
they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identification.data.dataset import Dataset, Split
from tensegrity_env.io_utils import InputError

#: largest distance of a kept sample from its grid time, as a fraction of dt
MAX_OFFSET = 0.1
#: a trajectory's grid may hold at most this many steps per sample: beyond, most of it
#: would be gaps (a timestamp glitch, a take paused for minutes) and is refused before
#: it is allocated
MAX_STEPS_PER_SAMPLE = 10


@dataclass(frozen=True)
class GridReport:
    """What :func:`on_nominal_grid` did, summed over the splits.

    Attributes:
        kept: samples placed at a grid time.
        left_out: samples left out (too far from any grid time, or a second one there).
        empty: grid times inside a trajectory without a sample (dropped frames).
        max_offset: largest ``|t - k dt|`` of a kept sample [s].
    """

    kept: int = 0
    left_out: int = 0
    empty: int = 0
    max_offset: float = 0.0

    @property
    def changed(self) -> bool:
        return self.left_out > 0 or self.empty > 0 or self.max_offset > 0

    def text(self, dt: float) -> str:
        """One line for a command's output."""
        return (
            f"sample times onto the {1 / dt:g} Hz grid: {self.kept} samples kept (largest "
            f"offset {self.max_offset * 1e6:.3g} µs), {self.empty} dropped frames left as gaps, "
            f"{self.left_out} samples left out"
        )


def grid_index(time: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Nearest grid step ``k`` of each time (T,) [s] and the offset ``t - k dt`` [s]."""
    k = np.rint(time / dt).astype(int)
    return k, time - k * dt


def on_nominal_grid(ds: Dataset, max_offset: float = MAX_OFFSET) -> tuple[Dataset, GridReport]:
    """``ds`` with every split sampled at ``k dt`` (see the module docstring)."""
    if not 0 < max_offset < 0.5:
        raise InputError(f"max_offset must be in (0, 0.5) of a step, got {max_offset}")
    splits: dict[str, Split] = {}
    total = GridReport()
    for name, s in ds.splits.items():
        splits[name], rep = split_on_grid(
            s, ds.dt, max_offset, f"{ds.path or 'dataset'}: split '{name}'"
        )
        total = GridReport(total.kept + rep.kept, total.left_out + rep.left_out,
                           total.empty + rep.empty, max(total.max_offset, rep.max_offset))  # fmt: skip
    if not total.changed:
        return ds, total
    return Dataset(ds.topology, ds.dt, splits, attrs=dict(ds.attrs), path=ds.path), total


def check_span(time: np.ndarray, k: np.ndarray, finite: np.ndarray, dt: float, where: str) -> None:
    """Refuse a trajectory whose grid steps ``k`` (T,) would outnumber its samples more
    than :data:`MAX_STEPS_PER_SAMPLE` times; the error names the longest pause."""
    idx = np.flatnonzero(finite)
    if idx.size < 2:
        return
    span = int(k[idx].max() - k[idx].min()) + 1
    if span <= MAX_STEPS_PER_SAMPLE * idx.size:
        return
    pauses = np.diff(time[idx])
    i = int(np.argmax(pauses))
    raise InputError(
        f"{where}: {idx.size} samples span {span} steps of {dt:g} s; the longest pause is "
        f"{pauses[i]:.4g} s (between samples {idx[i]} and {idx[i + 1]}): check the sample "
        "times, or cut the take at the pause"
    )


def split_on_grid(s: Split, dt: float, max_offset: float, where: str) -> tuple[Split, GridReport]:
    """One split on the grid; ``where`` names it in errors."""
    if s.time is None:
        return s, GridReport(kept=int(np.prod(s.nodes.shape[:2])))
    finite = np.isfinite(s.time)
    k, off = grid_index(np.where(finite, s.time, 0.0), dt)
    if (k[finite] == np.broadcast_to(np.arange(s.time.shape[1]), s.time.shape)[finite]).all() and (
        np.abs(off[finite]).max() < 1e-9 * dt
    ):
        return s, GridReport(kept=int(finite.sum()))
    if s.has_states:
        raise InputError(
            f"{where}: rod states at sample times off the {1 / dt:g} Hz grid; store end caps only"
        )
    N = s.n_trajectories
    for n in range(N):
        check_span(s.time[n], k[n], finite[n], dt, f"{where}, trajectory {n}")
    T1 = int(k[finite].max()) + 1
    nodes = np.full((N, T1, *s.nodes.shape[2:]), np.nan)
    control = np.zeros((N, T1 - 1, *s.control.shape[2:]))
    time = np.full((N, T1), np.nan)
    kept = left = empty = 0
    worst = 0.0
    for n in range(N):
        idx = np.flatnonzero(finite[n])
        kn, on = k[n, idx], np.abs(off[n, idx])
        ok = on <= max_offset * dt
        order = np.lexsort((on, kn))  # per grid time, the nearest sample first
        first = np.ones(len(order), bool)
        first[1:] = kn[order][1:] != kn[order][:-1]
        use = np.zeros(len(idx), bool)
        use[order[first]] = True
        use &= ok
        left += int((~use).sum())
        kept += int(use.sum())
        worst = max(worst, float(on[use].max(initial=0.0)))
        nodes[n, kn[use]] = s.nodes[n, idx[use]]
        last = int(kn.max())
        time[n, : last + 1] = np.arange(last + 1) * dt
        empty += last + 1 - int(use.sum()) - int(kn.min())
        # zero-order hold: the command of sample i acts until the next sample's grid step
        for i in range(len(idx) - 1):
            control[n, kn[i] : kn[i + 1]] = s.control[n, idx[i]]
    uniform = bool(np.isfinite(time).all())
    out = Split(nodes=nodes, control=control, time=None if uniform else time)
    return out, GridReport(kept, left, empty, worst)
