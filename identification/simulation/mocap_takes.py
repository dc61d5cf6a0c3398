"""Motion-capture takes of a MuJoCo model, as a lab's system would record them.

Runs an MJCF model (free joints, end-cap sites ``<rod>_end0/1``) from random initial
velocities and spins, samples the end-cap sites at a capture rate, adds Gaussian
marker noise and random dropouts (a lost marker stays lost for a few frames), and, for
an unlabelled export, gives every reappearance of a marker a new track id, shuffles
the columns and adds ghost points (reflections) far from any end cap.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np


@dataclass(frozen=True)
class Take:
    """One take. ``time`` (F,) [s]; ``caps`` (F, 2R, 3) [m] clean end caps; ``points``
    (F, M, 3) [m] what the file holds (noise, NaN dropouts, tracks); ``names`` (M,);
    ``cap_of_track`` (M,) the true end cap of each track, -1 for ghosts."""

    time: np.ndarray
    caps: np.ndarray
    points: np.ndarray
    names: list[str]
    cap_of_track: np.ndarray


def simulate_caps(
    xml: str, rate: float, duration: float, rng: np.random.Generator, physics_dt: float = 1e-3,
    speed: float = 0.5, spin: float = 1.5,
    commands: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, list[str]]:  # fmt: skip
    """Clean end caps (F, 2R, 3) [m] at ``rate`` [Hz], their times and site names.

    ``commands``: the actuators' log, times (K,) [s] and values (K, C); each physics
    step applies the last command at or before its start (a motor controller's hold).
    """
    model = mujoco.MjModel.from_xml_string(xml)
    sub = max(1, round(1.0 / (rate * physics_dt)))
    model.opt.timestep = 1.0 / (rate * sub)
    data = mujoco.MjData(model)
    sites = [
        i for i in range(model.nsite)
        if mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SITE, i).rsplit("_", 1)[-1] in ("end0", "end1")
    ]  # fmt: skip
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SITE, i) for i in sites]
    for j in range(model.njnt):
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            a = model.jnt_dofadr[j]
            data.qvel[a : a + 3] = rng.normal(0, speed / np.sqrt(3), 3)
            data.qvel[a + 3 : a + 6] = rng.normal(0, spin / np.sqrt(3), 3)
    n = round(duration * rate) + 1
    caps = np.empty((n, len(sites), 3))
    for f in range(n):
        mujoco.mj_forward(model, data)
        caps[f] = data.site_xpos[sites]
        if commands is None:
            mujoco.mj_step(model, data, nstep=sub)
            continue
        for j in range(sub):
            t = (f * sub + j) * model.opt.timestep
            k = int(np.searchsorted(commands[0], t + 1e-9, side="right")) - 1
            data.ctrl[:] = commands[1][k] if k >= 0 else 0.0
            mujoco.mj_step(model, data)
    return np.arange(n) / rate, caps, names


def record_take(
    time: np.ndarray, caps: np.ndarray, names: list[str], rng: np.random.Generator,
    noise: float = 1e-3, dropout: float = 0.0, unlabelled: bool = False, ghosts: float = 0.0,
    gap_frames: tuple[int, int] = (1, 6),
) -> Take:  # fmt: skip
    """Noise [m] on every coordinate; a fraction ``dropout`` of samples lost in runs of
    ``gap_frames`` frames; ``unlabelled``: new track id per reappearance, shuffled
    columns and ``ghosts`` ghost points per frame on average."""
    F, C, _ = caps.shape
    seen = np.ones((F, C), bool)
    if dropout > 0:
        mean_run = 0.5 * (gap_frames[0] + gap_frames[1])
        starts = rng.random((F, C)) < dropout / mean_run
        for f, c in zip(*np.nonzero(starts), strict=True):
            seen[f : f + rng.integers(gap_frames[0], gap_frames[1] + 1), c] = False
        seen[0] = True  # the take starts with every marker in view
    noisy = caps + rng.normal(0, noise, caps.shape)
    if not unlabelled:
        pts = np.where(seen[..., None], noisy, np.nan)
        return Take(time, caps, pts, list(names), np.arange(C))
    columns: list[np.ndarray] = []
    owner: list[int] = []
    for c in range(C):
        run = np.flatnonzero(np.diff(np.r_[0, seen[:, c].astype(int)]) == 1)
        ends = np.flatnonzero(np.diff(np.r_[seen[:, c].astype(int), 0]) == -1)
        for a, b in zip(run, ends, strict=True):
            col = np.full((F, 3), np.nan)
            col[a : b + 1] = noisy[a : b + 1, c]
            columns.append(col)
            owner.append(c)
    if ghosts > 0:
        lo, hi = caps.reshape(-1, 3).min(0) - 0.5, caps.reshape(-1, 3).max(0) + 0.5
        for f in np.flatnonzero(rng.random(F) < ghosts):
            col = np.full((F, 3), np.nan)
            for _ in range(20):  # a reflection away from every end cap
                x = rng.uniform(lo, hi)
                if np.linalg.norm(caps[f] - x, axis=-1).min() > 0.15:
                    col[f] = x
                    break
            columns.append(col)
            owner.append(-1)
    order = rng.permutation(len(columns))
    pts = np.stack([columns[i] for i in order], axis=1)
    ids = [f"Unlabeled {1000 + k}" for k in range(len(order))]
    return Take(time, caps, pts, ids, np.array([owner[i] for i in order]))
