"""The engine's steps by the C kernel where no gradient is wanted.

An :class:`~tensegrity_env.engine.Engine` built with ``native=True`` hands a step to
:class:`NativeEngineStep` (the C kernel, ``native_step.h``: the engine's physics written out
per assembly) when the kernel computes the same thing: no gradient wanted through the
state, the parameters or the effects, float64 on the CPU, no cable commands, a kernel
that builds, and a model :func:`~tensegrity_env.native.pack.pack_model` packs (only
effects the kernel has, each with the shapes it takes). Winches are wound in the kernel
too: the winch state (B, W, 2) goes in and comes out with the rod states. Parameters with a batch
dimension (a forward-difference Jacobian's perturbed copies) are stepped in runs of
consecutive assemblies that share them, one model per run. Otherwise the step runs in
PyTorch as always, and the reason is logged once (logger ``tensegrity_env.native``).
The two agree to round-off (``tests/unit/test_native_engine_path.py``).

Why: a trajectory fit steps small batches (a few windows) thousands of times, where
PyTorch spends its time dispatching its ~150 operations per physics step, not on
arithmetic; the kernel fuses the substeps of a step into one call.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import torch

from tensegrity_env.effects.ground_contact import ACTIVE_SET_ITERATIONS
from tensegrity_env.native.kernel import (
    GRADIENT_WANTED,
    SWITCHED_OFF,
    unusable_reason,
    usable_kernel,
)
from tensegrity_env.native.pack import PACKED_PARAMS, NotNative, PackedModel, pack_model
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology

LOG = logging.getLogger("tensegrity_env.native")

__all__ = ["FallbackLog", "ModelCache", "NativeEngineStep"]


class FallbackLog:
    """Logs why a step that asked for the kernel ran in PyTorch, once per reason.

    A gradient wanted (the kernel has none) and the kernel switched off are choices,
    logged at INFO; every other reason (an effect without a native form, parameters or
    dtypes it does not take, cable commands, no compiler) is a step slower than it could
    be, at WARNING.
    """

    def __init__(self) -> None:
        self.seen: set[str] = set()

    def __call__(self, reason: str) -> None:
        if reason in self.seen:
            return
        self.seen.add(reason)
        level = logging.INFO if reason in (GRADIENT_WANTED, SWITCHED_OFF) else logging.WARNING
        LOG.log(level, "Engine(native=True): stepping PyTorch instead of the C kernel: %s", reason)


#: the process's fallback log: each reason is said once per process
FALLBACKS = FallbackLog()


class ModelCache:
    """The last packed model, for the same parameter tensors unchanged.

    A rollout steps the same parameters every step, so the model is packed once. The
    key is each tensor's identity and version counter (bumped by every in-place
    change) and the batch size; the tensors are held while cached, so an identity
    cannot pass to a new tensor.
    """

    def __init__(self) -> None:
        self._key: tuple[object, ...] | None = None
        self._held: tuple[torch.Tensor, ...] = ()
        self._model: PackedModel | None = None

    @staticmethod
    def key(fields: Sequence[torch.Tensor], batch: int) -> tuple[object, ...]:
        return (*((id(t), t._version) for t in fields), batch)

    def get(self, fields: Sequence[torch.Tensor], batch: int) -> PackedModel | None:
        """The model packed for ``fields`` and ``batch``, or None."""
        return self._model if self._key == self.key(fields, batch) else None

    def put(self, fields: Sequence[torch.Tensor], batch: int, model: PackedModel) -> None:
        self._key, self._held, self._model = self.key(fields, batch), tuple(fields), model


class NativeEngineStep:
    """One engine's steps by the kernel (see the module docstring).

    Args:
        topology: the engine's assembly graph. effects: its effects.
        substeps: physics steps per step, each ``physics_dt`` [s] long.
        has_cables: whether the topology has cable actuators (their commands are
            stepped in PyTorch).
    """

    def __init__(
        self,
        topology: Topology,
        effects: Sequence[object],
        substeps: int,
        physics_dt: float,
        has_cables: bool,
    ) -> None:
        self.topology = topology
        self.effects = tuple(effects)
        self.substeps, self.physics_dt = int(substeps), float(physics_dt)
        self.has_cables = bool(has_cables)
        self.cache = ModelCache()
        self.fallbacks = FALLBACKS
        # the springs' node pairs (S, 2) as the kernel takes them
        self.springs = np.ascontiguousarray(topology.spring_nodes, dtype=np.int32)

    def __call__(
        self,
        state: Sequence[torch.Tensor],
        params: Params,
        control: torch.Tensor | None,
        cables: torch.Tensor | None,
        winch: torch.Tensor | None = None,
        commands: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor | None] | None:
        """The packed states (B, R, 13) and the winch state (B, W, 2) [m, m/s] (None
        without ``winch``) after one engine step of ``state`` (``p``, ``v``, ``q``,
        ``omega``, each (B, R, ·)) and ``winch`` under the winch motors' ``commands``
        (B, W) (None: 0) by the kernel, or None (the reason logged) where the kernel
        does not compute the same."""
        try:
            return self._step(state, params, control, cables, winch, commands)
        except NotNative as e:
            self.fallbacks(str(e))
            return None

    def _step(
        self,
        state: Sequence[torch.Tensor],
        params: Params,
        control: torch.Tensor | None,
        cables: torch.Tensor | None,
        winch: torch.Tensor | None,
        commands: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        if cables is not None and self.has_cables:
            raise NotNative("cable commands")
        B, R = state[0].shape[:2]
        if commands is not None:
            commands = commands.to(torch.float64)
        fields = {k: getattr(params, k) for k in PACKED_PARAMS}
        tensors = [*state, *fields.values()]
        tensors += [t for t in (control, winch, commands) if t is not None]
        reason = unusable_reason(*tensors)
        if reason is not None:
            raise NotNative(reason)
        lib = usable_kernel()
        if lib is None:  # pragma: no cover - unusable_reason says why first
            raise NotNative("the kernel is unavailable")
        if torch.is_grad_enabled() and any(
            torch.is_tensor(v) and v.requires_grad
            for e in self.effects
            for v in getattr(e, "values", {}).values()
        ):
            raise NotNative(GRADIENT_WANTED)
        order = [fields[k] for k in PACKED_PARAMS]
        model = self.cache.get(order, B)
        if model is None:
            model = pack_model(self.topology, fields, self.effects, B)
            self.cache.put(order, B, model)
        x = torch.cat([t.detach() for t in state], dim=-1).contiguous().numpy()
        u = None
        if control is not None:
            u = np.ascontiguousarray(torch.broadcast_to(control.detach(), (B, R, 3)).numpy())
        topo = self.topology
        W = topo.n_winches
        w = None if winch is None else winch.detach().clone().reshape(B, W, 2).contiguous()
        c = None
        if w is not None and commands is not None:
            c = np.ascontiguousarray(torch.broadcast_to(commands.detach(), (B, W)).numpy())
        code = lib.tsr_step_groups(
            B, R, topo.n_springs, topo.n_anchors, self.substeps, self.physics_dt,
            ACTIVE_SET_ITERATIONS, x.ctypes.data, _ptr(u), model.models.ctypes.data,
            len(model.start) - 1, model.start.ctypes.data, self.springs.ctypes.data, 1,
            _ptr(None if w is None else w.numpy()), _ptr(c),
        )  # fmt: skip
        if code != 0:
            raise NotNative(f"the kernel refused the model (code {code})")
        return torch.from_numpy(x), w


def _ptr(a: np.ndarray | None) -> int | None:
    """``a``'s address for the kernel (None: NULL)."""
    return None if a is None else int(a.ctypes.data)
