"""Residuals where physics lives: what a fitted model cannot explain, per element.

For every transition ``t -> t+1`` the measured rod accelerations (the transition's
own finite differences, exact for MuJoCo's semi-implicit Euler) are compared with
the model's (params + effects) at state ``t``; the difference times mass and
inertia is the **residual wrench** on each rod, the force and torque the model is
missing. It is then read in each element's own 1-D frame:

* **rods**: the residual force along ``-v̂`` (positive: something opposes the
  motion, like drag) against speed, and the residual torque along ``-ω̂`` against
  angular speed;
* **springs**: the residual *tension* of each spring, the (ridge) least-squares split
  of all rods' residual wrenches into tensions along the spring axes, against the
  spring's stretch ``l - l0`` (a slack cable shows ``ΔT = -K (l - l0)`` for
  ``l < l0`` and nothing above; a cubic spring ``ΔT ∝ (l - l0)^3``);
* **end caps**: the residual force of each rod split onto its two end caps
  (minimum-norm), vertical part against the cap's height above the floor
  ``z - r`` and horizontal part against its slip speed (contact lives at
  ``z - r <= 0``);
* **control**: the residual force against the applied command ``h f_u``;
* **time**: the residual size against time along each trajectory.

:func:`summarize` turns these into a few numbers, one per physical signature, and
:func:`plot_residuals` into one PNG.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from identification.data.dataset import Dataset
from identification.linear.extended import acting_split
from identification.linear.features import (
    cable_commands_at,
    drawn_transitions,
    transition_features,
    transitions_of,
)
from identification.report.plots import save_figure
from tensegrity_env.effects.base import PhysicalEffect, spring_unit_wrench
from tensegrity_env.engine import Engine
from tensegrity_env.params import Params
from tensegrity_env.plot_limits import set_robust_limits

DTYPE = torch.float64
#: torque rows are divided by this lever [m] so that N and N*m weigh alike
TORQUE_LEVER = 0.5
#: ridge of the spring-tension split, relative to the mean diagonal of its normal matrix
RIDGE = 0.05


@dataclass(frozen=True)
class Residuals:
    """Per-transition residuals in element frames (``n`` transitions; numpy arrays).

    Attributes:
        force: residual force on each rod, (n, R, 3) [N], world frame.
        torque: residual torque about each rod's centre of mass, (n, R, 3) [N*m], world.
        along_v: residual force along ``-v̂``, (n, R) [N] (> 0 opposes the motion).
        speed: rod speed ``|v|``, (n, R) [m/s].
        along_w: residual torque along ``-ω̂``, (n, R) [N*m].
        spin: angular speed ``|ω|``, (n, R) [rad/s].
        tension: residual tension of each spring, (n, S) [N] (> 0 pulls).
        stretch: ``l - l0``, (n, S) [m].
        length: spring length ``l``, (n, S) [m].
        rate: elongation rate ``l̇``, (n, S) [m/s].
        cap_force: residual force on each end cap, (n, 2R, 3) [N], world.
        cap_height: end-cap height above the floor ``z - r``, (n, 2R) [m].
        cap_slip: horizontal end-cap speed, (n, 2R) [m/s].
        command: applied control force ``h f_u`` per rod, (n, R, 3) [N].
        time: time of each transition along its trajectory, (n,) [s].
    """

    force: np.ndarray
    torque: np.ndarray
    along_v: np.ndarray
    speed: np.ndarray
    along_w: np.ndarray
    spin: np.ndarray
    tension: np.ndarray
    stretch: np.ndarray
    length: np.ndarray
    rate: np.ndarray
    cap_force: np.ndarray
    cap_height: np.ndarray
    cap_slip: np.ndarray
    command: np.ndarray
    time: np.ndarray

    @property
    def n(self) -> int:
        return int(self.force.shape[0])


def compute_residuals(
    topology: Any,
    params: Params,
    effects: Sequence[PhysicalEffect],
    dataset: Dataset,
    split: str = "train",
    max_transitions: int = 20_000,
    seed: int = 0,
) -> Residuals:
    """Residuals of the model (params + effects) on a random subset of a split."""
    data = dataset.split(split)
    T = data.n_transitions
    idx = drawn_transitions(data, max_transitions, seed)
    acting = acting_split(effects, data, dataset.dt)
    s0, s1, u = transitions_of(acting, idx)
    cables = cable_commands_at(acting, idx)
    engine = Engine(topology, dataset.dt, effects=effects)
    feat = transition_features(topology, s0, s1, u, dataset.dt, cables)
    with torch.no_grad():
        acc, alpha_l, _ = engine.accelerations(s0, params, u, cables)
    rot = feat.rot
    force = params.mass[None, :, None] * (feat.accel - acc)
    torque = torch.einsum("nrij,nrj->nri", rot, params.inertia * (feat.alpha_local - alpha_l))
    kin = engine.kinematics(s0)
    tension, stretch, length, rate = _spring_split(kin, topology, params, force, torque)
    cap_force = _cap_split(kin.arms, force, torque)
    R = topology.n_rods
    radius = torch.tensor([r.radius for r in topology.rods], dtype=DTYPE)
    caps = kin.x[:, : 2 * R]
    height = caps[..., 2] - radius.repeat_interleave(2)
    slip = torch.linalg.vector_norm(kin.xd[:, : 2 * R, :2], dim=-1)
    v_hat = s0.v / torch.linalg.vector_norm(s0.v, dim=-1, keepdim=True).clamp_min(1e-12)
    w_hat = s0.omega / torch.linalg.vector_norm(s0.omega, dim=-1, keepdim=True).clamp_min(1e-12)
    command = params.control_gain * u
    return Residuals(
        force=force.numpy(),
        torque=torque.numpy(),
        along_v=-(force * v_hat).sum(-1).numpy(),
        speed=torch.linalg.vector_norm(s0.v, dim=-1).numpy(),
        along_w=-(torque * w_hat).sum(-1).numpy(),
        spin=torch.linalg.vector_norm(s0.omega, dim=-1).numpy(),
        tension=tension,
        stretch=stretch,
        length=length,
        rate=rate,
        cap_force=cap_force,
        cap_height=height.numpy(),
        cap_slip=slip.numpy(),
        command=command.detach().numpy(),
        time=(idx % T) * dataset.dt,
    )


def _spring_split(
    kin: Any, topology: Any, params: Params, force: torch.Tensor, torque: torch.Tensor
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares spring tensions (n, S) explaining the residual wrenches, with each
    spring's stretch, length and elongation rate (n, S)."""
    f_u, t_u, length = spring_unit_wrench(kin, topology)  # (n, R, 3, S)
    n, R = force.shape[:2]
    design = torch.cat([f_u, t_u / TORQUE_LEVER], dim=2).reshape(n, 6 * R, -1)
    target = torch.cat([force, torque / TORQUE_LEVER], dim=2).reshape(n, 6 * R, 1)
    # ridge: springs nearly share directions, so plain least squares splits wildly
    gram = design.transpose(1, 2) @ design
    lam = RIDGE * torch.diagonal(gram, dim1=1, dim2=2).mean(-1)[:, None, None]
    eye = torch.eye(gram.shape[-1], dtype=DTYPE)
    tension = torch.linalg.solve(gram + lam * eye, design.transpose(1, 2) @ target)[..., 0]
    nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long)
    d = kin.x[:, nodes[:, 1]] - kin.x[:, nodes[:, 0]]
    axis = d / length.unsqueeze(-1)
    rate = ((kin.xd[:, nodes[:, 1]] - kin.xd[:, nodes[:, 0]]) * axis).sum(-1)
    stretch = length - params.rest_length
    return tension.numpy(), stretch.numpy(), length.numpy(), rate.numpy()


