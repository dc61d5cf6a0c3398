"""Dataset generation: seeded, MuJoCo-exact, exciting the springs, end caps consistent."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import h5py
import mujoco
import numpy as np
import pytest

import identification.simulation.generate as gen
from identification.data.dataset import SPLITS, STATE_KEYS, Dataset, GroundTruth, read_dataset
from identification.data.end_caps import rod_states_from_nodes
from identification.simulation.generate import GenerateSpec, generate, generate_dataset
from identification.simulation.rollout import RodFrames
from identification.simulation.truth import load_truth
from tensegrity_env.assemblies import node_positions
from tensegrity_env.mujoco_state import mj_to_rod_state, rod_state_to_mj
from tensegrity_env.rotations import np_quat_to_matrix
from tensegrity_sr.cli import main

EXAMPLE_MJCF = Path(__file__).resolve().parents[2] / "docs" / "examples" / "x_tensegrity.xml"
ARRAYS = ("nodes", "control", *STATE_KEYS)


@cache
def _data(**kw) -> tuple[Dataset, GroundTruth]:
    base = {"n_train": 4, "n_val": 2, "n_test": 2, "steps": 250, "seed": 3}
    return generate_dataset(GenerateSpec(**{**base, **kw}))


def _same(a: Dataset, b: Dataset) -> bool:
    return set(a.splits) == set(b.splits) and all(
        np.array_equal(getattr(a.splits[s], k), getattr(b.splits[s], k))
        for s in a.splits
        for k in ARRAYS
    )


def test_same_seed_gives_bit_identical_data_whatever_the_threads_and_chunks() -> None:
    a, _ = _data(control_std=1.0)
    b, _ = _data(control_std=1.0, threads=1, chunk=1)
    assert _same(a, b)
    c, _ = _data(control_std=1.0, seed=4)
    assert not np.array_equal(a.splits["train"].p, c.splits["train"].p)


def test_splits_are_independent_streams() -> None:
    a, _ = _data()
    b, _ = _data(n_train=6)
    for s in ("val", "test"):
        assert np.array_equal(a.splits[s].nodes, b.splits[s].nodes)


def test_same_seed_gives_identical_files(tmp_path: Path) -> None:
    argv = ["generate", "--n-train", "2", "--n-val", "1", "--n-test", "0", "--steps", "30"]
    for name in ("a.h5", "b.h5"):
        assert main([*argv, "--no-progress", "-o", str(tmp_path / name)]) == 0
    with h5py.File(tmp_path / "a.h5") as fa, h5py.File(tmp_path / "b.h5") as fb:
        assert {k: v for k, v in fa.attrs.items() if k != "created"} == {
            k: v for k, v in fb.attrs.items() if k != "created"
        }
        names: list[str] = []
        fa.visit(names.append)
        for name in names:
            if isinstance(fa[name], h5py.Dataset):
                assert np.array_equal(fa[name][()], fb[name][()]), name
            assert dict(fa[name].attrs) == dict(fb[name].attrs), name


def test_shapes_of_splits() -> None:
    ds, _ = _data()
    R = 6
    for name, n in zip(SPLITS, (4, 2, 2), strict=True):
        s = ds.splits[name]
        assert s.nodes.shape == (n, 251, 2 * R, 3)
        assert s.control.shape == (n, 250, R, 3)
        assert s.p.shape == s.v.shape == s.omega.shape == (n, 251, R, 3)
        assert s.q.shape == (n, 251, R, 4)
    assert ds.dt == 1e-3
    assert ds.n_steps == 8 * 250
    assert ds.attrs["assembly"] == "icosahedron" and ds.attrs["seed"] == 3


def _spring_lengths(ds: Dataset, nodes: np.ndarray) -> np.ndarray:
    topo = ds.topology
    anchors = np.broadcast_to(topo.anchor_positions, (*nodes.shape[:-2], topo.n_anchors, 3))
    x = np.concatenate([nodes, anchors], axis=-2)
    sn = topo.spring_nodes
    return np.linalg.norm(x[..., sn[:, 1], :] - x[..., sn[:, 0], :], axis=-1)


@pytest.mark.parametrize("assembly", ["icosahedron", "element"])
def test_springs_are_excited_but_not_violently(assembly: str) -> None:
    ds, _ = _data(assembly=assembly)
    # the element's springs carry its weight: nominal length is 1.25 x rest, not 1 x
    t = load_truth(GenerateSpec(assembly=assembly))
    caps = node_positions(ds.topology, t.pose_p, t.pose_q)[: 2 * ds.topology.n_rods]
    nominal = _spring_lengths(ds, caps)
    for s in ds.splits.values():
        lengths = _spring_lengths(ds, s.nodes)  # (N, T+1, S)
        std = lengths.std(axis=1)  # over time
        assert np.all(std.max(axis=1) > 5e-3)  # every trajectory moves some spring by mm
        assert np.median(std) > 3e-3
        assert np.all((lengths > 0.5 * nominal) & (lengths < 1.5 * nominal))
        assert np.all(np.isfinite(s.p)) and np.all(np.isfinite(s.omega))
        # initial states are randomized: rods move and spin from the start
        speed = np.linalg.norm(s.v[:, 0], axis=-1)
        assert np.all((speed > 0.2) & (speed < 1.1))
        axis = np_quat_to_matrix(s.q[:, 0])[..., :, 2]
        spin = np.abs(np.sum(s.omega[:, 0] * axis, axis=-1))
        assert spin.max() > 0.5


def _ctrl(asm, commands: np.ndarray) -> np.ndarray:
    ctrl = np.zeros(asm.model.nu)
    has = asm.actuators >= 0
    ctrl[asm.actuators[has]] = commands[has]
    return ctrl


@pytest.mark.parametrize(
    "kw", [{"control_std": 1.0}, {"assembly": "element", "control_std": 1.0}, {"mjcf": "example"}]
)
def test_next_state_is_one_mujoco_step_from_the_stored_state(kw: dict) -> None:
    kw = {**kw, "mjcf": str(EXAMPLE_MJCF)} if "mjcf" in kw else kw
    spec = GenerateSpec(n_train=2, n_val=0, n_test=0, steps=120, seed=1, **kw)
    ds, _ = generate_dataset(spec)
    asm = load_truth(spec).asm
    s = ds.splits["train"]
    m = asm.model
    d = mujoco.MjData(m)
    for i, t in [(0, 0), (1, 37), (0, 119)]:
        qpos, qvel = rod_state_to_mj(asm, s.p[i, t], s.v[i, t], s.q[i, t], s.omega[i, t])
        d.qpos[:], d.qvel[:] = qpos, qvel
        d.ctrl[:] = _ctrl(asm, s.control[i, t])
        mujoco.mj_step(m, d)
        nxt = mj_to_rod_state(asm, d.qpos.copy(), d.qvel.copy())
        for k in STATE_KEYS:
            np.testing.assert_allclose(nxt[k], getattr(s, k)[i, t + 1], rtol=0, atol=1e-12)
        # end caps are the rods' end offsets placed by (p, q)
        nodes = node_positions(ds.topology, s.p[i, t], s.q[i, t])[: 2 * ds.topology.n_rods]
        np.testing.assert_allclose(s.nodes[i, t], nodes, rtol=0, atol=1e-14)


def test_fast_frame_conversion_matches_the_reference() -> None:
    # the example's struts have principal frames that are not their body frames
    asm = load_truth(GenerateSpec(mjcf=str(EXAMPLE_MJCF))).asm
    rng = np.random.default_rng(0)
    q = rng.normal(size=(5, 2, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    qpos = np.concatenate([rng.normal(size=(5, 2, 3)), q], axis=-1).reshape(5, 14)
    qvel = rng.normal(size=(5, 12))
    fast = RodFrames(asm).convert(qpos, qvel)
    ref = mj_to_rod_state(asm, qpos, qvel)
    for k in STATE_KEYS:
        np.testing.assert_allclose(fast[k], ref[k], rtol=0, atol=1e-14)
    for i in range(5):
        nodes = node_positions(asm.topology, ref["p"][i], ref["q"][i])
        np.testing.assert_allclose(fast["nodes"][i], nodes, rtol=0, atol=1e-14)


def test_control_commands_are_held_piecewise_constant() -> None:
    ds, truth = _data(control_std=1.0)
    u = ds.splits["train"].control  # (N, T, R, 3)
    changes = np.flatnonzero(np.any(u[:, 1:] != u[:, :-1], axis=(0, 2, 3))) + 1
    assert changes.tolist() == [50, 100, 150, 200]
    assert 0.7 < u.std() < 1.3
    assert truth.params.control_gain.item() == 2.5
    quiet, _ = _data()
    assert np.all(quiet.splits["train"].control == 0)


def test_rod_states_from_end_caps_recover_p_v_and_the_axis() -> None:
    ds, _ = _data(control_std=1.0)
    s = ds.splits["train"]
    est = rod_states_from_nodes(s.nodes, ds.topology, ds.dt)
    np.testing.assert_allclose(est["p"], s.p, rtol=0, atol=1e-12)
    # central differences of semi-implicit Euler positions are the mean of two velocities
    mean_v = 0.5 * (s.v[:, 1:-1] + s.v[:, 2:])
    np.testing.assert_allclose(est["v"][:, 1:-1], mean_v, rtol=0, atol=1e-9)
    np.testing.assert_allclose(est["v"], s.v, rtol=0, atol=2e-2)  # ~ dt |a|
    axis_true = np_quat_to_matrix(s.q)[..., :, 2]
    axis_est = np_quat_to_matrix(est["q"])[..., :, 2]
    np.testing.assert_allclose(axis_est, axis_true, rtol=0, atol=1e-12)
    # only the angular velocity perpendicular to the axis is observable
    w_perp = s.omega - np.sum(s.omega * axis_true, -1, keepdims=True) * axis_true
    np.testing.assert_allclose(np.sum(est["omega"] * axis_true, -1), 0, atol=1e-9)
    np.testing.assert_allclose(est["omega"][:, 1:-1], w_perp[:, 1:-1], rtol=0, atol=5e-2)


def test_ground_lifts_the_structure_above_the_floor() -> None:
    ds, truth = _data(ground=True)
    nodes = np.concatenate([s.nodes for s in ds.splits.values()])
    radius = 0.016
    assert np.all(nodes[:, 0, :, 2].min(axis=1) - radius > 0.01)  # starts above
    assert nodes[..., 2].min() < radius  # and lands on the floor within 0.25 s
    assert nodes[..., 2].min() > -radius  # without falling through it
    assert truth.effects and truth.effects[0]["name"] == "ground_contact"
    assert truth.sim["ground"] is True and "floor" in truth.mjcf
    # the element hangs from anchors: anchors and rod are lifted together
    el, _ = _data(assembly="element", ground=True)
    assert np.all(el.topology.anchor_positions[:, 2] > 0.9)
    assert el.splits["train"].nodes[..., 2].min() > 0.2


def test_interrupted_generate_leaves_no_file_and_rerun_finishes(
    tmp_path: Path, monkeypatch
) -> None:
    out = tmp_path / "data.h5"
    argv = ["generate", "--n-train", "2", "--n-val", "2", "--steps", "20", "-o", str(out)]
    real = gen.rollout_split
    calls = []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(gen, "rollout_split", interrupted)
    assert main([*argv, "--no-progress"]) == 130
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(gen, "rollout_split", real)
    assert main([*argv, "--no-progress"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["data.h5"]
    assert read_dataset(out).n_steps == (2 + 2 + 4) * 20


def test_generate_reports_a_summary(tmp_path: Path, capsys) -> None:
    out = tmp_path / "x.h5"
    assert main(["generate", "--mjcf", str(EXAMPLE_MJCF), "--steps", "50", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"Wrote {out}: x_tensegrity (2 rods, 4 springs")
    assert "16/4/4 trajectories x 50 steps" in text and "steps/s" in text
    result = generate(GenerateSpec(mjcf=str(EXAMPLE_MJCF), n_train=2, n_val=0, n_test=0))
    assert result.spring_std > 3e-3
    assert result.rollout_seconds <= result.seconds
