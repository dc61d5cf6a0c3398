"""A robot's observation and task error in one C call (``native_sense.c``).

:mod:`~tensegrity_env.envs.robot_task` states what a generic environment observes and
how far its task is from done in NumPy (:class:`~tensegrity_env.envs.robot_task.RobotSensors`,
the tasks' ``observe`` and ``error``); an environment step needs all of it, for one robot
or thousands, and a few dozen small NumPy calls cost more than the physics of one robot's
control step. :class:`NativeSense` computes the same readings in one call of the C kernel:
the float32 observation equal to NumPy's bit for bit, the goal distance and the rods'
centre too (sums in NumPy's order, nothing fused), and the shape task's length error to
round-off (tests/unit/test_robot_sense.py). Where no C compiler works,
:func:`native_sense` returns None and the tasks read in NumPy.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from tensegrity_env.native.kernel import NativeUnavailable, load_kernel
from tensegrity_env.topology import Topology

#: the kernel's task codes
TASK_CODES = {"goal": 0, "shape": 1}


class NativeSense:
    """Observation (B, n_obs) float32, task error (B,) [m] and rods' centre (B, 3) [m] of
    B robots of one topology from rod states (B, R, 13) and winch states (B, W, 2).

    Args:
        topology: the robot (its end caps, anchors, attachment points, cables, winches).
        task: ``"goal"`` (target: the goal (B, 2) [m]) or ``"shape"`` (target: the wound
            cables' lengths (B, W) [m]).
        lib: the loaded kernel.
    """

    def __init__(self, topology: Topology, task: str, lib: Any) -> None:
        t = topology
        self.topology, self.code, self._lib = t, TASK_CODES[task], lib
        self.target_size = 2 if task == "goal" else t.n_winches
        self.size = 6 * t.n_rods + 1 + t.n_springs + t.n_winches + self.target_size
        self._node_rod = np.ascontiguousarray(t.node_rod, dtype=np.int32)
        self._offsets = np.ascontiguousarray(t.node_offsets, dtype=np.float64)
        self._springs = np.ascontiguousarray(t.spring_nodes, dtype=np.int32)
        self._wound = np.ascontiguousarray(t.winches, dtype=np.int32)
        self._dims = (t.n_rods, t.n_nodes, t.n_springs, t.n_winches, self.code)
        self._robot = (self._node_rod.ctypes.data, self._offsets.ctypes.data,
                       self._springs.ctypes.data, self._wound.ctypes.data)  # fmt: skip

    def __call__(
        self, x: np.ndarray, winch: np.ndarray, target: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(obs, error, centre)`` of the robots ``x`` (B, R, 13), ``winch`` (B, W, 2),
        ``target`` (B, k) (any float64 arrays; copied where not C-contiguous)."""
        x, winch, target = (np.ascontiguousarray(a, dtype=np.float64) for a in (x, winch, target))
        B = x.shape[0]
        t = self.topology
        if (x.shape != (B, t.n_rods, 13) or winch.shape != (B, t.n_winches, 2)
                or target.shape != (B, self.target_size)):  # fmt: skip
            raise ValueError(
                f"sensing takes states (B, {t.n_rods}, 13), winches (B, {t.n_winches}, 2) "
                f"and targets (B, {self.target_size}); got {x.shape}, {winch.shape}, "
                f"{target.shape}"
            )
        obs = np.empty((B, self.size), dtype=np.float32)
        error, centre = np.empty(B), np.empty((B, 3))
        code = self._lib.tsr_sense(
            B, *self._dims, x.ctypes.data, winch.ctypes.data, target.ctypes.data, *self._robot,
            obs.ctypes.data, error.ctypes.data, centre.ctypes.data,
        )  # fmt: skip
        if code != 0:
            raise ValueError(f"{t.name}: too large for the sensing kernel (code {code})")
        return obs, error, centre

    def one(
        self,
    ) -> Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, float, np.ndarray]]:
        """A reader of one robot, ``(x (R, 13), winch (W, 2), target (k,)) -> (obs (n_obs,)
        float32, error [m], centre (3,) [m])``: :meth:`__call__` on a batch of one, through
        buffers whose addresses are taken once (a single environment reads every step)."""
        t = self.topology
        x, winch = np.zeros((1, t.n_rods, 13)), np.zeros((1, t.n_winches, 2))
        target = np.zeros((1, self.target_size))
        obs, error, centre = np.empty((1, self.size), np.float32), np.empty(1), np.empty((1, 3))
        args = (1, *self._dims, x.ctypes.data, winch.ctypes.data, target.ctypes.data,
                *self._robot, obs.ctypes.data, error.ctypes.data, centre.ctypes.data)  # fmt: skip
        sense = self._lib.tsr_sense

        def read(
            xs: np.ndarray, ws: np.ndarray, gs: np.ndarray
        ) -> tuple[np.ndarray, float, np.ndarray]:
            x[0], winch[0], target[0] = xs, ws, gs
            code = sense(*args)
            if code != 0:
                raise ValueError(f"{t.name}: too large for the sensing kernel (code {code})")
            return obs[0].copy(), float(error[0]), centre[0].copy()

        return read


def native_sense(topology: Topology, task: str) -> NativeSense | None:
    """:class:`NativeSense` for a robot and task, or None where the kernel cannot be
    built or the robot is larger than it takes."""
    try:
        lib = load_kernel()[0]
    except NativeUnavailable:
        return None
    if (topology.n_rods > lib.tsr_max_rods() or topology.n_nodes > lib.tsr_max_nodes()
            or topology.n_winches > lib.tsr_max_winches()):  # fmt: skip
        return None
    return NativeSense(topology, task, lib)
