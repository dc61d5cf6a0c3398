"""Winch cables in MJCF: the convention that declares them, and their MuJoCo plant.

Convention: a spring (a two-site spatial tendon) is wound by a winch when the model has
a custom numeric named ``winch:<tendon name>`` with 3 or 4 values::

    <custom>
      <numeric name="winch:c0" data="v_max l_min l_max"/>        <!-- no motor lag -->
      <numeric name="winch:c4" data="v_max l_min l_max tau"/>    <!-- lag tau [s] -->
    </custom>

``v_max`` [m/s] is the rest length's rate at command 1 (winch radius times the motor's
top angular speed), ``[l_min, l_max]`` [m] the rest length's range, ``tau`` [s] the
motor's first-order lag on its speed (0 or absent: none). The tendon's
``springlength`` is the rest length at the start. Winches are numbered in the order of
their numerics in the file: motor command ``k`` winds the ``k``-th. MuJoCo loads the
numerics and ignores them; it cannot change a rest length by itself, so
:class:`MjWinches` sets ``model.tendon_lengthspring`` before every ``mj_step`` from the
winch state, integrated by :class:`Winding`: the steps of
:func:`tensegrity_env.engine.winch.winch_step` (the engine's discretisation, the
reference) in NumPy, the same numbers bit for bit at a fraction of PyTorch's per-call
cost (one implementation for every MuJoCo plant: this one and the twins stepped through
``mujoco.rollout``, :mod:`tensegrity_env.envs.robot_rollout`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from tensegrity_env.engine.winch import initial_winch_state, winding_decay
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import WINCH_FIELDS, Params
from tensegrity_env.topology import Topology

#: name prefix of the custom numerics that declare winches
WINCH_PREFIX = "winch:"


@dataclass(frozen=True)
class WinchDecl:
    """The winches an MJCF file declares (what :func:`winches_of` reads).

    Attributes:
        tendons: the tendon each winch winds, in winch order.
        values: per field of :data:`~tensegrity_env.params.WINCH_FIELDS`, (W,) arrays
            (``winch_speed`` [m/s], ``winch_min``, ``winch_max`` [m], ``winch_lag`` [s]).
    """

    tendons: list[int]
    values: dict[str, np.ndarray]


def winches_of(m: mujoco.MjModel, src: str) -> WinchDecl:
    """The winch numerics of a compiled model (module convention); raises
    :class:`InputError` naming the file, the numeric and the value at fault."""
    NUM, TEN = mujoco.mjtObj.mjOBJ_NUMERIC, mujoco.mjtObj.mjOBJ_TENDON
    tendons: list[int] = []
    rows: list[list[float]] = []
    for k in range(m.nnumeric):
        name = mujoco.mj_id2name(m, NUM, k) or ""
        if not name.startswith(WINCH_PREFIX):
            continue
        tendon = name[len(WINCH_PREFIX) :]
        t = mujoco.mj_name2id(m, TEN, tendon)
        if t < 0:
            raise InputError(f"{src}: numeric '{name}': no tendon named '{tendon}'")
        if t in tendons:
            raise InputError(f"{src}: numeric '{name}': tendon '{tendon}' has two winches")
        adr, size = int(m.numeric_adr[k]), int(m.numeric_size[k])
        if size not in (3, 4):
            raise InputError(
                f"{src}: numeric '{name}' has {size} values, expected 3 or 4 (v_max l_min l_max [tau])"
            )
        data = [float(x) for x in m.numeric_data[adr : adr + size]] + [0.0] * (4 - size)
        _check(data, name, src)
        tendons.append(t)
        rows.append(data)
    table = np.array(rows, dtype=float).reshape(-1, 4)
    return WinchDecl(tendons, {f: table[:, i].copy() for i, f in enumerate(WINCH_FIELDS)})


def _check(data: list[float], name: str, src: str) -> None:
    labels = ("v_max", "l_min", "l_max", "tau")
    for i, x in enumerate(data):
        if not np.isfinite(x):
            raise InputError(f"{src}: numeric '{name}': {labels[i]} (value {i}) is not finite")
    v, low, high, tau = data
    problem = (
        "v_max (value 0) must be > 0" if v <= 0 else
        "l_min (value 1) must be >= 0" if low < 0 else
        "l_max (value 2) must be >= l_min" if high < low else
        "tau (value 3) must be >= 0" if tau < 0 else ""
    )  # fmt: skip
    if problem:
        raise InputError(f"{src}: numeric '{name}': {problem}, got {data[:4]}")


def winch_numerics(topology: Topology, params: Params) -> list[tuple[str, str]]:
    """``(name, data)`` of each winch's custom numeric, in winch order (for the writer)."""
    P = params.numpy()
    out = []
    for w, s in enumerate(topology.winches):
        data = [P[f][w] for f in WINCH_FIELDS]
        out.append(
            (WINCH_PREFIX + topology.springs[s].name, " ".join(repr(float(x)) for x in data))
        )
    return out


