"""Rod states from measured end caps (motion capture), and datasets built from them.

Motion capture sees points, not rigid-body states. Two end caps per rod fix the
rod's centre of mass and the direction of its axis, and nothing else:

* **spin about the rod axis is unobservable** from two end caps. The orientation
  returned here is the shortest-arc rotation taking the rod-frame axis (end cap 0
  to end cap 1) onto the measured axis, i.e. it has *no twist about the axis*, and
  the angular velocity returned is the component perpendicular to the axis only,
  ``ω_⊥ = a × ȧ``. For a thin rod (tiny axial inertia, springs attached on the axis)
  the axial spin carries no spring force, so the lost component does not matter
  for the springs; the true ``q`` equals the returned one up to a rotation about
  the axis.
* velocities are **central differences** in time (second-order one-sided at the
  two ends), so they are smooth only as far as the positions are; with noisy
  positions, prefer fitting through a multi-step trajectory loss. For data from
  MuJoCo's semi-implicit Euler (``p_{t+1} = p_t + dt v_{t+1}``) the central
  difference of positions is ``(v_t + v_{t+1}) / 2``: half a step behind.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from identification.data.dataset import SPLITS, Dataset, Split, _check_dataset
from tensegrity_env.io_utils import InputError
from tensegrity_env.rotations import np_quat_to_matrix, shortest_arc, unit
from tensegrity_env.topology import Topology


def rod_states_from_nodes(
    nodes: np.ndarray, topology: Topology, dt: float
) -> dict[str, np.ndarray]:
    """Rod states from end-cap trajectories only (see the module docstring's caveats).

    Args:
        nodes: end-cap positions, (..., T+1, 2R, 3) [m], world frame; rod ``r`` owns
            nodes ``2r`` and ``2r + 1`` (the dataset's ``nodes``). Trailing world
            anchors, if included (``n_nodes`` points), are ignored.
        topology: the assembly; its end offsets say where the caps sit on each rod.
        dt: time between samples [s].

    Returns:
        ``p``, ``v``, ``omega`` (..., T+1, R, 3) and ``q`` (..., T+1, R, 4), as in
        the dataset schema: centre of mass [m] and its velocity [m/s]; principal-frame
        orientation (w, x, y, z) **with no twist about the rod axis** (shortest arc
        from the rod-frame axis); angular velocity [rad/s] **perpendicular to the
        axis only** (spin about the axis cannot be seen from two end caps).

    The centre of mass is placed from the end caps and the topology's end offsets:
    exact when it lies on the line through the end caps (every rod of the MJCF
    convention); an off-line centre of mass additionally depends on the unobservable
    twist and is placed using the no-twist orientation.
    """
    nodes = np.asarray(nodes, dtype=float)
    R = topology.n_rods
    if nodes.ndim < 3 or nodes.shape[-1] != 3 or nodes.shape[-2] not in (2 * R, topology.n_nodes):
        raise InputError(
            f"end caps have shape {nodes.shape}, expected (..., T+1, {2 * R}, 3) for {R} rods"
        )
    if nodes.shape[-3] < 2:
        raise InputError("end caps: need at least 2 samples in time")
    off_axis = topology.off_axis_points()
    if off_axis:
        raise InputError(
            f"end caps: springs attach at points off their rod's axis ({', '.join(off_axis[:3])}"
            f"{', ...' if len(off_axis) > 3 else ''}); placing them needs each rod's twist,"
            " which two tracked end caps do not give (record rod states)"
        )
    if not np.isfinite(dt) or dt <= 0:
        raise InputError(f"end caps: time step dt must be positive, got {dt}")
    x0, x1 = nodes[..., 0 : 2 * R : 2, :], nodes[..., 1 : 2 * R : 2, :]  # (..., T+1, R, 3)
    ends = topology.end_offsets  # (R, 2, 3), rod frame
    d_rod = ends[:, 1] - ends[:, 0]
    a_rod = unit(d_rod)
    d = x1 - x0
    a = unit(d)
    q = shortest_arc(a_rod, a)
    # COM = e0 + s (e1 - e0) + c_perp in the rod frame (origin = COM)
    s = -np.sum(ends[:, 0] * d_rod, axis=-1) / np.sum(d_rod * d_rod, axis=-1)  # (R,)
    c_perp = -(ends[:, 0] + s[:, None] * d_rod)  # (R, 3), zero for on-axis COM
    p = x0 + s[:, None] * d
    if np.any(np.abs(c_perp) > 1e-12):
        p = p + np.einsum(
            "...ij,...j->...i", np_quat_to_matrix(q), np.broadcast_to(c_perp, p.shape)
        )
    edge = 2 if nodes.shape[-3] >= 3 else 1
    v = np.gradient(p, dt, axis=-3, edge_order=edge)
    a_dot = np.gradient(a, dt, axis=-3, edge_order=edge)
    omega = np.cross(a, a_dot)  # ω_⊥ = a × ȧ for a unit vector turning as ȧ = ω × a
    return {"p": p, "v": v, "q": q, "omega": omega}


def dataset_from_end_caps(
    topology: Topology,
    dt: float,
    nodes: Mapping[str, np.ndarray],
    control: Mapping[str, np.ndarray] | None = None,
    attrs: Mapping[str, Any] | None = None,
) -> Dataset:
    """A dataset from end-cap trajectories only, e.g. motion capture.

    Args:
        topology: the assembly (rods with their end offsets, springs, anchors).
        dt: time between samples [s].
        nodes: split name (``train``, ``val``, ``test``) -> end caps (N, T+1, 2R, 3)
            [m] world frame, or a single trajectory (T+1, 2R, 3). Rod ``r`` owns
            nodes ``2r`` (its end cap 0) and ``2r + 1`` (end cap 1).
        control: split name -> commands f_u (N, T, R, 3) applied during each step,
            world frame; None (or a missing split) means no control.
        attrs: provenance stored in the file (e.g. ``{"source": "vicon, 200 Hz"}``).

    Returns:
        a :class:`~identification.data.dataset.Dataset` without rod states (they are
        derived by :func:`rod_states_from_nodes` when needed); write it with
        :func:`identification.data.dataset.write_dataset`. Raises :class:`InputError` on
        bad shapes or non-finite values.
    """
    if "train" not in nodes:
        raise InputError(f"end-cap data: needs a 'train' split (got {sorted(nodes)})")
    splits: dict[str, Split] = {}
    R = topology.n_rods
    for name, arr in nodes.items():
        if name not in SPLITS:
            raise InputError(f"end-cap data: unknown split '{name}' (use {', '.join(SPLITS)})")
        x = np.asarray(arr, dtype=float)
        if x.ndim == 3:
            x = x[None]
        if x.ndim != 4 or x.shape[2:] != (2 * R, 3):
            raise InputError(
                f"end-cap data: split '{name}' has shape {np.shape(arr)}, expected "
                f"(N, T+1, {2 * R}, 3) or (T+1, {2 * R}, 3)"
            )
        ctrl = None if control is None else control.get(name)
        if ctrl is None:
            ctrl = np.zeros((x.shape[0], max(x.shape[1] - 1, 0), R, 3))
        else:
            ctrl = np.asarray(ctrl, dtype=float)
            if ctrl.ndim == 3 and x.shape[0] == 1:
                ctrl = ctrl[None]
        splits[name] = Split(nodes=x, control=ctrl)
    ds = Dataset(
        topology=topology,
        dt=float(dt),
        splits=splits,
        attrs={"assembly": topology.name, "source": "end caps", **dict(attrs or {})},
    )
    _check_dataset(ds, "end-cap data")
    return ds
