"""``IcosahedronMJ-v0``: the same task in MuJoCo with the true parameters (the twin).

The twin's model ships as ``tensegrity_env/assets/icosahedron_rolling.xml``
(:func:`tensegrity_env.envs.twin.twin_mjcf`): the prestressed icosahedron, a floor,
and three world-axis force actuators per rod whose gain is the true ``h``, so the
same command ``f_u`` applies ``h_true * f_u``. :class:`MJBatch` steps many copies
through MuJoCo's multi-threaded :mod:`mujoco.rollout` for the vector twin.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Unpack

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from tensegrity_env.envs.base import RollingEnv, settle
from tensegrity_env.envs.physics import default_threads
from tensegrity_env.envs.sr_env import ASSETS
from tensegrity_env.envs.task import TaskOptions, make_task
from tensegrity_env.mjcf import MjcfAssembly, from_mjcf
from tensegrity_env.mujoco_state import mj_to_rod_state, rod_state_to_mj

#: the MuJoCo twin (regenerate: tensegrity_sr/make_default_params.py)
TWIN_XML = ASSETS / "icosahedron_rolling.xml"


def pack_mj(asm: MjcfAssembly, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """Packed rod states (..., R, 13) from MuJoCo's qpos (..., nq) and qvel (..., nv)."""
    s = mj_to_rod_state(asm, qpos, qvel)
    return np.concatenate([s["p"], s["v"], s["q"], s["omega"]], axis=-1)


def unpack_mj(asm: MjcfAssembly, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's (qpos, qvel) from packed rod states (..., R, 13)."""
    return rod_state_to_mj(asm, x[..., 0:3], x[..., 3:6], x[..., 6:10], x[..., 10:13])


class MJPhysics:
    """One assembly in MuJoCo, ``frame_skip`` steps per control step: its packed rod
    state in and out, and MuJoCo's declared instability kept as ``diverged``. The base
    of the icosahedron's twin (:class:`MJSimulator`) and of a winch-driven robot's
    (:class:`~tensegrity_env.envs.robot_physics.MJRobotSimulator`).

    Args:
        xml_path: the assembly's MJCF.
        frame_skip: MuJoCo steps per control step.
    """

    def __init__(self, xml_path: Path, frame_skip: int) -> None:
        self.xml_path = xml_path
        self.asm = from_mjcf(self.xml_path)
        self.topology, self.model = self.asm.topology, self.asm.model
        self.data = mujoco.MjData(self.model)
        self.frame_skip = int(frame_skip)
        self.control_dt = float(self.model.opt.timestep) * self.frame_skip
        self.diverged = False

    def set_state(self, x: np.ndarray) -> None:
        """Packed rod states (R, 13), at MuJoCo's clock 0."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:], self.data.qvel[:] = unpack_mj(self.asm, x)
        mujoco.mj_forward(self.model, self.data)
        self.diverged = False

    def get_state(self) -> np.ndarray:
        """Packed rod states (R, 13); NaN once MuJoCo has declared the simulation unstable."""
        if self.diverged:
            return np.full((self.topology.n_rods, 13), np.nan)
        return pack_mj(self.asm, self.data.qpos.copy(), self.data.qvel.copy())

    def _advance(self, run: Callable[[], None]) -> None:
        """``run()`` (the MuJoCo steps of a control step), flagging ``diverged`` where
        MuJoCo reset an unstable simulation to ``qpos0`` and went on."""
        bad = self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC]
        before = bad.number
        run()
        self.diverged |= bad.number > before

    def render_assembly(self) -> MjcfAssembly:
        return self.asm


class MJSimulator(MJPhysics):
    """The icosahedron's twin (``mj_step`` with ``nstep = frame_skip``), commanded by its
    world-axis force actuators.

    Args:
        frame_skip: MuJoCo steps per control step.
        xml_path: the twin's MJCF (None: the shipped model).
    """

    def __init__(self, frame_skip: int = 50, xml_path: str | Path | None = None) -> None:
        super().__init__(Path(xml_path) if xml_path is not None else TWIN_XML, frame_skip)
        if np.any(self.asm.actuators < 0):
            raise ValueError(f"{self.xml_path}: every rod needs x, y, z force actuators")

    def step(self, command: np.ndarray) -> None:
        self.data.ctrl[self.asm.actuators.ravel()] = np.asarray(command).ravel()
        self._advance(lambda: mujoco.mj_step(self.model, self.data, nstep=self.frame_skip))

    def initial_pose(self) -> np.ndarray:
        """The model's own initial pose (``qpos0``, the face-down nominal pose), at rest."""
        return pack_mj(self.asm, self.model.qpos0.copy(), np.zeros(self.model.nv))


@lru_cache(maxsize=8)
def _twin_rest(xml_path: str, mtime: float, frame_skip: int) -> np.ndarray:
    sim = MJSimulator(frame_skip, xml_path)
    return settle(sim, sim.initial_pose())


def twin_rest_pose(sim: MJSimulator) -> np.ndarray:
    """The twin's resting pose, settled in MuJoCo (cached per model file)."""
    p = sim.xml_path.resolve()
    return _twin_rest(str(p), p.stat().st_mtime, sim.frame_skip).copy()


class MJBatch:
    """``B`` copies of the twin stepped by :mod:`mujoco.rollout` (one call per control step).

    Holds MuJoCo's full physics state of every copy; ``threads`` rollout threads.
    """

    def __init__(self, sim: MJSimulator, batch: int, threads: int | None = None) -> None:
        self.sim, self.asm, self.model = sim, sim.asm, sim.model
        self.threads = int(threads or default_threads())
        self._pool = mj_rollout.Rollout(nthread=self.threads)
        self._datas = [mujoco.MjData(self.model) for _ in range(self.threads)]
        self.spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        nstate = mujoco.mj_stateSize(self.model, self.spec)
        self.states = np.zeros((batch, nstate))
        self._out = np.empty((batch, sim.frame_skip, nstate))
        t = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_TIME)
        self._qpos = slice(t, t + self.model.nq)
        self._qvel = slice(t + self.model.nq, t + self.model.nq + self.model.nv)
        self.diverged = np.zeros(batch, dtype=bool)

    def set_states(self, idx: np.ndarray, x: np.ndarray) -> None:
        """Set copies ``idx`` from packed rod states (len(idx), R, 13)."""
        for i, xi in zip(idx, x, strict=True):
            self.sim.set_state(xi)
            mujoco.mj_getState(self.model, self.sim.data, self.states[i], self.spec)
        self.diverged[idx] = False

    def get_states(self) -> np.ndarray:
        """Packed rod states of every copy (B, R, 13); NaN where MuJoCo went unstable."""
        x = pack_mj(self.asm, self.states[:, self._qpos], self.states[:, self._qvel])
        x[self.diverged] = np.nan
        return x

    def step(self, commands: np.ndarray) -> None:
        """Every copy ``frame_skip`` MuJoCo steps under commands (B, R, 3)."""
        B = commands.shape[0]
        ctrl = np.zeros((B, 1, self.model.nu))
        ctrl[:, 0, self.asm.actuators.ravel()] = commands.reshape(B, -1)
        expected = self.states[:, 0] + self.sim.frame_skip * self.model.opt.timestep
        self._pool.rollout(
            self.model, self._datas, self.states, ctrl, nstep=self.sim.frame_skip,
            state=self._out,
        )  # fmt: skip
        self.states[:] = self._out[:, -1]
        # an unstable copy is reset by MuJoCo (its clock restarts): report it instead
        self.diverged |= self.states[:, 0] < expected - 0.5 * self.model.opt.timestep

    def close(self) -> None:
        self._pool.close()


