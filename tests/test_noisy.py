"""Identification from noisy end caps: smoothing + regression, then trajectory fits.

The MuJoCo trajectories are generated here directly (free-floating icosahedron or the
hanging element, random initial velocities and position perturbations, no control),
so these tests depend only on the engine, the MJCF writer and the identifier.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from identification.dataset import Dataset, Split
from identification.noisy import (
    TrajectoryIdentifier,
    add_measurement_noise,
    parse_anchors,
    window_schedule,
)
from tensegrity_env.assemblies import Assembly, element, icosahedron
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
    split = Split(nodes=ends.reshape(n, steps + 1, 2 * R, 3), control=np.zeros((n, steps, R, 3)), **s)
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


# ---------------------------------------------------------------------- identification
def test_clean_end_caps_icosahedron() -> None:
    """Noise-free end caps: the same pipeline recovers every parameter to round-off."""
    asm = icosahedron()
    clean = add_measurement_noise(simulate(asm, n=2, steps=200, seed=1), std=0.0)
    est = TrajectoryIdentifier(anchors=anchor_of(asm), window=200, max_iter=12).fit(clean)
    errors = max_errors(est.params_, asm.params)
    assert max(errors.values()) < 1e-6, errors
    assert est.rms_ < 1e-9
    assert est.mode_ == "anchored"
    axial = [name for name in est.notes_ if name.startswith("inertia[")]
    assert axial == [f"inertia[rod{r},z]" for r in range(6)]


def test_noisy_element() -> None:
    """The one-rod element with 1 mm noise: K, c, I_perp within 2 %."""
    asm = element()
    noisy = add_measurement_noise(simulate(asm, n=4, steps=1000, seed=2), std=1e-3, seed=5)
    est = TrajectoryIdentifier(anchors=anchor_of(asm), window=1000).fit(noisy)
    errors = max_errors(est.params_, asm.params)
    assert max(errors.values()) < 0.02, errors
    assert 0.9e-3 < est.rms_ < 1.1e-3  # the fit explains everything but the noise
