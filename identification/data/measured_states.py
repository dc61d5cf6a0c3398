"""Rod states for datasets that hold end caps only (motion capture, noisy planted data).

A Gaussian filter (std ``smoothing`` seconds) smooths the measured end caps; rod states follow from the smoothed caps by
:func:`identification.data.end_caps.rod_states_from_nodes`. The one-step transitions of
smoothed data stand in for the measured ones in the regression and the residuals;
with 1 mm noise they carry the smoothing's bias, so small effects stay hidden.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.signal import savgol_filter

from identification.data.dataset import Dataset, Split
from identification.data.end_caps import rod_states_from_nodes


def smooth_nodes(nodes: np.ndarray, dt: float, smoothing: float) -> np.ndarray:
    """End caps (N, T+1, 2R, 3) smoothed along time: Gaussian of std ``smoothing`` [s].

    A Gaussian kernel (not Savitzky-Golay, whose side lobes pass high-frequency noise
    that the transitions' double differences then amplify by 1/dt²); the ends are
    extended by a cubic fit (``mode="nearest"`` would bend them).
    """
    sigma = smoothing / dt
    if sigma < 0.5:
        return nodes
    pad = min(int(4 * sigma), nodes.shape[1] - 1)
    w = min(nodes.shape[1] if nodes.shape[1] % 2 else nodes.shape[1] - 1, 2 * pad + 1)
    ext = savgol_filter(nodes, window_length=max(w, 5), polyorder=3, axis=1, mode="interp")
    head = 2 * ext[:, :1] - nodes[:, pad:0:-1]  # point reflection about the smoothed ends
    tail = 2 * ext[:, -1:] - nodes[:, -2 : -pad - 2 : -1]
    padded = np.concatenate([head, nodes, tail], axis=1)
    return gaussian_filter1d(padded, sigma, axis=1, mode="nearest")[:, pad : pad + nodes.shape[1]]


def with_measured_states(dataset: Dataset, smoothing: float = 0.01) -> Dataset:
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
    attrs = {**dataset.attrs, "states": f"from end caps, Gaussian smoothing {smoothing:g} s"}
    return Dataset(dataset.topology, dataset.dt, splits, attrs=attrs, path=dataset.path)
