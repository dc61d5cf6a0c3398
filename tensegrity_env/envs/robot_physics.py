"""The physics of the generic robot environments: an identified model and its MuJoCo twin.

A robot is an MJCF file whose cables are wound by winches
(:mod:`tensegrity_env.mjcf.winches`); its identified model is a params file the
pipeline wrote for it (or, by default, the file's own parameters). Both simulators
hold packed rod states (R, 13) (rows ``p``, ``v``, ``q`` (w x y z), ``omega``, world
frame) and winch states (W, 2) (rest length [m], winding speed [m/s]) and advance them
``frame_skip`` physics steps per control step under motor commands (W,) in [-1, 1]:

* :class:`SRRobotSimulator`: the identified model by the C kernel
  (:meth:`NativeStepper.wind <tensegrity_env.envs.physics.NativeStepper.wind>`: the
  ``frame_skip`` physics steps and the winding of a control step in one call, threads
  over the batch), or by :class:`~tensegrity_env.engine.Engine` in float64 where the
  kernel cannot be built or an effect has no C form
  (:meth:`TorchStepper.wind <tensegrity_env.envs.physics.TorchStepper.wind>`, with a
  warning); the two agree to round-off.
* :class:`MJRobotSimulator`: MuJoCo with :class:`~tensegrity_env.mjcf.winches.MjWinches`
  setting ``tendon_lengthspring`` from the winch state before every ``mj_step`` (the
  winding of a control step integrated first, in NumPy:
  :class:`~tensegrity_env.mjcf.winches.Winding`).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from tensegrity_env.engine.winch import initial_winch_state
from tensegrity_env.envs.base import settle
from tensegrity_env.envs.mj_env import MJPhysics, pack_mj
from tensegrity_env.envs.physics import Backend, NativeStepper, make_stepper
from tensegrity_env.envs.robot_faces import tipped_poses
from tensegrity_env.envs.sr_env import ASSETS
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import MjcfAssembly, from_mjcf
from tensegrity_env.model import Model
from tensegrity_env.topology import Topology

#: the robot the generic environments move by default: the lab 3-bar with six winches
DEFAULT_ROBOT = ASSETS / "lab_prism.xml"
#: how long the resting pose is settled from the file's initial pose [s]
ROBOT_SETTLE_SECONDS = 5.0


def require_winches(topology: Topology, src: str | Path) -> None:
    """Raise :class:`InputError` unless the robot is driven by winches only."""
    if topology.n_cables:
        raise InputError(
            f"{src}: {topology.n_cables} force cable actuator(s): the generic environments "
            "drive winch cables (declare them with winch:<tendon> numerics, docs/mjcf.md)"
        )
    if not topology.n_winches:
        raise InputError(f"{src}: no winch cables (winch:<tendon> numerics): nothing to command")


def initial_pose(asm: MjcfAssembly) -> np.ndarray:
    """The file's own initial pose (``qpos0``) at rest, packed (R, 13)."""
    return pack_mj(asm, asm.model.qpos0.copy(), np.zeros(asm.model.nv))