def _cap_split(arms: torch.Tensor, force: torch.Tensor, torque: torch.Tensor) -> np.ndarray:
    """Minimum-norm end-cap forces (n, 2R, 3) with the residual force and torque per rod."""
    n, R = force.shape[:2]
    eye = torch.eye(3, dtype=DTYPE).expand(n, R, 3, 3)

    def skew(a: torch.Tensor) -> torch.Tensor:
        z = torch.zeros_like(a[..., 0])
        return torch.stack(
            [
                torch.stack([z, -a[..., 2], a[..., 1]], -1),
                torch.stack([a[..., 2], z, -a[..., 0]], -1),
                torch.stack([-a[..., 1], a[..., 0], z], -1),
            ],
            -2,
        )

    top = torch.cat([eye, eye], -1)
    bottom = torch.cat([skew(arms[:, :, 0]), skew(arms[:, :, 1])], -1) / TORQUE_LEVER
    G = torch.cat([top, bottom], -2)  # (n, R, 6, 6)
    rhs = torch.cat([force, torque / TORQUE_LEVER], -1).unsqueeze(-1)
    caps = (torch.linalg.pinv(G) @ rhs)[..., 0]  # (n, R, 6)
    return caps.reshape(n, R, 2, 3).reshape(n, 2 * R, 3).numpy()


