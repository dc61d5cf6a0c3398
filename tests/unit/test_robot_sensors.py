"""The generic environments' sensors: every node of the shipped robot (end caps and the
cables' attachment points) where the assembly's own geometry puts it."""

from __future__ import annotations

import numpy as np

from tensegrity_env.assemblies import node_positions
from tensegrity_env.envs.robot_physics import DEFAULT_ROBOT
from tensegrity_env.envs.robot_task import RobotSensors
from tensegrity_env.mjcf import from_mjcf


def test_nodes_are_the_assembly_node_positions() -> None:
    """Random rod poses, one robot and a batch: the same nodes as ``node_positions``."""
    topology = from_mjcf(DEFAULT_ROBOT).topology
    sensors = RobotSensors(topology)
    rng = np.random.default_rng(3)
    B, R = 5, topology.n_rods
    x = np.zeros((B, R, 13))
    x[..., 0:3] = rng.uniform(-1, 1, (B, R, 3))
    q = rng.normal(size=(B, R, 4))
    x[..., 6:10] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x[..., 3:6] = rng.normal(size=(B, R, 3))  # velocities play no part
    expected = node_positions(topology, x[..., 0:3], x[..., 6:10])
    assert topology.n_nodes > 2 * R  # attachment points besides the end caps
    np.testing.assert_allclose(sensors.nodes(x), expected, rtol=0, atol=1e-14)
    np.testing.assert_allclose(sensors.nodes(x[1:2]), expected[1:2], rtol=0, atol=1e-14)
    np.testing.assert_allclose(sensors.end_caps(x), expected[:, : 2 * R], rtol=0, atol=1e-14)