class Winding:
    """The winches' winding in NumPy: the steps of
    :func:`~tensegrity_env.engine.winch.winch_step` (module doc of
    :mod:`tensegrity_env.engine.winch`, step 3), its lag decay taken from
    :func:`~tensegrity_env.engine.winch.winding_decay`, so that the two agree bit for bit
    in float64 (``tests/unit/test_winches.py``).

    Args:
        params: ``winch_speed`` [m/s], ``winch_min``, ``winch_max`` [m], ``winch_lag``
            [s], each (W,).
        h: the physics step [s].
    """

    def __init__(self, params: Params, h: float) -> None:
        p = params.to(dtype=torch.float64)
        self.h = float(h)
        self.v_max = p.winch_speed.detach().cpu().numpy().copy()
        self.l_min = p.winch_min.detach().cpu().numpy().copy()
        self.l_max = p.winch_max.detach().cpu().numpy().copy()
        self.decay = winding_decay(p.winch_lag.detach().cpu(), self.h).numpy().copy()

    def wind(
        self, rest: np.ndarray, speed: np.ndarray, command: np.ndarray | None, steps: int = 1
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``steps`` physics steps of winding with the motor commands held.

        Args:
            rest: the winch state's rest lengths, (..., W) [m].
            speed: the winch state's winding speeds, (..., W) [m/s].
            command: the motors' commands (..., W), clipped to [-1, 1] (None: 0).
            steps: physics steps.

        Returns:
            ``(before, rest, speed)``: the rest lengths at the start of each step, what
            the springs pull with during it, (steps, ..., W) [m]; the state after the
            last step, (..., W) [m] and [m/s].
        """
        rest = np.array(rest, dtype=np.float64)
        speed = np.array(speed, dtype=np.float64)
        u = np.zeros_like(rest) if command is None else np.asarray(command, dtype=np.float64)
        target = np.minimum(np.maximum(u, -1.0), 1.0) * self.v_max
        before = np.empty((steps, *rest.shape))
        for k in range(steps):
            before[k] = rest
            speed = target + (speed - target) * self.decay
            rest = np.minimum(np.maximum(rest + self.h * speed, self.l_min), self.l_max)
        return before, rest, speed


class MjWinches:
    """Winds a compiled model's winch tendons: the MuJoCo side of the winches.

    Before every ``mj_step`` the wound tendons' ``tendon_lengthspring`` is set from the
    winch state (a tension-only spring keeps its dead band ``[0, l0]``); after it, the
    state advances by :func:`~tensegrity_env.engine.winch.winch_step` with the step's
    commands. The model is changed in place: one :class:`MjWinches` per model in use.

    Args:
        model: the compiled model. topology, params: the assembly it was read as
            (``MjcfAssembly.topology``/``params``). slack_springs: its tension-only springs.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        topology: Topology,
        params: Params,
        slack_springs: Sequence[int] = (),
    ) -> None:
        self.model = model
        self.topology = topology
        self.params = params.to(dtype=torch.float64)
        self.tendons = np.asarray(topology.winches, dtype=int)
        self.slack = np.array([s in set(slack_springs) for s in topology.winches], dtype=bool)
        self.winding = Winding(self.params, float(model.opt.timestep))
        self.at_rest = initial_winch_state(topology, self.params, 1)[0].numpy().copy()
        #: the winch state (W, 2): rest length [m], winding speed [m/s]
        self.state = self.at_rest.copy()

    def reset(self, state: np.ndarray | None = None) -> None:
        """Back to ``state`` (W, 2) [m, m/s], or to rest at the declared rest lengths."""
        src = self.at_rest if state is None else np.asarray(state, dtype=np.float64)
        self.state = src.reshape(-1, 2).copy()

    @property
    def rest_lengths(self) -> np.ndarray:
        """The wound springs' rest lengths now, (W,) [m]."""
        return self.state[:, 0].copy()

    def _lengthspring(self, rest: np.ndarray) -> np.ndarray:
        """The wound tendons' ``tendon_lengthspring`` rows for rest lengths (..., W) [m]:
        (..., W, 2) (a tension-only spring keeps its dead band ``[0, l0]``)."""
        return np.stack([np.where(self.slack, 0.0, rest), rest], axis=-1)

    def apply(self, rest: np.ndarray | None = None) -> None:
        """Write the rest lengths ``rest`` (W,) [m] (default: the winch state's) into
        ``model.tendon_lengthspring``."""
        rest = self.state[:, 0] if rest is None else np.asarray(rest, dtype=np.float64)
        self.model.tendon_lengthspring[self.tendons] = self._lengthspring(rest)

    def plan(self, commands: np.ndarray) -> np.ndarray:
        """The rest lengths before each step of command logs (n, T, W) from rest, (n, T, W)
        [m]: the winding depends on the commands alone, so a rollout can integrate it
        first (the same steps as :meth:`step`) and only :meth:`apply` them between
        ``mj_step`` calls."""
        u = np.asarray(commands, dtype=np.float64)
        out = np.empty(u.shape)
        rest = np.broadcast_to(self.at_rest[:, 0], u[:, 0].shape)
        speed = np.broadcast_to(self.at_rest[:, 1], u[:, 0].shape)
        for t in range(u.shape[1]):
            before, rest, speed = self.winding.wind(rest, speed, u[:, t])
            out[:, t] = before[0]
        return out

    def run(self, data: mujoco.MjData, command: np.ndarray | None, steps: int) -> None:
        """``steps`` ``mj_step`` calls with motor commands ``command`` (W,) held (None:
        0): the winding over them integrated first (it depends on the commands alone),
        each step's rest lengths written before it."""
        before, rest, speed = self.winding.wind(self.state[:, 0], self.state[:, 1], command,
                                                steps)  # fmt: skip
        rows = self._lengthspring(before)
        lengthspring, tendons = self.model.tendon_lengthspring, self.tendons
        for k in range(steps):
            lengthspring[tendons] = rows[k]
            mujoco.mj_step(self.model, data)
        self.state = np.stack([rest, speed], axis=-1)

    def step(self, data: mujoco.MjData, command: np.ndarray | None = None) -> None:
        """One ``mj_step`` with the winches' rest lengths, then wind by ``command`` (W,)."""
        self.run(data, command, 1)