# ---------------------------------------------------------------------- summaries
def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.ravel(a), np.ravel(b)
    sa, sb = a.std(), b.std()
    if sa == 0 or sb == 0:
        return 0.0
    return float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else 0.0


def summarize(res: Residuals) -> dict[str, float]:
    """One number per physical signature (see :data:`SIGNATURES`)."""
    low = res.cap_height <= 0
    high = res.cap_height > 0.02
    comp, tens = res.stretch < 0, res.stretch > 0
    cmd = np.linalg.norm(res.command, axis=-1)
    out = {
        "rms_force": _rms(res.force),
        "rms_torque": _rms(res.torque),
        "cap_low_rms": _rms(res.cap_force[low]),
        "cap_high_rms": _rms(res.cap_force[high]),
        "cap_low_fraction": float(low.mean()),
        "spring_compressed_rms": _rms(res.tension[comp]),
        "spring_stretched_rms": _rms(res.tension[tens]),
        "drag_corr_speed": _corr(res.along_v, res.speed),
        "drag_corr_speed2": _corr(res.along_v, res.speed**2),
        "rot_drag_corr_spin": _corr(res.along_w, res.spin),
        "cubic_corr": _corr(res.tension, res.stretch**3),
        "field_mean_fraction": float(
            np.linalg.norm(res.force.reshape(-1, 3).mean(0))
            / max(_rms(res.force) * np.sqrt(3), 1e-300)
        ),
        "control_corr": _corr(np.linalg.norm(res.force, axis=-1), cmd) if cmd.any() else 0.0,
        "time_corr": _corr(np.linalg.norm(res.force, axis=-1).mean(-1), res.time),
    }
    return out


#: signature -> (summary key, what it reveals)
SIGNATURES: dict[str, str] = {
    "cap_low_rms": "residual force on end caps at/below the floor (contact)",
    "cap_high_rms": "residual force on end caps well above the floor",
    "spring_compressed_rms": "residual tension of springs shorter than rest (slack)",
    "spring_stretched_rms": "residual tension of springs longer than rest",
    "drag_corr_speed": "residual force against the motion vs speed (linear drag)",
    "drag_corr_speed2": "residual force against the motion vs speed^2 (quadratic drag)",
    "rot_drag_corr_spin": "residual torque against the spin vs angular speed (rotational drag)",
    "cubic_corr": "residual tension vs (l - l0)^3 (nonlinear stiffness)",
    "field_mean_fraction": "mean residual force / its RMS (a constant force field)",
    "control_corr": "residual force size vs command size (control gain / lag)",
    "time_corr": "residual size vs time (drift)",
}


def summary_table(summary: dict[str, float]) -> str:
    """Markdown table of :func:`summarize` output."""
    lines = ["| signature | value | reveals |", "|---|---|---|"]
    lines.append(f"| rms_force | {summary['rms_force']:.3g} N | overall missing force per rod |")
    lines.append(f"| rms_torque | {summary['rms_torque']:.3g} N*m | overall missing torque |")
    for key, text in SIGNATURES.items():
        unit = " N" if key.endswith("_rms") else ""
        lines.append(f"| {key} | {summary[key]:.3g}{unit} | {text} |")
    return "\n".join(lines)


