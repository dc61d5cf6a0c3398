"""Stepping the identified model for environments: ``frame_skip`` physics steps per action.

Two steppers with one interface, ``stepper(x, control)`` advancing ``x`` (B, R, 13)
float64 in place (rows ``p`` (3) [m], ``v`` (3) [m/s], ``q`` (4, w x y z), ``omega``
(3) [rad/s], world frame, as :class:`~tensegrity_env.engine.State`) under commands
``control`` (B, R, 3) held for the whole control step:

* :class:`NativeStepper`, the default on CPU: the C kernel
  (``tensegrity_env/native/native_step.h`` and its files: the engine's step with the effects it has,
  written out per assembly, threads over the batch; the model packed by
  :func:`~tensegrity_env.native.pack.pack_model`, as the engine's no-gradient step
  packs it). It fuses the ``frame_skip`` substeps of a control step into one call and
  visits only the end caps that touch the floor, which is what makes one
  environment step cheaper than MuJoCo's and a batch of 4096 an order of magnitude
  faster (``benchmarks/bench_env.py``). :meth:`NativeStepper.wind` winds a robot's
  winches in the same call.
* :class:`TorchStepper`: :class:`~tensegrity_env.engine.Engine` itself, with any
  effects, on any device; the reference the native kernel is tested against, and
  the fallback where the kernel cannot be built or an effect has no native form.

Why not ``torch.compile``: the engine's ground contact solves a small active-set
problem per rod. Compiled through Inductor (a ``while_loop`` over the substeps)
the unrolled solve took ~10 minutes to compile and ran at ~0.3 ms per substep for
one assembly, ten times MuJoCo; eager PyTorch is ~1000 times slower per substep.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Literal, Protocol

import numpy as np
import torch

from tensegrity_env.effects.ground_contact import ACTIVE_SET_ITERATIONS
from tensegrity_env.engine import Engine, State
from tensegrity_env.engine.effects import Effect
from tensegrity_env.io_utils import InputError
from tensegrity_env.native.build import NativeUnavailable
from tensegrity_env.native.kernel import NARROW_LANES, load_kernel
from tensegrity_env.native.pack import PACKED_PARAMS, pack_model
from tensegrity_env.params import Params
from tensegrity_env.rotations import np_quat_to_matrix
from tensegrity_env.topology import Topology

#: rows of the packed state: p, v, q, omega
STATE_SIZE = 13
Backend = Literal["auto", "native", "torch"]


class Stepper(Protocol):
    """Advances packed states (B, R, 13) in place by ``frame_skip`` physics steps."""

    frame_skip: int
    dt: float
    backend: str

    def __call__(self, x: np.ndarray, control: np.ndarray) -> None: ...


def pack_states(state: State) -> np.ndarray:
    """Packed (B, R, 13) float64 array from a :class:`State`."""
    return np.ascontiguousarray(
        np.concatenate([t.detach().cpu().double().numpy() for t in state.tensors()], axis=-1)
    )


def unpack_states(
    x: np.ndarray, dtype: torch.dtype = torch.float64, device: str | torch.device = "cpu"
) -> State:
    """:class:`State` from packed (B, R, 13) states."""
    return State.from_numpy(x[..., 0:3], x[..., 3:6], x[..., 6:10], x[..., 10:13], dtype, device)


def default_threads() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


class KernelMismatch(ValueError):
    """The native kernel no longer computes what :class:`Engine` computes."""


class NativeStepper:
    """The C kernel (see the module docstring). Raises :class:`NativeUnavailable`.

    Args:
        topology, params: the identified model.
        effects: its effects, those the kernel has
            (:class:`~tensegrity_env.native.pack.NotNative`, a ValueError, otherwise).
        dt: physics step [s]. frame_skip: physics steps per call.
        threads: OpenMP threads over the batch (None: every available core).
        contact_iterations: most active-set iterations of the contact problem (None:
            ``GroundContact``'s own limit).
        verify: compare one step with :class:`Engine` on states touching the floor and
            raise :class:`KernelMismatch` if they differ beyond round-off (the kernel
            restates the engine's physics; this catches the two drifting apart).
    """

    backend = "native"

    def __init__(
        self,
        topology: Topology,
        params: Params,
        effects: Sequence[Effect],
        dt: float,
        frame_skip: int,
        threads: int | None = None,
        contact_iterations: int | None = None,
        verify: bool = True,
    ) -> None:
        packed = pack_model(topology, {k: getattr(params, k) for k in PACKED_PARAMS}, effects)
        self._lib, self.openmp = load_kernel()
        try:  # the narrow build, for a few assemblies (the same numbers, less latency)
            self._narrow = load_kernel(NARROW_LANES)[0]
        except NativeUnavailable:
            self._narrow = self._lib
        if (
            topology.n_rods > self._lib.tsr_max_rods()
            or topology.n_nodes > self._lib.tsr_max_nodes()
            or topology.n_points > self._lib.tsr_max_points()
            or topology.n_winches > self._lib.tsr_max_winches()
        ):
            raise ValueError(f"{topology.name}: too large for the native kernel")
        self.topology = topology
        self.dt, self.frame_skip = float(dt), int(frame_skip)
        self.threads = int(threads or default_threads())
        self.iterations = int(contact_iterations or ACTIVE_SET_ITERATIONS)
        self._model = packed.models[0]
        self._springs = np.ascontiguousarray(topology.spring_nodes, dtype=np.int32)
        # the arrays' addresses, taken once (a step passes them as they are)
        self._model_ptr, self._springs_ptr = self._model.ctypes.data, self._springs.ctypes.data
        if verify:
            self.verify(params, effects)

    def verify(self, params: Params, effects: Sequence[Effect], atol: float = 1e-9) -> float:
        """Largest state difference after two steps against :class:`Engine` (float64).

        The states: rods in random orientations spread over a square metre, each
        lowered so that its lower end cap sinks 1 mm into the floor, with random
        velocities and commands; with winches, their rest lengths and speeds at random
        within their ranges and random motor commands (:meth:`wind`). Raises
        :class:`KernelMismatch` above ``atol``.
        """
        t = self.topology
        rng = np.random.default_rng(0)
        B, R = 3, t.n_rods
        q = rng.normal(size=(B, R, 4))
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
        ends = np.einsum("brij,rkj->brki", np_quat_to_matrix(q), t.end_offsets)
        radius = np.array([max(r.radius, 1e-3) for r in t.rods])
        p = np.concatenate([rng.uniform(-0.5, 0.5, (B, R, 2)), np.zeros((B, R, 1))], -1)
        p[..., 2] = radius - 1e-3 - ends[..., 2].min(axis=-1)
        x = np.concatenate([p, rng.normal(0, 0.3, (B, R, 3)), q, rng.normal(0, 1, (B, R, 3))], -1)
        u = rng.normal(0, 1, (B, R, 3))
        engine = Engine(t, self.dt, effects)
        W = t.n_winches
        lo, hi = (getattr(params, k).detach().double().numpy() for k in ("winch_min", "winch_max"))
        winch = np.stack([rng.uniform(lo, hi, (B, W)), rng.normal(0, 0.05, (B, W))], -1)
        commands = rng.uniform(-1.2, 1.2, (B, W))
        ref = unpack_states(x).with_winch(torch.as_tensor(winch) if W else None)
        with torch.no_grad():
            for _ in range(2):
                ref = engine.step(ref, params, torch.as_tensor(u),
                                  winches=torch.as_tensor(commands) if W else None)  # fmt: skip
        steps, self.frame_skip = self.frame_skip, 2
        try:
            mine, wound = np.ascontiguousarray(x), winch.copy()
            if W:
                self.wind(mine, wound, commands, u)
            else:
                self(mine, u)
        finally:
            self.frame_skip = steps
        err = float(np.abs(mine - pack_states(ref)).max())
        if W:
            err = max(err, float(np.abs(wound - ref.winch.numpy()).max()))
        if not err <= atol:
            raise KernelMismatch(
                f"the native kernel differs from the engine by {err:.2e} (> {atol:g}): "
                "an effect's law changed without the C kernel (tensegrity_env/native/)"
            )
        return err

    def __call__(self, x: np.ndarray, control: np.ndarray) -> None:
        """Advance ``x`` (B, R, 13) in place under ``control`` (B, R, 3); winches, if the
        robot has any, hold the model's rest lengths (no winding: see :meth:`wind`)."""
        u = np.ascontiguousarray(control, dtype=np.float64)
        B, R = x.shape[:2]
        if u.shape != (B, R, 3):
            raise ValueError(f"control has shape {u.shape}, expected {(B, R, 3)}")
        self._run(x, u, None, None)

    def wind(
        self,
        x: np.ndarray,
        winch: np.ndarray,
        commands: np.ndarray,
        control: np.ndarray | None = None,
    ) -> None:
        """Advance rod states ``x`` (B, R, 13) and winch states ``winch`` (B, W, 2) [m,
        m/s] (both C-contiguous float64) in place by ``frame_skip`` physics steps, the
        winch motors' ``commands`` (B, W) in [-1, 1] held (clipped), as
        :meth:`Engine.step <tensegrity_env.engine.Engine.step>` winds them; ``control``
        (B, R, 3) the rods' commands f_u (None: none)."""
        B, W = x.shape[0], self.topology.n_winches
        if winch.shape != (B, W, 2) or winch.dtype != np.float64 or not winch.flags.c_contiguous:
            raise ValueError(f"winch states must be a C-contiguous float64 array {(B, W, 2)}")
        c = np.ascontiguousarray(commands, dtype=np.float64)
        if c.shape != (B, W):
            raise ValueError(f"winch commands have shape {c.shape}, expected {(B, W)}")
        u = None if control is None else np.ascontiguousarray(control, dtype=np.float64)
        self._run(x, u, winch, c)

    def bind(self, x: np.ndarray, winch: np.ndarray, commands: np.ndarray) -> Callable[[], None]:
        """A call that does ``wind(x, winch, commands)`` on these arrays, checked once here
        (the shapes and layouts of :meth:`wind`; ``commands`` are read as they are at each
        call, and must lie in [-1, 1] or be clipped by the kernel): one environment's
        step, without re-checking its own buffers every step."""
        B, W = x.shape[0], self.topology.n_winches
        for name, a, shape in (
            ("states", x, (B, self.topology.n_rods, STATE_SIZE)),
            ("winch states", winch, (B, W, 2)),
            ("commands", commands, (B, W)),
        ):
            if a.shape != shape or a.dtype != np.float64 or not a.flags.c_contiguous:
                raise ValueError(f"{name} must be a C-contiguous float64 array {shape}")
        args = self._args(x, None, winch, commands)
        step = self._lib_for(B).tsr_step

        def bound(_arrays: tuple[np.ndarray, ...] = (x, winch, commands)) -> None:
            # _arrays: the call holds them, so the addresses in args stay valid
            code = step(*args)
            if code != 0:
                raise RuntimeError(f"native kernel failed with code {code}")

        return bound

    def _lib_for(self, batch: int) -> Any:
        """The build that steps ``batch`` assemblies fastest: the narrow one for a few."""
        return self._narrow if batch <= NARROW_LANES else self._lib

    def _args(
        self,
        x: np.ndarray,
        u: np.ndarray | None,
        winch: np.ndarray | None,
        commands: np.ndarray | None,
    ) -> tuple[Any, ...]:
        """``tsr_step``'s arguments for these arrays."""
        t = self.topology
        return (
            x.shape[0], t.n_rods, t.n_springs, t.n_anchors, self.frame_skip, self.dt,
            self.iterations, x.ctypes.data, None if u is None else u.ctypes.data,
            self._model_ptr, self._springs_ptr, self.threads,
            None if winch is None else winch.ctypes.data,
            None if commands is None else commands.ctypes.data,
        )  # fmt: skip

    def _run(
        self,
        x: np.ndarray,
        u: np.ndarray | None,
        winch: np.ndarray | None,
        commands: np.ndarray | None,
    ) -> None:
        if x.dtype != np.float64 or not x.flags.c_contiguous:
            raise ValueError("states must be a C-contiguous float64 array (B, R, 13)")
        code = self._lib_for(x.shape[0]).tsr_step(*self._args(x, u, winch, commands))
        if code != 0:
            raise RuntimeError(f"native kernel failed with code {code}")


@contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """PyTorch's intra-op CPU threads set to ``threads`` inside (None: left as they are).

    A few rods are tensors of a few dozen numbers: extra threads only add
    synchronisation, which costs most on a loaded machine.
    """
    before = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(int(threads))
    try:
        yield
    finally:
        if threads is not None:
            torch.set_num_threads(before)


class TorchStepper:
    """:class:`Engine` with any effects (eager PyTorch, any device).

    Args:
        topology, params, effects: the identified model.
        dt: physics step [s]. frame_skip: physics steps per call.
        dtype, device: where the engine runs.
        threads: PyTorch's CPU threads while stepping (None: PyTorch's setting).
    """

    backend = "torch"

    def __init__(
        self,
        topology: Topology,
        params: Params,
        effects: Sequence[Effect],
        dt: float,
        frame_skip: int,
        dtype: torch.dtype = torch.float64,
        device: str | torch.device = "cpu",
        threads: int | None = None,
    ) -> None:
        self.threads = threads
        self.engine = Engine(topology, dt, effects, dtype=dtype, device=device)
        self.params = params.to(dtype=dtype, device=device)
        self.dt, self.frame_skip = float(dt), int(frame_skip)
        self.dtype, self.device = dtype, torch.device(device)

    def __call__(self, x: np.ndarray, control: np.ndarray) -> None:
        with torch.no_grad(), torch_threads(self.threads):
            state = unpack_states(x, self.dtype, self.device)
            u = torch.as_tensor(np.asarray(control), dtype=self.dtype, device=self.device)
            for _ in range(self.frame_skip):
                state = self.engine.step(state, self.params, u)
            x[...] = pack_states(state)

    def wind(self, x: np.ndarray, winch: np.ndarray, commands: np.ndarray) -> None:
        """Advance rod states ``x`` (B, R, 13) and winch states ``winch`` (B, W, 2) [m, m/s]
        in place by ``frame_skip`` physics steps, the winch motors' commands ``commands``
        (B, W) in [-1, 1] held (:meth:`Engine.step <tensegrity_env.engine.Engine.step>`)."""
        with torch.no_grad(), torch_threads(self.threads):
            kw: dict[str, Any] = {"dtype": self.dtype, "device": self.device}
            state = unpack_states(x, self.dtype, self.device).with_winch(
                torch.as_tensor(winch, **kw)
            )
            u = torch.as_tensor(np.asarray(commands), **kw)
            for _ in range(self.frame_skip):
                state = self.engine.step(state, self.params, winches=u)
            x[...] = pack_states(state)
            assert state.winch is not None  # a state stepped with winches keeps them
            winch[...] = state.winch.cpu().numpy()


def make_stepper(
    topology: Topology,
    params: Params,
    effects: Sequence[Effect],
    dt: float,
    frame_skip: int,
    backend: Backend = "auto",
    device: str | torch.device = "cpu",
    threads: int | None = None,
) -> NativeStepper | TorchStepper:
    """The native kernel where it applies (``"auto"`` on CPU), else the PyTorch engine.

    A model with cable actuators is refused (:class:`InputError`): env actions are the
    world-frame control forces f_u, and neither stepper takes cable commands.
    """
    if topology.n_cables:
        raise InputError(
            f"{topology.name}: has {topology.n_cables} cable actuator(s); the envs' actions are"
            " control forces f_u per rod and cannot command cables"
        )
    if backend not in ("auto", "native", "torch"):
        raise ValueError(f"backend must be 'auto', 'native' or 'torch', got {backend!r}")
    on_cpu = torch.device(device).type == "cpu"
    if backend == "native" or (backend == "auto" and on_cpu):
        if not on_cpu:
            raise ValueError("the native backend runs on the CPU; use backend='torch'")
        try:
            return NativeStepper(topology, params, effects, dt, frame_skip, threads)
        except (NativeUnavailable, ValueError) as e:
            if backend == "native":
                raise
            warnings.warn(f"{e}: stepping the PyTorch engine instead (slower)", stacklevel=2)
    return TorchStepper(topology, params, effects, dt, frame_skip, device=device, threads=threads)
