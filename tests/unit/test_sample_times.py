"""Real sample times: the engine integrates between a take's own (jittered, uneven) times.

A take sampled at its capture times is reproduced by rolling the engine out at those
times (:meth:`~tensegrity_env.engine.Engine.rollout_at`), to within the marker noise;
the same rollout on the uniform grid the median interval suggests misses by far more.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from test_mjcf_lab import mj_rod_state

from tensegrity_env.engine import Engine, State
from tensegrity_env.mjcf import from_mjcf

LAB_PRISM = Path(__file__).resolve().parents[2] / "tensegrity_env" / "assets" / "lab_prism.xml"
#: marker noise added to the simulated end caps [m]
NOISE = 2e-4


@cache
def lab():
    return from_mjcf(LAB_PRISM)


def jittered_times(rng: np.random.Generator) -> np.ndarray:
    """(T + 1,) sample times [s]: median 20 ms apart with 2 ms of jitter, six steps of
    1-3 ms (two messages at once) and one gap of 0.2 s."""
    steps = rng.normal(0.02, 0.002, size=40)
    steps[rng.choice(40, 6, replace=False)] = rng.uniform(0.001, 0.003, size=6)
    steps[25] = 0.2
    return np.concatenate(([0.0], np.cumsum(steps)))


def start_state(asm) -> State:
    """The prism at its file pose, moving: (1, R, ·)."""
    d = mujoco.MjData(asm.model)
    mujoco.mj_forward(asm.model, d)
    s = mj_rod_state(asm, d)
    rng = np.random.default_rng(3)
    v = torch.as_tensor(rng.normal(0, 0.3, size=s.v.shape))
    w = torch.as_tensor(rng.normal(0, 1.0, size=s.omega.shape))
    return State(s.p, v, s.q, w)


def caps(engine: Engine, states: State) -> np.ndarray:
    """End caps (T + 1, 2R, 3) [m] of stacked states (1, T + 1, R, ·)."""
    from tensegrity_env.rotations import quat_to_matrix

    arms = torch.einsum("btrij,rkj->btrki", quat_to_matrix(states.q), engine.end_offsets)
    return (states.p.unsqueeze(3) + arms).reshape(states.p.shape[1], -1, 3).numpy()


def test_advance_by_a_whole_step_is_the_step() -> None:
    """``advance(dt)`` takes the same physics steps as ``step``: equal to round-off."""
    asm = lab()
    engine = Engine(asm.topology, dt=0.01, effects=asm.declared_effects(), substeps=10)
    s0 = start_state(asm)
    u = torch.full((1, 6), 0.7, dtype=torch.float64)
    a = engine.step(s0, asm.params, winches=u)
    b = engine.advance(s0, asm.params, 0.01, winches=u)
    for x, y in zip(a.tensors(), b.tensors(), strict=True):
        assert torch.allclose(x, y, rtol=0, atol=1e-14)
    assert torch.allclose(a.winch, b.winch, rtol=0, atol=1e-15)


def test_each_assembly_advances_by_its_own_interval() -> None:
    """A batch of two with intervals 4 ms and 7 ms and a 1 ms physics step: both take 7
    steps, each of its own interval / 7, ending on its own time."""
    asm = lab()
    engine = Engine(asm.topology, dt=0.001, effects=asm.declared_effects())
    s0 = start_state(asm)
    two = State(*(torch.cat([x, x]) for x in s0.tensors()))
    both = engine.advance(two, asm.params, torch.tensor([0.004, 0.007], dtype=torch.float64))
    for k, iv in enumerate((0.004, 0.007)):
        alone = Engine(asm.topology, dt=iv, effects=asm.declared_effects(), substeps=7)
        one = alone.step(s0, asm.params)
        assert torch.allclose(both.p[k], one.p[0], rtol=0, atol=1e-14)
        assert torch.allclose(both.q[k], one.q[0], rtol=0, atol=1e-14)


def simulated_take(tmp_path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, Path, Path]:
    """The prism in free flight winding its cables, written as a plain CSV at jittered
    times with noise, and its command log. Each sample interval is stepped by an engine
    of its own (``dt`` the interval, physics steps of at most 1 ms): the samples are the
    engine's motion at those times. Returns times (T + 1,), true and measured end caps
    (T + 1, 2R, 3) [m], the CSV and the log."""
    from identification.data.mocap.commands import write_commands
    from tensegrity_env.engine import substeps_for

    asm = lab()
    rng = np.random.default_rng(11)
    t = jittered_times(rng)
    u = rng.uniform(-1, 1, size=(len(t) - 1, 6))
    state = start_state(asm)
    states = [state]
    for k in range(len(t) - 1):
        iv = float(t[k + 1] - t[k])
        engine = Engine(asm.topology, dt=iv, substeps=substeps_for(iv, 1e-3))
        state = engine.step(state, asm.params, winches=torch.as_tensor(u[k])[None])
        states.append(state)
    truth = caps(engine, State.stack(states, dim=1))
    measured = truth + rng.normal(0, NOISE, size=truth.shape)
    names = [f"{r.name}_{k}" for r in asm.topology.rods for k in (0, 1)]
    header = ",".join(["time", *(f"{n}_{a}" for n in names for a in "xyz")])
    rows = [
        ",".join([repr(float(tk)), *(repr(float(x)) for x in m.ravel())])
        for tk, m in zip(t, measured, strict=True)
    ]
    csv = tmp_path / "take.csv"
    csv.write_text("\n".join([header, *rows]) + "\n")
    log = write_commands(tmp_path / "take_commands.csv", t[:-1], u, [f"w{k}" for k in range(6)])
    return t, truth, measured, csv, log


def test_a_take_at_its_own_times_fits_to_the_noise(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A simulated take at jittered times (steps of 1-3 ms among 20 ms ones, a 0.2 s gap)
    through import-mocap with its winch command log: each sample keeps its time, and the
    engine rolled out at those times fits the end caps to the noise; rolled out on the
    uniform grid of the median interval it misses by many noise levels. ``inspect``
    flags the short steps and the gap with their times."""
    from identification.data.dataset import read_dataset
    from tensegrity_sr.cli import main

    t, truth, _, csv, log = simulated_take(tmp_path)
    h5 = tmp_path / "take.h5"
    assert main(["import-mocap", str(csv), "--robot", str(LAB_PRISM), "--units", "m", "--up", "z",
                 "--split", "1,0,0", "--commands", str(log), "-o", str(h5)]) == 0  # fmt: skip
    split = read_dataset(h5).split("train")
    assert split.time is not None and np.allclose(split.time[0], t - t[0], rtol=0, atol=1e-12)
    u = torch.as_tensor(split.winch_control)
    assert u.shape == (1, len(t) - 1, 6)
    asm = lab()
    engine = Engine(asm.topology, dt=1e-3)
    s0 = start_state(asm)
    at_times = caps(engine, engine.rollout_at(s0, asm.params, split.time[0], winches=u))
    grid = np.arange(len(t)) * np.median(np.diff(t))
    on_grid = caps(engine, engine.rollout_at(s0, asm.params, grid, winches=u))

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean((x - split.nodes[0]) ** 2)))

    assert np.abs(at_times - truth).max() < 1e-9
    assert rms(at_times) < 1.2 * NOISE, rms(at_times)
    assert rms(on_grid) > 10 * NOISE, rms(on_grid)
    capsys.readouterr()
    assert main(["inspect", str(h5)]) == 0
    out = capsys.readouterr().out
    short = np.flatnonzero(np.diff(t) < 0.005) + 1
    assert f"{len(short)} steps too short to be capture times" in out
    assert ", ".join(f"{x:.3f}" for x in t[short][:5]) in out
    assert "1 gaps (> 1.5 x the median step" in out and f"at {t[26]:.3f} s" in out


