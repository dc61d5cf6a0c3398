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
winch state, integrated by :func:`tensegrity_env.engine.winch.winch_step` (the engine's
discretisation).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from tensegrity_env.engine.winch import REST, initial_winch_state, winch_history, winch_step
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
        self.state = initial_winch_state(topology, self.params, 1)

    def reset(self, state: np.ndarray | None = None) -> None:
        """Back to ``state`` (W, 2) [m, m/s], or to rest at the declared rest lengths."""
        if state is None:
            self.state = initial_winch_state(self.topology, self.params, 1)
        else:
            self.state = torch.as_tensor(np.asarray(state, float)).reshape(1, -1, 2).clone()

    @property
    def rest_lengths(self) -> np.ndarray:
        """The wound springs' rest lengths now, (W,) [m]."""
        return self.state[0, :, REST].numpy().copy()

    def apply(self, rest: np.ndarray | None = None) -> None:
        """Write the rest lengths ``rest`` (W,) [m] (default: the winch state's) into
        ``model.tendon_lengthspring``."""
        rest = self.rest_lengths if rest is None else rest
        self.model.tendon_lengthspring[self.tendons, 0] = np.where(self.slack, 0.0, rest)
        self.model.tendon_lengthspring[self.tendons, 1] = rest

    def plan(self, commands: np.ndarray) -> np.ndarray:
        """The rest lengths before each step of command logs (n, T, W) from rest, (n, T, W)
        [m]: the winding depends on the commands alone, so a rollout can integrate it
        first (:func:`~tensegrity_env.engine.winch.winch_history`, the same steps as
        :meth:`step`) and only :meth:`apply` them between ``mj_step`` calls."""
        h = float(self.model.opt.timestep)
        history = winch_history(
            self.topology, self.params, torch.as_tensor(commands, dtype=torch.float64), h
        )
        return history[:, :-1, :, REST].numpy()

    def step(self, data: mujoco.MjData, command: np.ndarray | None = None) -> None:
        """One ``mj_step`` with the winches' rest lengths, then wind by ``command`` (W,)."""
        self.apply()
        mujoco.mj_step(self.model, data)
        u = None if command is None else torch.as_tensor(np.asarray(command, float)).reshape(1, -1)
        self.state = winch_step(self.state, self.params, u, float(self.model.opt.timestep))
