"""Identification from noisy end caps: smoothing + regression, then trajectory fits.

Most MuJoCo trajectories are generated here directly (free-floating icosahedron or the
hanging element, random initial velocities and position perturbations, no control);
one test uses the dataset generator's small preset.

Reproduce the numbers: ``pytest tests/accuracy/test_noisy.py`` (about 1 min) and
``pytest tests/accuracy/test_noisy.py -m slow`` (about 4 min).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from identification.data.dataset import Dataset, Split
from identification.data.end_caps import RodAxes
from identification.linear.smoothed import parse_anchors
from identification.simulation.generate import GenerateSpec, InitialConditions, generate_dataset
from identification.simulation.planted import add_measurement_noise
from identification.trajectory.identifier import TrajectoryIdentifier
from identification.trajectory.windowed_fit import linearize
from identification.trajectory.windows import cut_windows, local_basis, window_schedule
from tensegrity_env.assemblies import Assembly, element, icosahedron
from tensegrity_env.engine import Engine
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import SimOptions, from_mjcf, to_mjcf
from tensegrity_env.mujoco_state import mj_to_rod_state
from tensegrity_env.params import Params
from tensegrity_env.rotations import np_quat_to_matrix


def simulate(
    asm: Assembly, n: int, steps: int, seed: int = 0, speed: float = 0.5, tumble: float = 1.5,
    position: float = 0.02,
) -> Dataset:  # fmt: skip
    """``n`` MuJoCo trajectories of ``steps`` steps from randomly perturbed nominal poses.

    Each rod gets a position perturbation of std ``position`` [m] per axis, a random
    linear velocity of rms ``speed`` [m/s] and angular velocity of rms ``tumble``
    [rad/s] (a random direction, so with some spin about the rod axis).
    """
    xml = to_mjcf(asm.topology, asm.params, SimOptions(control=False), asm.pose_p, asm.pose_q)
    mj = from_mjcf("<memory>", xml=xml)
    m, d = mj.model, mujoco.MjData(mj.model)
    rng = np.random.default_rng(seed)
    R = asm.topology.n_rods
    qpos, qvel = np.zeros((n, steps + 1, m.nq)), np.zeros((n, steps + 1, m.nv))
    for i in range(n):
        mujoco.mj_resetData(m, d)
        for r in range(R):
            a, b = mj.rod_qpos[r], mj.rod_qvel[r]
            d.qpos[a : a + 3] += position * rng.standard_normal(3)
            d.qvel[b : b + 3] = speed / np.sqrt(3) * rng.standard_normal(3)
            d.qvel[b + 3 : b + 6] = tumble / np.sqrt(3) * rng.standard_normal(3)
        for t in range(steps + 1):
            qpos[i, t], qvel[i, t] = d.qpos, d.qvel
            mujoco.mj_step(m, d)
    s = mj_to_rod_state(mj, qpos, qvel)
    rot = np_quat_to_matrix(s["q"])
    ends = s["p"][..., None, :] + np.einsum("ntrij,rkj->ntrki", rot, asm.topology.end_offsets)
    split = Split(
        nodes=ends.reshape(n, steps + 1, 2 * R, 3), control=np.zeros((n, steps, R, 3)), **s
    )
    return Dataset(asm.topology, float(m.opt.timestep), {"train": split})


def max_errors(fit: Params, truth: Params) -> dict[str, float]:
    """Largest relative error per group; rod 0's mass is the anchor, axial inertia is not
    identifiable from end caps and left out."""
    e = fit.relative_error(truth)
    return {
        "stiffness": float(e["stiffness"].max()),
        "damping": float(e["damping"].max()),
        "rest_length": float(e["rest_length"].max()),
        "mass": float(e["mass"][1:].max()) if len(e["mass"]) > 1 else 0.0,
        "inertia_perp": float(e["inertia"][:, :2].max()),
    }


def anchor_of(asm: Assembly) -> dict[str, float]:
    return {"mass[rod0]": float(asm.params.mass[0])}


def z_scores(est: TrajectoryIdentifier, truth: Params) -> np.ndarray:
    """(log estimate - log truth) / reported standard error of every fitted parameter."""
    vec = est.vector_
    axes = vec.axes.axis

    def full(p: Params) -> np.ndarray:
        P = p.numpy()
        perp = P["inertia"][np.arange(len(axes)), (axes + 1) % 3]
        groups = (P["stiffness"], P["damping"], P["rest_length"], P["mass"], perp)
        return np.log(np.concatenate([*groups, [P["control_gain"]]]))

    diff = (full(est.params_) - full(truth))[vec.free.numpy()]
    return diff / np.array(list(est.stderr_.values()))


# ---------------------------------------------------------------------- small pieces
def test_noise_copy_drops_states_and_is_seeded() -> None:
    asm = element()
    ds = simulate(asm, n=1, steps=20)
    noisy = add_measurement_noise(ds, std=1e-3, seed=3)
    split = noisy.split("train")
    assert not split.has_states and split.p is None and split.q is None
    resid = split.nodes - ds.split("train").nodes
    assert 0.5e-3 < resid.std() < 1.5e-3
    again = add_measurement_noise(ds, std=1e-3, seed=3).split("train").nodes
    np.testing.assert_array_equal(again, split.nodes)
    assert ds.split("train").has_states  # the original is untouched


def test_anchor_names_and_schedule() -> None:
    topo = icosahedron().topology
    assert parse_anchors(topo, {"mass[rod2]": 2.0, "inertia[rod1,x]": 0.2}) == {
        ("mass", 2): 2.0,
        ("inertia_perp", 1): 0.2,
    }
    with pytest.raises(InputError, match="unknown anchor"):
        parse_anchors(topo, {"mass[rod9]": 1.0})
    with pytest.raises(InputError, match="positive"):
        parse_anchors(topo, {"stiffness[spring0]": -1.0})
    assert window_schedule(100, 1000) == [100, 316, 1000]
    assert window_schedule(100, 60) == [60]


def test_finite_difference_gradient_matches_autograd() -> None:
    """The forward-difference ``Jᵀr`` equals the reverse-mode gradient through the engine."""
    asm = icosahedron()
    clean = simulate(asm, n=1, steps=40, seed=4)
    data = add_measurement_noise(clean, std=1e-3, seed=1).split("train")
    truth = clean.split("train")
    grid = {k: getattr(truth, k) for k in ("p", "v", "q", "omega")}
    windows = cut_windows(data.nodes, data.control, grid, 20)
    axes = RodAxes.of(asm.topology)
    est = TrajectoryIdentifier(anchors=anchor_of(asm))
    P = asm.params.numpy()
    start = {
        "stiffness": 1.05 * P["stiffness"], "damping": 0.9 * P["damping"],
        "rest_length": P["rest_length"], "mass": P["mass"],
        "inertia_perp": P["inertia"][:, 0], "control_gain": np.ones(1),
    }  # fmt: skip
    vec = est.start_vector(asm.topology, axes, start, {("mass", 0): float(P["mass"][0])}, False)
    engine, basis = Engine(asm.topology, clean.dt), local_basis(axes)
    theta = vec.start[vec.free]
    fd = linearize(engine, vec, windows, basis, theta, chunk=8)
    ad = linearize(engine, vec, windows, basis, theta, chunk=8, exact_gradient=True)
    for a, b in ((fd.g_g, ad.g_g), (fd.g_l, ad.g_l)):
        assert float((a - b).abs().max()) < 1e-5 * float(b.abs().max())
    assert fd.sse == pytest.approx(ad.sse, rel=1e-12)


# ---------------------------------------------------------------------- identification
def test_clean_end_caps_icosahedron() -> None:
    """Noise-free end caps: the same pipeline recovers every parameter to round-off."""
    asm = icosahedron()
    clean = add_measurement_noise(simulate(asm, n=1, steps=300, seed=1), std=0.0)
    est = TrajectoryIdentifier(anchors=anchor_of(asm), window=300).fit(clean)
    errors = max_errors(est.params_, asm.params)
    assert max(errors.values()) < 1e-6, errors
    assert est.rms_ < 1e-9
    assert est.mode_ == "anchored" and est.spin_fitted_ and est.converged_
    axial = [name for name in est.notes_ if name.startswith("inertia[")]
    assert axial == [f"inertia[rod{r},z]" for r in range(6)]


def test_clean_element_without_anchor_gives_ratios() -> None:
    """No anchor: everything is identified relative to the first rod's mass."""
    asm = element()
    clean = add_measurement_noise(simulate(asm, n=2, steps=300, seed=3), std=0.0)
    est = TrajectoryIdentifier(window=300, max_iter=12).fit(clean)
    assert est.mode_ == "ratios"
    m = float(asm.params.mass[0])
    got, want = est.params_.numpy(), asm.params.numpy()
    np.testing.assert_allclose(got["stiffness"], want["stiffness"] / m, rtol=1e-6)
    np.testing.assert_allclose(got["damping"], want["damping"] / m, rtol=1e-6)
    np.testing.assert_allclose(got["rest_length"], want["rest_length"], rtol=1e-6)
    np.testing.assert_allclose(got["inertia"][0, :2], want["inertia"][0, :2] / m, rtol=1e-6)


