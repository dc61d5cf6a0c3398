"""MuJoCo's multi-threaded batched rollout, converted to rod states and end caps.

:class:`Roller` wraps :mod:`mujoco.rollout` (a thread pool and one ``MjData`` per
thread, reused across calls; a model with winches is stepped one ``mj_step`` at a time
instead, by its winch plant :class:`~tensegrity_env.mjcf.winches.MjWinches`, since MuJoCo
cannot wind a rest length itself). :class:`RodFrames` turns MuJoCo's free-joint
``(qpos, qvel)`` into rod states in each rod's principal frame and end-cap
positions, vectorized over any leading dimensions; it computes exactly what
:func:`tensegrity_env.mujoco_state.mj_to_rod_state` and
:func:`tensegrity_env.assemblies.node_positions` compute, with quaternion rotations
written out component by component so that the conversion costs a small fraction
of the simulation (see ``benchmarks/bench_generate.py``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import MjcfAssembly
from tensegrity_env.mjcf.winches import MjWinches
from tensegrity_env.rotations import np_quat_mul, np_quat_to_matrix


@dataclass(frozen=True)
class StateLayout:
    """Where time, qpos and qvel sit in MuJoCo's ``mjSTATE_FULLPHYSICS`` vector."""

    size: int
    time: int
    qpos: slice
    qvel: slice

    @classmethod
    def of(cls, m: mujoco.MjModel) -> StateLayout:
        t = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_TIME)
        return cls(
            size=mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS),
            time=0,
            qpos=slice(t, t + m.nq),
            qvel=slice(t + m.nq, t + m.nq + m.nv),
        )


def default_threads() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