# ---------------------------------------------------------------------- plots
def plot_residuals(
    res: Residuals, path: str | Path, title: str = "residuals", points: int = 4000
) -> Path:
    """One PNG: the residual in each element's frame against what reveals each effect."""
    rng = np.random.default_rng(0)

    def pick(*arrays: np.ndarray) -> list[np.ndarray]:
        flat = [np.ravel(a) for a in arrays]
        k = rng.choice(flat[0].size, size=min(points, flat[0].size), replace=False)
        return [f[k] for f in flat]

    fig, axes = plt.subplots(2, 4, figsize=(18, 8), layout="constrained")
    kw = {"s": 3, "alpha": 0.4}

    def scaled(ax: Any, x: np.ndarray, y: np.ndarray, x_bound: float | None = None) -> None:
        """Both axes scaled to the bulk of the points (``x_bound``: the x axis within ±)."""
        bound: dict[str, Any] = {} if x_bound is None else {"low": -x_bound, "high": x_bound}
        set_robust_limits(ax, x, "x", what="points", **bound)
        set_robust_limits(ax, y, "y", what="points")

    h, fz = pick(res.cap_height, res.cap_force[..., 2])
    axes[0, 0].scatter(h * 1e3, fz, **kw)
    axes[0, 0].axvline(0, color="k", lw=0.8)
    scaled(axes[0, 0], h * 1e3, fz)
    axes[0, 0].set(xlabel="end-cap height z - r [mm]", ylabel="vertical residual force [N]",
                   title="end caps: contact?")  # fmt: skip
    s, ft, hh = pick(res.cap_slip, np.linalg.norm(res.cap_force[..., :2], axis=-1), res.cap_height)
    axes[0, 1].scatter(s, ft, c=hh <= 0, cmap="coolwarm", **kw)
    scaled(axes[0, 1], s, ft)
    axes[0, 1].set(xlabel="end-cap slip speed [m/s]", ylabel="horizontal residual force [N]",
                   title="end caps: friction? (red: at/below floor)")  # fmt: skip
    x, t = pick(res.stretch, res.tension)
    axes[0, 2].scatter(x * 1e3, t, **kw)
    axes[0, 2].axvline(0, color="k", lw=0.8)
    # a rest length between 0 and twice the spring's length: |l - l0| <= l
    longest = float(np.nanmax(res.length)) * 1e3 if res.length.size else None
    scaled(axes[0, 2], x * 1e3, t, longest)
    axes[0, 2].set(xlabel="spring stretch l - l0 [mm]", ylabel="residual tension [N]",
                   title="springs: slack / nonlinear?")  # fmt: skip
    r, tt = pick(res.rate, res.tension)
    axes[0, 3].scatter(r, tt, **kw)
    scaled(axes[0, 3], r, tt)
    axes[0, 3].set(
        xlabel="spring rate [m/s]", ylabel="residual tension [N]", title="springs: damping?"
    )
    v, fv = pick(res.speed, res.along_v)
    axes[1, 0].scatter(v, fv, **kw)
    scaled(axes[1, 0], v, fv)
    axes[1, 0].set(
        xlabel="rod speed [m/s]", ylabel="residual force along -v [N]", title="rods: drag?"
    )
    w, tw = pick(res.spin, res.along_w)
    axes[1, 1].scatter(w, tw, **kw)
    scaled(axes[1, 1], w, tw)
    axes[1, 1].set(xlabel="angular speed [rad/s]", ylabel="residual torque along -ω [N*m]",
                   title="rods: rotational drag?")  # fmt: skip
    c, fc = pick(res.command.reshape(-1, 3)[:, 0], res.force.reshape(-1, 3)[:, 0])
    axes[1, 2].scatter(c, fc, **kw)
    scaled(axes[1, 2], c, fc)
    axes[1, 2].set(xlabel="applied command h f_u, x [N]", ylabel="residual force, x [N]",
                   title="control: gain / lag?")  # fmt: skip
    order = np.argsort(res.time)
    mag = np.linalg.norm(res.force, axis=-1).mean(-1)[order]
    axes[1, 3].plot(res.time[order], mag, ".", ms=2, alpha=0.4)
    set_robust_limits(axes[1, 3], mag, what="points")
    axes[1, 3].set(xlabel="time along trajectory [s]", ylabel="mean |residual force| [N]",
                   title="time: drift?")  # fmt: skip
    for a in axes.ravel():
        a.grid(True, alpha=0.3)
    fig.suptitle(title)
    return save_figure(fig, path)
