"""N MuJoCo twins of a winch-driven robot through :mod:`mujoco.rollout`.

A winch changes its tendon's rest length ``l0``, which ``mujoco.rollout`` cannot change
between steps; but the winding depends on the motor commands alone (never on the rods'
motion), and a plain spring's force along its tendon is linear in ``l0``:

    ``-K (L - l0(t)) = -K (L - l_ref) + K (l0(t) - l_ref)``.

So each wound tendon keeps its file's rest length ``l_ref`` and gets a force actuator
(a ``motor`` on the tendon, gear 1) whose control at each physics step is
``K (l0 - l_ref)``, ``l0`` the rest length :class:`~tensegrity_env.mjcf.winches.MjWinches`
would have written before that step; the winding over a control step is integrated
first (by the twin's own :class:`~tensegrity_env.mjcf.winches.Winding`) and the
whole control step of every twin is one ``rollout`` call over threads. The same forces
as the twin stepped one ``mj_step`` at a time, to round-off
(``tests/unit/test_robot_envs.py``). A robot with a tension-only wound cable (a dead
band, whose force is not linear in ``l0``) is refused (:class:`ValueError`): its twins
are stepped one after another (:class:`~tensegrity_env.envs.robot_physics.MJRobotBatch`).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from tensegrity_env.envs.mj_env import pack_mj, unpack_mj
from tensegrity_env.envs.physics import default_threads
from tensegrity_env.envs.robot_physics import MJRobotSimulator
from tensegrity_env.io_utils import InputError

#: the name prefix of the force actuators added on the wound tendons
MOTOR_PREFIX = "winch_motor:"


def motor_model(xml_path: Path, tendons: list[str]) -> mujoco.MjModel:
    """The robot file compiled with a force actuator (gear 1, no control limit) on each
    of ``tendons``, after the file's own actuators."""
    try:
        spec = mujoco.MjSpec.from_file(str(xml_path))
    except ValueError as e:
        raise InputError(f"{xml_path}: {e}") from None
    for name in tendons:
        act = spec.add_actuator()
        act.name = MOTOR_PREFIX + name
        act.trntype = mujoco.mjtTrn.mjTRN_TENDON
        act.target = name
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE
    return spec.compile()


class MJRobotRollout:
    """N twins through ``mujoco.rollout`` (see the module docstring), with the batch
    interface of :class:`~tensegrity_env.envs.robot_physics.SRRobotSimulator`: ``x``
    (N, R, 13), ``winch`` (N, W, 2) [m, m/s], ``set_state(x, winch, i)``,
    ``step_batch(commands)``.

    Args:
        robot: the robot's MJCF (None: the shipped lab 3-bar).
        frame_skip: MuJoCo steps per control step. batch: N.
        threads: rollout threads (None: every available core).

    Raises:
        ValueError: a wound cable is tension-only (the twins cannot go through a rollout).
    """

    def __init__(
        self,
        robot: str | Path | None = None,
        frame_skip: int = 50,
        batch: int = 1,
        threads: int | None = None,
    ) -> None:
        self.base = MJRobotSimulator(robot, frame_skip)
        plant, asm = self.base.plant, self.base.asm
        if plant.slack.any():
            raise ValueError(f"{self.base.xml_path}: a wound cable is tension-only")
        self.asm, self.topology = asm, self.base.topology
        self.control_dt, self.command_shape = self.base.control_dt, self.base.command_shape
        self.frame_skip = int(frame_skip)
        t = self.topology
        names = [t.springs[s].name for s in t.winches]
        self.model = motor_model(self.base.xml_path, names)
        tendons = np.asarray(t.winches, dtype=int)
        self.motors = np.array([self.model.actuator(MOTOR_PREFIX + n).id for n in names])
        self.stiffness = self.model.tendon_stiffness[tendons].copy()  # K [N/m]
        self.l_ref = self.model.tendon_lengthspring[tendons, 1].copy()  # [m]
        self.winding = plant.winding  # the twin's own winding (mjcf/winches.py)
        self.h = float(self.model.opt.timestep)
        self.threads = int(threads or default_threads())
        self._pool = mj_rollout.Rollout(nthread=self.threads)
        self._datas = [mujoco.MjData(self.model) for _ in range(self.threads)]
        self._data = mujoco.MjData(self.model)
        self.spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        nstate = mujoco.mj_stateSize(self.model, self.spec)
        self.states = np.zeros((batch, nstate))
        self._out = np.empty((batch, self.frame_skip, nstate))
        self._ctrl = np.zeros((batch, self.frame_skip, self.model.nu))
        n_time = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_TIME)
        self._qpos = slice(n_time, n_time + self.model.nq)
        self._qvel = slice(n_time + self.model.nq, n_time + self.model.nq + self.model.nv)
        self.rest_winch = self.base.get_winch()
        self.x = np.zeros((batch, t.n_rods, 13))
        self.winch = np.repeat(self.rest_winch[None], batch, axis=0)
        self.diverged = np.zeros(batch, dtype=bool)

    def set_state(self, x: np.ndarray, winch: np.ndarray | None = None, i: int = 0) -> None:
        """Set twin ``i``: rod state (R, 13), winch state (W, 2) (None: at rest)."""
        mujoco.mj_resetData(self.model, self._data)
        self._data.qpos[:], self._data.qvel[:] = unpack_mj(self.asm, x)
        mujoco.mj_getState(self.model, self._data, self.states[i], self.spec)
        self.x[i] = pack_mj(self.asm, self._data.qpos.copy(), self._data.qvel.copy())
        self.winch[i] = self.rest_winch if winch is None else winch
        self.diverged[i] = False

    def step_batch(self, commands: np.ndarray) -> None:
        """Every twin ``frame_skip`` MuJoCo steps under its motor commands (N, W)."""
        # the rest lengths before each step (K, N, W) [m], and the winch state after
        before, rest, speed = self.winding.wind(self.winch[..., 0], self.winch[..., 1], commands,
                                                self.frame_skip)  # fmt: skip
        ctrl = self._ctrl
        ctrl[:, :, self.motors] = (self.stiffness * (before - self.l_ref)).transpose(1, 0, 2)
        expected = self.states[:, 0] + self.frame_skip * self.h
        self._pool.rollout(self.model, self._datas, self.states, ctrl, nstep=self.frame_skip,
                           state=self._out)  # fmt: skip
        self.states[:] = self._out[:, -1]
        # an unstable copy is reset by MuJoCo (its clock restarts): report it instead
        self.diverged |= self.states[:, 0] < expected - 0.5 * self.h
        self.x[:] = pack_mj(self.asm, self.states[:, self._qpos], self.states[:, self._qvel])
        self.x[self.diverged] = np.nan
        self.winch[..., 0], self.winch[..., 1] = rest, speed

    def rest_pose(self) -> np.ndarray:
        return self.base.rest_pose()

    def tipped_poses(self) -> np.ndarray:
        return self.base.tipped_poses()

    def close(self) -> None:
        self._pool.close()