def test_noisy_element() -> None:
    """The one-rod element with 1 mm noise: K, c, I_perp within 2 %."""
    asm = element()
    noisy = add_measurement_noise(simulate(asm, n=4, steps=1000, seed=2), std=1e-3, seed=5)
    est = TrajectoryIdentifier(anchors=anchor_of(asm), window=1000).fit(noisy)
    errors = max_errors(est.params_, asm.params)
    assert max(errors.values()) < 0.02, errors
    assert 0.95e-3 < est.rms_ < 1.05e-3  # the fit explains everything but the noise
    assert np.abs(z_scores(est, asm.params)).max() < 4


def test_noisy_icosahedron() -> None:
    """The generator's small preset (16 trajectories of 0.3 s) with 1 mm noise.

    Every K, c, M, I_perp comes out within 2 %, and every estimate lies within 4
    reported standard errors of the truth (the uncertainty is honest).
    """
    initial = InitialConditions(
        rotate=True, position_std=0.02, rotation_std=0.05, speed=(0.3, 1.0),
        tumble=(1.0, 3.0), spin=2.0,
    )  # fmt: skip
    spec = GenerateSpec(n_train=16, n_val=0, n_test=0, steps=300, initial=initial, threads=1)
    data, truth = generate_dataset(spec)
    noisy = add_measurement_noise(data, std=1e-3, seed=7)
    anchor = {"mass[rod0]": float(truth.params.mass[0])}
    est = TrajectoryIdentifier(anchors=anchor, window=300).fit(noisy)
    errors = max_errors(est.params_, truth.params)
    assert max(errors.values()) < 0.02, errors
    first = max_errors(est.initial_params_, truth.params)
    assert all(errors[g] < first[g] for g in errors)  # the trajectory fit beats stage 1
    assert np.abs(z_scores(est, truth.params)).max() < 4
    assert 0.95e-3 < est.rms_ < 1.05e-3


@pytest.mark.slow
def test_noisy_icosahedron_long_windows() -> None:
    """Gentler excitation (0.5 m/s, 1.5 rad/s), 1 mm noise, four 2 s trajectories fitted
    as whole windows: every K, c, M, I_perp within 2 % (about 4 min)."""
    asm = icosahedron()
    noisy = add_measurement_noise(simulate(asm, n=4, steps=2000, seed=0), std=1e-3, seed=100)
    est = TrajectoryIdentifier(anchors=anchor_of(asm), window=2000).fit(noisy)
    errors = max_errors(est.params_, asm.params)
    assert max(errors.values()) < 0.02, errors
    assert np.abs(z_scores(est, asm.params)).max() < 4
