"""The topology graph: the paper's assemblies, validation, and MJCF in and out."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from tensegrity_env.assemblies import GRAVITY, element, icosahedron, node_positions
from tensegrity_env.mjcf import SimOptions, from_mjcf, to_mjcf
from tensegrity_env.mujoco_state import mj_to_rod_state
from tensegrity_env.params import FIELDS
from tensegrity_env.topology import Rod, Spring, Topology, TopologyError

EXAMPLE_MJCF = Path(__file__).resolve().parents[2] / "docs" / "examples" / "x_tensegrity.xml"


def _lengths(topology: Topology, nodes: np.ndarray) -> np.ndarray:
    sn = topology.spring_nodes
    return np.linalg.norm(nodes[sn[:, 1]] - nodes[sn[:, 0]], axis=-1)


def test_icosahedron_has_six_rods_and_24_springs_all_at_rest_length() -> None:
    a = icosahedron()
    topo = a.topology
    assert (topo.n_rods, topo.n_springs, topo.n_anchors) == (6, 24, 0)
    # every rod end (12 nodes) carries exactly 4 springs
    counts = np.bincount(topo.spring_nodes.ravel(), minlength=topo.n_nodes)
    assert counts.tolist() == [4] * 12
    for r in range(6):
        assert len(topo.springs_of_rod(r)) == 8
    lengths = _lengths(topo, a.node_positions())
    np.testing.assert_allclose(lengths, 0.637, rtol=0, atol=1e-12)
    # rods are 1.04 m between end caps
    ends = a.node_positions().reshape(6, 2, 3)
    np.testing.assert_allclose(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=-1), 1.04, atol=1e-12)


def test_element_hangs_in_static_equilibrium_from_two_anchors() -> None:
    a = element()
    topo = a.topology
    assert (topo.n_rods, topo.n_springs, topo.n_anchors) == (1, 2, 2)
    # each end cap hangs from the anchor straight above it
    assert topo.spring_nodes.tolist() == [[0, 2], [1, 3]]
    nodes = a.node_positions()
    np.testing.assert_allclose(nodes[2] - nodes[0], [0, 0, 0.5], atol=1e-12)
    np.testing.assert_allclose(nodes[3] - nodes[1], [0, 0, 0.5], atol=1e-12)
    # spring forces carry the weight: sum K (l - l0) = m g
    P = a.params.numpy()
    tension = P["stiffness"] * (_lengths(topo, nodes) - P["rest_length"])
    np.testing.assert_allclose(tension.sum(), P["mass"][0] * -GRAVITY[2], rtol=1e-12)
    np.testing.assert_allclose(tension[0], tension[1], rtol=1e-12)


def _rods(n: int) -> tuple[Rod, ...]:
    return tuple(Rod(f"r{i}", 1.0) for i in range(n))


@pytest.mark.parametrize(
    ("springs", "anchors", "message"),
    [
        ((Spring("s", 0, 7),), (), "does not exist"),
        ((Spring("s", 0, 1),), (), "same rod"),
        ((Spring("s", 2, 2),), (), "both ends on node"),
        ((Spring("s", 4, 5),), ((0, 0, 1), (0, 0, 2)), "world anchors"),
        ((Spring("s", -1, 2),), (), "does not exist"),
    ],
)
def test_invalid_topologies_raise(springs: tuple, anchors: tuple, message: str) -> None:
    with pytest.raises(TopologyError, match=message):
        Topology(rods=_rods(2), springs=springs, anchors=anchors)


def test_invalid_rods_raise() -> None:
    with pytest.raises(TopologyError, match="at least one rod"):
        Topology(rods=(), springs=())
    with pytest.raises(TopologyError, match="length must be positive"):
        Topology(rods=(Rod("r", 0.0),), springs=())
    with pytest.raises(TopologyError, match="duplicate"):
        Topology(rods=(Rod("r", 1.0), Rod("r", 1.0)), springs=())


@pytest.mark.parametrize("build", [icosahedron, element])
def test_mjcf_round_trip_gives_same_topology_and_identical_params(build) -> None:
    a = build()
    xml = to_mjcf(a.topology, a.params, SimOptions(), a.pose_p, a.pose_q)
    back = from_mjcf("<generated>", xml=xml)
    assert back.topology.same_as(a.topology)
    assert [s.name for s in back.topology.springs] == [s.name for s in a.topology.springs]
    for f in FIELDS:
        assert torch.equal(getattr(back.params, f), getattr(a.params, f)), f
    # the nominal pose survives as qpos0
    state = mj_to_rod_state(back, back.model.qpos0, np.zeros(back.model.nv))
    np.testing.assert_allclose(state["p"], a.pose_p, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(state["q"] * a.pose_q, -1)), 1.0, atol=1e-12)


def test_reads_an_mjcf_file_with_its_own_names_and_frames() -> None:
    asm = from_mjcf(EXAMPLE_MJCF)
    topo = asm.topology
    assert [r.name for r in topo.rods] == ["strut_A", "strut_B"]
    assert [s.name for s in topo.springs] == ["edge_west", "edge_north", "edge_east", "edge_south"]
    assert topo.n_anchors == 0
    np.testing.assert_allclose([r.length for r in topo.rods], np.sqrt(2), atol=1e-12)
    np.testing.assert_allclose(asm.params.stiffness.numpy(), [200, 220, 180, 210])
    np.testing.assert_allclose(asm.params.rest_length.numpy(), 0.9)
    # the struts' principal frames are not their body frames: the geometry still agrees
    # with MuJoCo's own tendon lengths
    m = asm.model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    state = mj_to_rod_state(asm, d.qpos.copy(), d.qvel.copy())
    nodes = node_positions(topo, state["p"], state["q"])
    np.testing.assert_allclose(_lengths(topo, nodes), d.ten_length, atol=1e-12)
    np.testing.assert_allclose(nodes[: 2 * topo.n_rods], d.site_xpos, atol=1e-12)


def test_the_robot_files_axial_moment_per_unit_mass_is_read_and_kept() -> None:
    """End caps cannot show a rod's moment about its own axis: the topology carries the
    robot file's (MuJoCo's compiled inertia over the mass) through serialisation."""
    a = icosahedron()
    inertia, mass = a.params.numpy()["inertia"], a.params.numpy()["mass"]
    heavy = inertia.copy()
    heavy[:, 2] *= 20.0  # end-cap housings: an axial moment far above a solid rod's
    xml = to_mjcf(a.topology, replace(a.params, inertia=torch.as_tensor(heavy)), SimOptions(),
                  a.pose_p, a.pose_q)  # fmt: skip
    topo = from_mjcf("<generated>", xml=xml).topology
    along = np.argmax(np.abs(np.diff(topo.end_offsets, axis=1)[:, 0]), axis=1)
    np.testing.assert_allclose(topo.axial_gyrations, heavy[np.arange(len(mass)), along] / mass, rtol=1e-9)
    assert Topology.from_dict(topo.to_dict()).axial_gyrations.tolist() == topo.axial_gyrations.tolist()
    # a rod file without one: a solid rod's r^2 / 2
    np.testing.assert_allclose(a.topology.axial_gyrations, [max(r.radius, 1e-3) ** 2 / 2 for r in a.topology.rods])
    with pytest.raises(TopologyError, match="axial_gyration must be > 0"):
        Topology(rods=(Rod("r", 1.0, axial_gyration=0.0),), springs=())