class Roller:
    """A MuJoCo rollout thread pool with one ``MjData`` per thread, reused across calls.

    Args:
        model: the compiled model.
        threads: rollout threads (None: every available core).
        winches: the model's winch plant (it sets ``tendon_lengthspring`` of ``model``
            each step); with it, :meth:`run` steps in one thread, in Python.
    """

    def __init__(
        self, model: mujoco.MjModel, threads: int | None = None, winches: MjWinches | None = None
    ) -> None:
        self.model = model
        self.winches = winches
        self.threads = 1 if winches is not None else threads or default_threads()
        self.layout = StateLayout.of(model)
        self.seconds = 0.0  # wall time spent inside MuJoCo's rollout
        self._pool = mj_rollout.Rollout(nthread=self.threads)
        self._datas = [mujoco.MjData(model) for _ in range(self.threads)]

    def __enter__(self) -> Roller:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._pool.close()

    def initial_states(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """``mjSTATE_FULLPHYSICS`` vectors (n, nstate) at time 0 from qpos (n, nq), qvel (n, nv)."""
        m, layout = self.model, self.layout
        template = np.empty(layout.size)
        mujoco.mj_getState(m, mujoco.MjData(m), template, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        out = np.tile(template, (qpos.shape[0], 1))
        out[:, layout.qpos], out[:, layout.qvel] = qpos, qvel
        return out

    def run(self, init: np.ndarray, ctrl: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """States after steps 1..T, (n, T, nstate), from initial states (n, nstate).

        ``ctrl`` is (n, T, nu), followed by the W winch commands (n, T, nu + W) with
        winches (each trajectory starts with its winches at rest); ``out``, if given,
        must be C-contiguous (n, T, nstate). Warm starts are reset to zero for every
        trajectory, so a trajectory does not depend on which thread ran it before.
        """
        n, steps = ctrl.shape[:2]
        if out is None:
            out = np.empty((n, steps, self.layout.size))
        t0 = time.perf_counter()
        if self.winches is not None:
            self._run_winches(init, ctrl, out)
            self.seconds += time.perf_counter() - t0
            return out
        state, _ = self._pool.rollout(
            self.model,
            self._datas,
            np.ascontiguousarray(init),
            np.ascontiguousarray(ctrl),
            control_spec=mujoco.mjtState.mjSTATE_CTRL.value,
            nstep=steps,
            initial_warmstart=np.zeros((n, self.model.nv)),
            state=out,
        )
        self.seconds += time.perf_counter() - t0
        return state

    def _run_winches(self, init: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        """:meth:`run` one ``mj_step`` at a time, the winches winding between steps."""
        assert self.winches is not None
        m, d, nu = self.model, self._datas[0], self.model.nu
        full = mujoco.mjtState.mjSTATE_FULLPHYSICS
        rest = self.winches.plan(ctrl[..., nu:])  # (n, T, W): winding needs the commands only
        for i in range(init.shape[0]):
            mujoco.mj_resetData(m, d)
            mujoco.mj_setState(m, d, np.ascontiguousarray(init[i]), full)
            for t in range(ctrl.shape[1]):
                d.ctrl[:] = ctrl[i, t, :nu]
                self.winches.apply(rest[i, t])
                mujoco.mj_step(m, d)
                mujoco.mj_getState(m, d, out[i, t], full)

    def check(self, states: np.ndarray, first: int = 0, where: str = "") -> None:
        """Raise :class:`InputError` if a trajectory diverged.

        MuJoCo resets a diverging simulation to ``qpos0`` at time 0 and carries on, so
        the time column is the tell-tale; non-finite values are caught too.
        """
        dt = float(self.model.opt.timestep)
        expected = dt * np.arange(1, states.shape[1] + 1)
        bad = ~np.all(np.abs(states[:, :, self.layout.time] - expected) < 0.5 * dt, axis=1)
        bad |= ~np.all(np.isfinite(states), axis=(1, 2))
        if bad.any():
            i = first + int(np.argmax(bad))
            raise InputError(
                f"{where}: trajectory {i} diverged (MuJoCo reset or non-finite state); "
                "the model or the initial velocities are too violent for its time step"
            )


# ---------------------------------------------------------------------- frames
Vec = tuple[Any, Any, Any]


def _rotation_columns(q: np.ndarray) -> tuple[Vec, Vec, Vec]:
    """Columns of R(q) as component arrays, for quaternions q (..., 4) (w, x, y, z).

    The same matrix as :func:`tensegrity_env.rotations.quat_to_matrix`, without
    materialising (..., 3, 3) arrays.
    """
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    ww, xx, yy, zz = w * w, x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    return (
        (ww + xx - yy - zz, 2 * (xy + wz), 2 * (xz - wy)),
        (2 * (xy - wz), ww - xx + yy - zz, 2 * (yz + wx)),
        (2 * (xz + wy), 2 * (yz - wx), ww - xx - yy + zz),
    )


def _apply(cols: tuple[Vec, Vec, Vec], v: np.ndarray, out: np.ndarray, base: Any = None) -> None:
    """``out = base + R v`` (``base`` optional) with R given by its columns.

    ``v`` is (..., 3) or a constant (R, 3) per rod; components that are zero for
    every rod are skipped.
    """
    per_rod = v.ndim == 2
    terms = [j for j in range(3) if not (per_rod and not np.any(v[:, j]))]
    for i in range(3):
        acc = out[..., i]
        if base is not None:
            acc[...] = base[..., i]
        else:
            acc[...] = 0.0
        for j in terms:
            acc += cols[j][i] * v[..., j]


class RodFrames:
    """Rod states and end caps from MuJoCo free-joint coordinates, for one model.

    Args:
        asm: the model read by :func:`tensegrity_env.mjcf.from_mjcf`.
    """

    def __init__(self, asm: MjcfAssembly) -> None:
        R = asm.topology.n_rods
        self.n_rods = R
        self.qpos_idx = asm.rod_qpos[:, None] + np.arange(7)  # (R, 7)
        self.qvel_idx = asm.rod_qvel[:, None] + np.arange(6)  # (R, 6)
        # free joints of rods in order, nothing else: cheap reshapes instead of gathers
        self.contiguous = bool(
            np.array_equal(self.qpos_idx.ravel(), np.arange(7 * R))
            and np.array_equal(self.qvel_idx.ravel(), np.arange(6 * R))
        )
        self.ipos = np.asarray(asm.body_ipos, dtype=float)  # (R, 3)
        self.iquat = np.asarray(asm.body_iquat, dtype=float)  # (R, 4)
        self.trivial = bool(
            np.all(self.ipos == 0) and np.all(self.iquat == np.array([1.0, 0.0, 0.0, 0.0]))
        )
        # end caps in the body frame: ipos + R(iquat) e
        ends = asm.topology.end_offsets  # (R, 2, 3), principal frame
        self.ends_body = self.ipos[:, None] + np.einsum(
            "rij,rkj->rki", np_quat_to_matrix(self.iquat), ends
        )

    def split(self, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-rod free-joint coordinates: (..., R, 7) and (..., R, 6)."""
        lead, R = qpos.shape[:-1], self.n_rods
        if self.contiguous:
            return qpos.reshape(*lead, R, 7), qvel.reshape(*lead, R, 6)
        return qpos[..., self.qpos_idx], qvel[..., self.qvel_idx]

    def convert(
        self, qpos: np.ndarray, qvel: np.ndarray, out: dict[str, np.ndarray] | None = None
    ) -> dict[str, np.ndarray]:
        """p, v, omega (..., R, 3), q (..., R, 4), nodes (..., 2R, 3) from qpos, qvel.

        Same conventions as :func:`tensegrity_env.mujoco_state.mj_to_rod_state`. With
        ``out``, results are written into those arrays (shapes as returned).
        """
        jp, jv = self.split(qpos, qvel)
        lead, R = jp.shape[:-2], self.n_rods
        if out is None:
            out = {k: np.empty((*lead, R, 3)) for k in ("p", "v", "omega")}
            out["q"] = np.empty((*lead, R, 4))
            out["nodes"] = np.empty((*lead, 2 * R, 3))
        pos, quat, vel, w_body = jp[..., :3], jp[..., 3:], jv[..., :3], jv[..., 3:]
        cols = _rotation_columns(quat)  # R of the body frame
        _apply(cols, w_body, out["omega"])  # body-frame angular velocity -> world
        if self.trivial:
            out["p"][...] = pos
            out["q"][...] = quat
            out["v"][...] = vel
        else:
            ipos_w = np.empty(pos.shape)
            _apply(cols, self.ipos, ipos_w)
            np.add(pos, ipos_w, out=out["p"])
            out["q"][...] = np_quat_mul(quat, np.broadcast_to(self.iquat, quat.shape))
            np.add(vel, np.cross(out["omega"], ipos_w), out=out["v"])
        for k in range(2):  # rod r owns nodes 2r and 2r + 1
            _apply(cols, self.ends_body[:, k], out["nodes"][..., k::2, :], base=pos)
        return out


# ---------------------------------------------------------------------- pipeline
#: Trajectories converted per task: small enough to stay in cache.
CONVERT_BLOCK = 4


def roll_and_convert(
    roller: Roller,
    frames: RodFrames,
    init: np.ndarray,
    controls: Callable[[int, int], np.ndarray],
    out: dict[str, np.ndarray],
    chunk: int | None = None,
    done: Callable[[int], None] | None = None,
    where: str = "",
) -> None:
    """Roll out ``n`` trajectories and write their rod states and end caps into ``out``.

    A pipeline: MuJoCo rolls out chunk ``i + 1`` (its threads release the GIL)
    while a pool of as many threads converts chunk ``i`` in cache-sized blocks
    (numpy releases the GIL too), so the conversion hides behind the simulation
    on any number of cores; each output block is first written (and its memory
    first touched) by the worker that converts it.

    Args:
        roller: the MuJoCo rollout pool.
        frames: the converter of the same model.
        init: initial ``mjSTATE_FULLPHYSICS`` states, (n, nstate).
        controls: ``controls(lo, hi)`` gives the MuJoCo controls of trajectories
            ``lo..hi-1``, (hi - lo, T, nu); built a chunk at a time.
        out: ``p, v, omega`` (n, T+1, R, 3), ``q`` (n, T+1, R, 4), ``nodes``
            (n, T+1, 2R, 3), filled for samples 0..T.
        chunk: trajectories per rollout call (None: 8 per thread, at least 32).
        done: called with the number of trajectories finished, as they finish.
        where: label for error messages.
    """
    n, steps = init.shape[0], out["p"].shape[1] - 1
    layout = roller.layout
    chunk = chunk or max(32, 8 * roller.threads)
    bounds = [(lo, min(n, lo + chunk)) for lo in range(0, n, chunk)]
    bufs = [np.empty((min(chunk, n), steps, layout.size)) for _ in bounds[:2]]

    def launch(i: int) -> Future[np.ndarray]:
        lo, hi = bounds[i]
        ctrl = controls(lo, hi)
        return sim.submit(roller.run, init[lo:hi], ctrl, bufs[i % 2][: hi - lo])

    def convert(states: np.ndarray, lo: int) -> None:
        hi = lo + states.shape[0]
        first = init[lo:hi]
        frames.convert(
            first[:, layout.qpos], first[:, layout.qvel], {k: a[lo:hi, 0] for k, a in out.items()}
        )
        frames.convert(
            states[..., layout.qpos],
            states[..., layout.qvel],
            {k: a[lo:hi, 1:] for k, a in out.items()},
        )

    def finish(tasks: list[Future[None]], count: int) -> None:
        for t in tasks:
            t.result()
        if done is not None and count:
            done(count)

    with (
        ThreadPoolExecutor(max_workers=1) as sim,
        ThreadPoolExecutor(max_workers=roller.threads) as work,
    ):
        pending, count = launch(0), 0
        converting: list[Future[None]] = []
        for i, (lo, hi) in enumerate(bounds):
            states = pending.result()
            finish(converting, count)  # frees the buffer the next rollout writes
            if i + 1 < len(bounds):
                pending = launch(i + 1)
            roller.check(states, first=lo, where=where)
            converting = [
                work.submit(convert, states[b : b + CONVERT_BLOCK], lo + b)
                for b in range(0, hi - lo, CONVERT_BLOCK)
            ]
            count = hi - lo
        finish(converting, count)