class SRRobotSimulator:
    """B copies of a robot's identified model on the engine (see the module docstring).

    Args:
        model: the identified params file (None: the robot file's own parameters,
            floor contact and tension-only cables as it declares them).
        robot: the robot's MJCF (None: :data:`DEFAULT_ROBOT`): its pose to start from
            and its geometry to draw; the model must have its topology.
        frame_skip: physics steps per control step (the physics step is the file's
            ``timestep``).
        batch: number of copies stepped together.
        threads: the C kernel's threads over the batch (None: every available core), or
            PyTorch's CPU threads where it steps (None: PyTorch's setting).
        backend: ``"auto"`` (the C kernel where it applies), ``"native"`` or ``"torch"``
            (:func:`~tensegrity_env.envs.physics.make_stepper`).
    """

    def __init__(
        self,
        model: str | Path | None = None,
        robot: str | Path | None = None,
        frame_skip: int = 50,
        batch: int = 1,
        threads: int | None = None,
        backend: Backend = "auto",
    ) -> None:
        self.robot_path = Path(robot) if robot is not None else DEFAULT_ROBOT
        self.asm = from_mjcf(self.robot_path)
        self.model_path = Path(model) if model is not None else self.robot_path
        self.model = Model.read(self.model_path, dt=float(self.asm.model.opt.timestep))
        t = self.topology = self.model.topology
        if not t.same_as(self.asm.topology, atol=1e-9):
            raise InputError(
                f"{self.model_path}: its topology is not the robot's ({self.robot_path}: "
                f"{self.asm.topology.n_rods} rods, {self.asm.topology.n_springs} cables)"
            )
        require_winches(t, self.model_path)
        if "ground_contact" not in self.model.effect_names:
            raise InputError(
                f"{self.model_path}: no 'ground_contact' effect: identify it first (the "
                "robot would fall through the floor)"
            )
        self.params, self.effects = self.model.params, self.model.effects
        self.dt, self.frame_skip = self.model.dt, int(frame_skip)
        self.control_dt = self.dt * self.frame_skip
        self.command_shape = (t.n_winches,)
        self.stepper = make_stepper(t, self.params, self.effects, self.dt, self.frame_skip,
                                    backend=backend, threads=threads)  # fmt: skip
        self.rest_winch = initial_winch_state(t, self.params.to(dtype=torch.float64), 1)[0].numpy()
        self.x = np.zeros((batch, t.n_rods, 13))
        self.winch = np.repeat(self.rest_winch[None], batch, axis=0)
        # copy 0's step on its own buffers, bound once where the kernel steps
        self._command = np.zeros((1, t.n_winches))
        self._step_first = (
            self.stepper.bind(self.x[:1], self.winch[:1], self._command)
            if isinstance(self.stepper, NativeStepper)
            else None
        )

    def set_state(self, x: np.ndarray, winch: np.ndarray | None = None, i: int = 0) -> None:
        """Set copy ``i``: rod state (R, 13), winch state (W, 2) (None: at rest)."""
        self.x[i] = x
        self.winch[i] = self.rest_winch if winch is None else winch

    def get_state(self) -> np.ndarray:
        result: np.ndarray = self.x[0].copy()
        return result

    def get_winch(self) -> np.ndarray:
        result: np.ndarray = self.winch[0].copy()
        return result

    def step(self, command: np.ndarray) -> None:
        """Advance copy 0 under motor commands (W,) (in place: its rows are contiguous)."""
        if self._step_first is None:
            self.stepper.wind(self.x[:1], self.winch[:1],
                              np.asarray(command, dtype=np.float64)[None])  # fmt: skip
            return
        self._command[0] = command
        self._step_first()

    def step_batch(self, commands: np.ndarray) -> None:
        """Advance every copy under motor commands (B, W)."""
        self.stepper.wind(self.x, self.winch, commands)

    def rest_pose(self) -> np.ndarray:
        """The model's resting pose on the floor from the robot file's pose, (R, 13)
        (cached per file pair)."""
        m, r = self.model_path.resolve(), self.robot_path.resolve()
        return _sr_rest(str(m), m.stat().st_mtime, str(r), r.stat().st_mtime).copy()

    def tipped_poses(self) -> np.ndarray:
        """The model resting on each of its other faces, (F, R, 13)
        (:func:`~tensegrity_env.envs.robot_faces.tipped_poses`; cached per file pair)."""
        m, r = self.model_path.resolve(), self.robot_path.resolve()
        return _sr_tipped(str(m), m.stat().st_mtime, str(r), r.stat().st_mtime).copy()

    def render_assembly(self) -> MjcfAssembly:
        return self.asm


@lru_cache(maxsize=8)
def _sr_rest(model: str, model_mtime: float, robot: str, robot_mtime: float) -> np.ndarray:
    """Settled with the winches at rest and no command: no cable winds, so the model is
    the same without its winch state, and the native kernel steps it where it builds."""
    sim = SRRobotSimulator(model, robot)
    result = _sr_settler(sim)(initial_pose(sim.asm))
    if not np.all(np.isfinite(result)):
        raise RuntimeError(f"{model}: the model diverged while settling on the floor")
    return result


def _sr_settler(sim: SRRobotSimulator) -> Callable[[np.ndarray], np.ndarray]:
    """A pose (R, 13) after :data:`ROBOT_SETTLE_SECONDS` on ``sim``'s model with the
    winches at rest and no command (one C-kernel copy where it builds)."""
    stepper = make_stepper(sim.topology, sim.params, sim.effects, sim.dt, sim.frame_skip,
                           threads=1)  # fmt: skip
    zero = np.zeros((1, sim.topology.n_rods, 3))
    n = max(1, round(ROBOT_SETTLE_SECONDS / sim.control_dt))

    def run(x0: np.ndarray) -> np.ndarray:
        x = x0[None].copy()
        for _ in range(n):
            stepper(x, zero)
        result: np.ndarray = x[0]
        return result

    return run


@lru_cache(maxsize=8)
def _sr_tipped(model: str, model_mtime: float, robot: str, robot_mtime: float) -> np.ndarray:
    sim = SRRobotSimulator(model, robot)
    rest = _sr_rest(model, model_mtime, robot, robot_mtime)
    return tipped_poses(sim.topology, rest, _sr_settler(sim))


