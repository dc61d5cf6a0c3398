"""End caps -> rod states under every way a file can place a rod's end caps.

Which end is end cap 0, along which principal axis and in which direction the caps
run, and where the centre of mass sits between them are the file's choice. Each path
from end caps to rod states must give states whose end caps are the data's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from identification.data.end_caps import (
    RodAxes,
    measured_rod_states,
    rod_states_from_nodes,
    smooth_rod_states,
)
from tensegrity_env.rotations import np_quat_to_matrix, unit
from tensegrity_env.topology import Rod, Spring, Topology

DT = 0.01
#: end offsets in the principal frame [m]: the code's own (cap 0 at -L/2 on z), cap 0 at
#: +L/2, caps along -x, and a centre of mass 30 % of the way from cap 0 along -y
OFFSETS = {
    "cap 0 at -L/2": ((0.0, 0.0, -0.5), (0.0, 0.0, 0.5)),
    "cap 0 at +L/2": ((0.0, 0.0, 0.5), (0.0, 0.0, -0.5)),
    "along -x": ((0.4, 0.0, 0.0), (-0.4, 0.0, 0.0)),
    "off-centre along -y": ((0.0, 0.3, 0.0), (0.0, -0.7, 0.0)),
}


def two_rods(ends: tuple) -> Topology:
    """Two rods with end caps ``ends`` (rod 0) and the code's own convention (rod 1)."""
    rods = (
        Rod("a", float(np.linalg.norm(np.subtract(*ends))), end_offsets=ends),
        Rod("b", 1.0, end_offsets=((0.0, 0.0, -0.5), (0.0, 0.0, 0.5))),
    )
    return Topology(rods, (Spring("s0", 1, 2), Spring("s1", 0, 3)))


def rigid_motion(topo: Topology, n: int = 2, t1: int = 80) -> np.ndarray:
    """End caps (n, t1, 2R, 3) [m] of each rod tumbling and drifting on its own."""
    t = np.arange(t1) * DT
    rng = np.random.default_rng(3)
    R = topo.n_rods
    caps = np.empty((n, t1, 2 * R, 3))
    for i in range(n):
        for r in range(R):
            axis = unit(rng.normal(size=3))
            angle = 0.3 + 2.0 * t + 3.0 * t**2  # [rad]
            q = np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], -1)
            p = rng.normal(size=3) + np.outer(t, rng.normal(size=3)) - 4.9 * np.outer(t**2, [0, 0, 1])
            caps[i, :, 2 * r : 2 * r + 2] = p[:, None] + np.einsum(
                "tij,kj->tki", np_quat_to_matrix(q), topo.end_offsets[r]
            )
    return caps


def caps_of(topo: Topology, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """End caps (..., 2R, 3) of rod states ``p`` (..., R, 3) [m], ``q`` (..., R, 4)."""
    arms = np.einsum("...rij,rkj->...rki", np_quat_to_matrix(q), topo.end_offsets)
    return (p[..., None, :] + arms).reshape(*p.shape[:-2], -1, 3)


@pytest.mark.parametrize("name", list(OFFSETS))
def test_rod_axes_carry_the_signed_cap_direction(name: str) -> None:
    topo = two_rods(OFFSETS[name])
    axes = RodAxes.of(topo)
    e = topo.end_offsets
    np.testing.assert_allclose(axes.direction, unit(e[:, 1] - e[:, 0]), atol=1e-15)
    np.testing.assert_allclose(e[:, 0] + axes.frac[:, None] * (e[:, 1] - e[:, 0]), 0.0, atol=1e-15)


@pytest.mark.parametrize("name", list(OFFSETS))
def test_smoothed_states_put_the_end_caps_back_where_they_were_measured(name: str) -> None:
    topo = two_rods(OFFSETS[name])
    caps = rigid_motion(topo)
    s = smooth_rod_states(caps, DT, RodAxes.of(topo), 11)
    # a rotation is not a cubic in time: the filter's own error only (0.1 mm here)
    np.testing.assert_allclose(caps_of(topo, s.p, s.q), caps, atol=2e-4)
    np.testing.assert_allclose(s.x, caps, atol=2e-4)
    exact = rod_states_from_nodes(caps, topo, DT)
    np.testing.assert_allclose(s.p, exact["p"], atol=2e-4)
    np.testing.assert_allclose(caps_of(topo, exact["p"], exact["q"]), caps, atol=1e-12)
    # the savgol method of measured_rod_states is this path
    _, st = measured_rod_states(caps, topo, DT, "savgol", 11 * DT)
    np.testing.assert_allclose(st["p"], s.p, atol=1e-12)
    np.testing.assert_allclose(caps_of(topo, st["p"], st["q"]), caps, atol=2e-4)


def test_a_reversed_rod_is_not_turned_upside_down() -> None:
    """With cap 0 at +L/2, a shortest arc from the positive principal axis would swap
    the rod's two caps, one rod length apart."""
    topo = two_rods(OFFSETS["cap 0 at +L/2"])
    caps = rigid_motion(topo)
    s = smooth_rod_states(caps, DT, RodAxes.of(topo), 11)
    err = np.linalg.norm(caps_of(topo, s.p, s.q) - caps, axis=-1)  # (n, T+1, 4)
    assert err.max() < 2e-4
    upside_down = replace(RodAxes.of(topo), sign=np.ones(2))
    s_bad = smooth_rod_states(caps, DT, upside_down, 11)
    bad = np.linalg.norm(caps_of(topo, s_bad.p, s_bad.q) - caps, axis=-1)
    assert bad[..., :2].min() > 0.99  # the caps of rod 0 swap: 1 m apart