class IcosahedronMJEnv(RollingEnv):
    """The MuJoCo twin of :class:`~tensegrity_env.envs.sr_env.IcosahedronSREnv`.

    Identical action and observation spaces, task, rewards, terminations, reset
    procedure and handling of bad input (a NaN or misshapen action raises
    ``ValueError``, ``step`` before ``reset`` raises ``ResetNeeded``; see
    ``IcosahedronSREnv`` for the tables); the physics is MuJoCo with
    the true parameters and contact, and the actuators apply ``h_true * f_u``. Its
    resting pose is settled in MuJoCo from the same face-down nominal pose. It is
    the ground truth for checking what a policy trained on the identified env does
    on the "real" robot; ``reset(options={"state": x, "goal": g})`` starts it in a
    state taken from the identified env.

    Args:
        xml_path: the twin's MJCF (None: ``tensegrity_env/assets/icosahedron_rolling.xml``).
        frame_skip, render_mode, width, height, **task: as ``IcosahedronSREnv``.
    """

    #: what videos call this env
    label = "MuJoCo (IcosahedronMJ-v0)"

    def __init__(
        self,
        xml_path: str | Path | None = None,
        frame_skip: int = 50,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        **task: Unpack[TaskOptions],
    ) -> None:
        sim = MJSimulator(frame_skip, xml_path)
        rest = twin_rest_pose(sim)
        super().__init__(sim, rest, make_task(sim.control_dt, task), render_mode, width, height)
