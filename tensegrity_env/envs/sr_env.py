"""``IcosahedronSR-v0``: the rolling icosahedron on the identified spring-rod engine."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Unpack

import numpy as np
import torch

from tensegrity_env.envs.base import RollingEnv, settle
from tensegrity_env.envs.physics import Backend, make_stepper
from tensegrity_env.envs.task import TaskOptions, make_task
from tensegrity_env.envs.twin import TWIN_TIMESTEP, face_down_pose, twin_assembly
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import MjcfAssembly, SimOptions, from_mjcf, to_mjcf
from tensegrity_env.model import Model

ASSETS = Path(__file__).resolve().parent.parent / "assets"
#: the identified model that ships with the package (regenerate: tensegrity_sr/make_default_params.py)
DEFAULT_PARAMS = ASSETS / "icosahedron_rolling_params.json"


def load_env_model(path: str | Path | None = None) -> Model:
    """The identified icosahedron model of a params file, stepped at the twin's 1 ms.

    Raises :class:`InputError` if the file is not an icosahedron (the rolling task
    needs its geometry) or has no ground contact effect (it would fall through the
    floor).
    """
    path = Path(path) if path is not None else DEFAULT_PARAMS
    model = Model.load(path, dt=TWIN_TIMESTEP)
    if not model.topology.same_as(twin_assembly().topology, atol=1e-9):
        raise InputError(f"{path}: the rolling environments need the icosahedron's topology")
    if "ground_contact" not in model.effect_names:
        raise InputError(
            f"{path}: no 'ground_contact' effect: identify it first (the structure would "
            "fall through the floor)"
        )
    return model


class SRSimulator:
    """One (or B) assemblies on the identified engine; see :mod:`tensegrity_env.envs.physics`.

    Args:
        params_path: identified params file (None: the shipped default).
        frame_skip: physics steps of ``dt = 1 ms`` per control step.
        backend: ``"auto"`` (native C kernel on CPU), ``"native"`` or ``"torch"``.
        device: torch device of the ``"torch"`` backend.
        batch: number of assemblies stepped together.
        threads: CPU threads of the native kernel (None: all cores).
    """

    def __init__(
        self,
        params_path: str | Path | None = None,
        frame_skip: int = 50,
        backend: Backend = "auto",
        device: str | torch.device = "cpu",
        batch: int = 1,
        threads: int | None = None,
    ) -> None:
        self.params_path = Path(params_path) if params_path is not None else DEFAULT_PARAMS
        self.model = load_env_model(self.params_path)
        self.topology, self.params = self.model.topology, self.model.params
        self.effects = self.model.effects
        self.dt, self.frame_skip = self.model.dt, int(frame_skip)
        self.control_dt = self.dt * self.frame_skip
        self.stepper = make_stepper(
            self.topology, self.params, self.effects, self.dt, self.frame_skip, backend, device,
            threads,
        )  # fmt: skip
        self.x = np.zeros((batch, self.topology.n_rods, 13))

    # single-assembly interface (Simulator)
    def set_state(self, x: np.ndarray) -> None:
        self.x[0] = x

    def get_state(self) -> np.ndarray:
        result: np.ndarray = self.x[0].copy()
        return result

    def step(self, command: np.ndarray) -> None:
        """Advance the first (single) assembly: command (R, 3)."""
        self.stepper(self.x[:1], np.asarray(command, dtype=np.float64)[None])

    def step_batch(self, commands: np.ndarray) -> None:
        """Advance every assembly: commands (B, R, 3)."""
        self.stepper(self.x, commands)

    def initial_pose(self) -> np.ndarray:
        """The face-down nominal pose at rest, packed (R, 13)."""
        a = twin_assembly()
        p, q = face_down_pose(self.topology, a.pose_p, a.pose_q)
        R = self.topology.n_rods
        return np.concatenate([p, np.zeros((R, 3)), q, np.zeros((R, 3))], axis=1)

    def render_assembly(self) -> MjcfAssembly:
        xml = to_mjcf(self.topology, self.params, SimOptions(ground=True, control=False))
        return from_mjcf(f"<{self.params_path.name}>", xml=xml)


@lru_cache(maxsize=8)
def _rest_pose(params_path: str, mtime: float, frame_skip: int) -> np.ndarray:
    sim = SRSimulator(params_path, frame_skip, "auto")  # the same model on any backend
    return settle(sim, sim.initial_pose())


def rest_pose(sim: SRSimulator) -> np.ndarray:
    """The identified model's resting pose on the floor (cached per params file).

    Settled by the native kernel where it builds, whatever ``sim``'s backend: both
    compute the same model, and the PyTorch engine would take minutes for it.
    """
    p = sim.params_path.resolve()
    return _rest_pose(str(p), p.stat().st_mtime, sim.frame_skip).copy()


class IcosahedronSREnv(RollingEnv):
    """Roll a six-rod tensegrity icosahedron to a goal, on the identified engine.

    The structure (six 1.04 m rods, 24 prestressed springs, ~12 kg) rests on a
    triangular face on the floor. Each rod carries a control arm a quarter of its
    length from its centre where a world-frame force ``h * f_u`` acts, ``f_u`` the
    command and ``h`` the control gain identified from data. The commands are
    bounded (``max_command`` per rod: at most a quarter of the weight in all) so the
    robot cannot lift itself: it must tip over its edges, i.e. roll, to move its
    centre (the mean of the rod centres) into a goal disc on the floor.

    The physics is the model the identification pipeline wrote into a params file
    (the shipped default, or ``params_path``): per-spring stiffness, damping and
    rest length, per-rod mass and inertia, the control gain and the identified
    ground-contact effect, stepped at ``dt = 1 ms`` (MuJoCo's Euler step exactly),
    ``frame_skip`` steps per action (20 Hz by default). ``IcosahedronMJ-v0`` is the
    same task in MuJoCo with the true parameters.

    **Action space** ``Box(-1, 1, (18,), float32)``: per rod ``r`` (``3r .. 3r+2``) a
    force command along world x, y, z. Each rod's 3-vector is clipped to the unit
    ball and scaled by ``max_command``:

    =====  ==============================  =====  =====  =======================
    index  action                          min    max    unit
    =====  ==============================  =====  =====  =======================
    3r+0   command f_u,x of rod r          -1     1      max_command (force h f_u)
    3r+1   command f_u,y of rod r          -1     1      max_command
    3r+2   command f_u,z of rod r          -1     1      max_command
    =====  ==============================  =====  =====  =======================

    **Observation space** ``Box(-inf, inf, (75,), float32)``, world axes, the centre
    ``c`` being the mean of the six rod centres:

    =======  =============================================  =====
    index    observation                                    unit
    =======  =============================================  =====
    0-17     rod centre minus c, rod r at 3r..3r+2          m
    18-35    rod axis (unit vector from end cap 0 to 1)     -
    36-53    rod centre linear velocity                     m/s
    54-71    rod angular velocity                           rad/s
    72       height of c above the floor                    m
    73-74    goal minus c (x, y)                            m
    =======  =============================================  =====

    **Rewards** (each term in ``info``): ``reward_progress`` = ``progress_weight`` x
    the approach speed to the goal [m/s]; ``reward_control`` = -``control_weight`` x
    the mean squared command (as a fraction of ``max_command``); ``reward_goal`` =
    ``goal_bonus`` on reaching the goal.

    **Episode end**: ``terminated`` when the centre is within ``goal_radius`` of the
    goal (``info["is_success"]``) or, should the physics ever diverge, with
    ``info["physics_diverged"]``; ``truncated`` at the time limit (300 steps = 15 s,
    applied by ``gym.make``'s ``TimeLimit``).

    **Bad input** (the same in ``IcosahedronMJ-v0`` and the vector envs): ``step``
    before the first ``reset`` raises ``gymnasium.error.ResetNeeded``; an action of a
    shape other than (18,), or with a NaN or infinite entry, raises ``ValueError``
    naming the expected shape or the bad entries, before any physics runs.

    **Reset** (deterministic for a seed): the model's own resting pose, settled once
    from the face-down nominal pose, turned by a random yaw, perturbed by
    ``reset_noise_scale``; the goal 2-4 m away in a random direction.
    ``reset(options={"state": x, "goal": g})`` sets both explicitly (packed rod
    states (6, 13): p, v, q (w x y z), omega), e.g. to start the twin in the same
    state.

    Args:
        params_path: identified params file (None: the shipped default,
            ``tensegrity_env/assets/icosahedron_rolling_params.json``).
        frame_skip: physics steps (1 ms) per action.
        backend: ``"auto"`` (the native C kernel on CPU, else the PyTorch engine),
            ``"native"`` or ``"torch"``.
        device: torch device of the ``"torch"`` backend.
        render_mode: ``"rgb_array"``, ``"human"`` or None.
        width, height: rendered image size [px].
        **task: the task and reward options (:class:`TaskOptions`): ``goal_distance``,
            ``goal_radius``, ``max_command``, ``progress_weight``, ``control_weight``,
            ``goal_bonus``, ``reset_noise_scale``; see
            :class:`~tensegrity_env.envs.task.RollingTask`.
    """

    #: what videos call this env
    label = "identified model (IcosahedronSR-v0)"

    def __init__(
        self,
        params_path: str | Path | None = None,
        frame_skip: int = 50,
        backend: Backend = "auto",
        device: str | torch.device = "cpu",
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        **task: Unpack[TaskOptions],
    ) -> None:
        sim = SRSimulator(params_path, frame_skip, backend, device, batch=1, threads=1)
        task_ = make_task(sim.control_dt, task)
        super().__init__(sim, rest_pose(sim), task_, render_mode, width, height)