def test_measured_states_come_from_the_samples_own_times(tmp_path: Path) -> None:
    """End caps moving at constant velocity, sampled at uneven times with steps of 1-3 ms
    among them: the local line fits give each cap's velocity and the rods' states
    exactly, where a grid of the median step would not (the 3-bar of
    ``test_bekris_crawl``, its cables between end-cap centres)."""
    import sys

    from test_bekris_crawl import CAPS, lab_take

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from bekris_crawl import LENGTH, convert

    from identification.trajectory.timed import local_linear, states_at_times
    from tensegrity_env.model import Model

    topology = Model.read(convert(lab_take(tmp_path / "lab"), tmp_path / "out").robot).topology
    rng = np.random.default_rng(4)
    t = jittered_times(rng)[:20]
    vel = np.tile(rng.normal(0, 0.2, size=(1, 3)), (6, 1))  # a rigid translation [m/s]
    nodes = CAPS[None] * LENGTH + t[:, None, None] * vel[None]
    pos, v = local_linear(nodes, t, 0.03)
    assert np.allclose(pos, nodes, atol=1e-12) and np.allclose(v, vel[None], atol=1e-10)
    st = states_at_times(nodes, t, topology, 0.03)
    assert np.allclose(st["v"], vel[None, :3], atol=1e-10)
    assert np.allclose(st["omega"], 0.0, atol=1e-10)
    grid = np.arange(len(t)) * np.median(np.diff(t))
    _, v_grid = local_linear(nodes, grid, 0.03)
    assert np.abs(v_grid - vel[None]).max() > 0.1 * np.abs(vel).max()
