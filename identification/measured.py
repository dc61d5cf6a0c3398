"""Rod states for datasets that hold end caps only (motion capture, noisy planted data).

A Savitzky-Golay filter (cubic, ``smoothing`` seconds wide) smooths the measured end
caps; rod states follow from the smoothed caps by
:func:`identification.states.rod_states_from_nodes`. The one-step transitions of
smoothed data stand in for the measured ones in the regression and the residuals;
with 1 mm noise they carry the smoothing's bias, so small effects stay hidden.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

from identification.dataset import Dataset, Split
from identification.states import rod_states_from_nodes


def smooth_nodes(nodes: np.ndarray, dt: float, smoothing: float) -> np.ndarray:
    """End caps (N, T+1, 2R, 3) smoothed along time by a cubic Savitzky-Golay filter."""
    T1 = nodes.shape[1]
    w = max(5, round(smoothing / dt) | 1)
    w = min(w, T1 if T1 % 2 else T1 - 1)
    if w <= 3:
        return nodes
    return savgol_filter(nodes, window_length=w, polyorder=3, axis=1)


def with_measured_states(dataset: Dataset, smoothing: float = 0.02) -> Dataset:
    """The dataset with rod states in every split (smoothed end caps where it had none)."""
    if all(s.has_states for s in dataset.splits.values()):
        return dataset
    splits = {}
    for name, s in dataset.splits.items():
        if s.has_states:
            splits[name] = s
            continue
        nodes = smooth_nodes(s.nodes, dataset.dt, smoothing)
        st = rod_states_from_nodes(nodes, dataset.topology, dataset.dt)
        splits[name] = Split(nodes=nodes, control=s.control, **st)
    attrs = {**dataset.attrs, "states": f"from end caps, Savitzky-Golay {smoothing:g} s"}
    return Dataset(dataset.topology, dataset.dt, splits, attrs=attrs, path=dataset.path)