class MJRobotSimulator(MJPhysics):
    """One robot in MuJoCo, its winches wound by :class:`~tensegrity_env.mjcf.winches.MjWinches`.

    Args:
        robot: the robot's MJCF (None: :data:`DEFAULT_ROBOT`).
        frame_skip: MuJoCo steps per control step.
    """

    def __init__(self, robot: str | Path | None = None, frame_skip: int = 50) -> None:
        super().__init__(Path(robot) if robot is not None else DEFAULT_ROBOT, frame_skip)
        require_winches(self.topology, self.xml_path)
        self.plant = self.asm.mj_winches()
        self.command_shape = (self.topology.n_winches,)

    def set_state(self, x: np.ndarray, winch: np.ndarray | None = None) -> None:
        """Rod state (R, 13) and winch state (W, 2) (None: at rest)."""
        self.plant.reset(winch)
        self.plant.apply()
        super().set_state(x)

    def get_winch(self) -> np.ndarray:
        return self.plant.state.copy()

    def step(self, command: np.ndarray) -> None:
        """``frame_skip`` MuJoCo steps under motor commands (W,)."""
        self._advance(lambda: self.plant.run(self.data, command, self.frame_skip))

    def rest_pose(self) -> np.ndarray:
        """The twin's resting pose, settled in MuJoCo from the file's pose (cached per file)."""
        p = self.xml_path.resolve()
        return _mj_rest(str(p), p.stat().st_mtime, self.frame_skip).copy()

    def tipped_poses(self) -> np.ndarray:
        """The twin resting on each of its other faces, settled in MuJoCo, (F, R, 13)
        (:func:`~tensegrity_env.envs.robot_faces.tipped_poses`; cached per file)."""
        p = self.xml_path.resolve()
        return _mj_tipped(str(p), p.stat().st_mtime, self.frame_skip).copy()


@lru_cache(maxsize=8)
def _mj_rest(xml_path: str, mtime: float, frame_skip: int) -> np.ndarray:
    sim = MJRobotSimulator(xml_path, frame_skip)
    return settle(sim, initial_pose(sim.asm), ROBOT_SETTLE_SECONDS, np.zeros(sim.command_shape))


@lru_cache(maxsize=8)
def _mj_tipped(xml_path: str, mtime: float, frame_skip: int) -> np.ndarray:
    sim = MJRobotSimulator(xml_path, frame_skip)
    zero = np.zeros(sim.command_shape)
    rest = _mj_rest(xml_path, mtime, frame_skip)
    return tipped_poses(sim.topology, rest,
                        lambda x0: settle(sim, x0, ROBOT_SETTLE_SECONDS, zero))  # fmt: skip


class MJRobotBatch:
    """N twins (:class:`MJRobotSimulator`) stepped one after another, with the batch
    interface of :class:`SRRobotSimulator`: ``x`` (N, R, 13), ``winch`` (N, W, 2),
    ``set_state(x, winch, i)``, ``step_batch(commands)``. ``mujoco.rollout`` cannot step
    them: the winches change the model's rest lengths between ``mj_step`` calls.

    Args:
        robot, frame_skip: as :class:`MJRobotSimulator`. batch: N.
    """

    def __init__(self, robot: str | Path | None = None, frame_skip: int = 50, batch: int = 1):
        self.sims = [MJRobotSimulator(robot, frame_skip) for _ in range(batch)]
        first = self.sims[0]
        self.topology, self.control_dt = first.topology, first.control_dt
        self.command_shape, self.asm = first.command_shape, first.asm
        self.rest_winch = first.get_winch()
        self.x = np.zeros((batch, self.topology.n_rods, 13))
        self.winch = np.repeat(self.rest_winch[None], batch, axis=0)

    def set_state(self, x: np.ndarray, winch: np.ndarray | None = None, i: int = 0) -> None:
        self.sims[i].set_state(x, winch)
        self.x[i], self.winch[i] = self.sims[i].get_state(), self.sims[i].get_winch()

    def step_batch(self, commands: np.ndarray) -> None:
        """Every twin ``frame_skip`` steps under its motor commands (N, W)."""
        for i, (sim, u) in enumerate(zip(self.sims, commands, strict=True)):
            sim.step(u)
            self.x[i], self.winch[i] = sim.get_state(), sim.get_winch()

    def rest_pose(self) -> np.ndarray:
        return self.sims[0].rest_pose()

    def tipped_poses(self) -> np.ndarray:
        return self.sims[0].tipped_poses()
