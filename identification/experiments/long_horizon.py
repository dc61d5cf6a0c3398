"""Long-horizon accuracy of an engine against ground-truth trajectories (the paper's Fig. 9b).

Rolls the engine out open-loop from each trajectory's first state with the recorded
controls, and measures the mean rod position error [m] and orientation error [rad]
(the angle of ``q_true⁻¹ q_model``) at every step.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from identification.data.dataset import Split
from identification.report.plots import save_figure
from identification.report.tables import error_text
from tensegrity_env.engine import Engine, State
from tensegrity_env.params import Params
from tensegrity_env.plot_limits import set_robust_limits
from tensegrity_env.rotations import quat_conj, quat_mul

CHECKPOINTS = (100, 1000, 2000, 5000, 10000, 20000)


def long_horizon_errors(
    engine: Engine, params: Params, split: Split, chunk: int = 1000
) -> dict[str, np.ndarray]:
    """Per-step errors of an open-loop rollout over whole trajectories.

    Returns ``position`` and ``orientation`` curves, (T+1,), averaged over rods and
    trajectories, in m and rad. Steps in chunks of ``chunk`` to bound memory.
    """
    T = split.n_transitions
    assert split.p is not None and split.q is not None
    state = State.from_numpy(*(getattr(split, k)[:, 0] for k in ("p", "v", "q", "omega")))
    control = torch.as_tensor(split.control)
    pos = np.zeros(T + 1)
    ang = np.zeros(T + 1)
    with torch.no_grad():
        for start in range(0, T, chunk):
            n = min(chunk, T - start)
            roll = engine.rollout(state, params, n, control[:, start : start + n])
            p_true = torch.as_tensor(split.p[:, start : start + n + 1])
            q_true = torch.as_tensor(split.q[:, start : start + n + 1])
            pos[start : start + n + 1] = (
                torch.linalg.vector_norm(roll.p - p_true, dim=-1).mean(dim=(0, 2)).numpy()
            )
            rel = quat_mul(quat_conj(q_true), roll.q)  # rotation from truth to model
            angle = 2 * torch.atan2(
                torch.linalg.vector_norm(rel[..., 1:], dim=-1), rel[..., 0].abs()
            )
            ang[start : start + n + 1] = angle.mean(dim=(0, 2)).numpy()
            state = roll.index((slice(None), -1))
    return {"position": pos, "orientation": ang}


def checkpoint_table(curves: dict[str, dict[str, np.ndarray]], dt: float) -> str:
    """Markdown table of errors at :data:`CHECKPOINTS` for each named model."""
    T = len(next(iter(curves.values()))["position"]) - 1
    steps = [s for s in CHECKPOINTS if s <= T] or [T]
    head = "| model | " + " | ".join(f"{s} steps ({s * dt:g} s)" for s in steps) + " |"
    lines = [head, "|" + "---|" * (len(steps) + 1)]
    for name, c in curves.items():
        cells = [
            f"{error_text(c['position'][s], '.3g', 'mm', 1e3)} / "
            f"{np.degrees(c['orientation'][s]):.3g}°"
            if np.isfinite(c["position"][s]) and np.isfinite(c["orientation"][s])
            else "diverged"
            for s in steps
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_long_horizon(
    curves: dict[str, dict[str, np.ndarray]], dt: float, path: str | Path
) -> Path:
    """Position and orientation error against time for each named model (log scale)."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4), layout="constrained")
    pos, ori = [], []
    for name, c in curves.items():
        t = np.arange(len(c["position"])) * dt
        pos.append(np.maximum(c["position"][1:], 1e-16))
        ori.append(np.maximum(np.degrees(c["orientation"][1:]), 1e-14))
        a1.semilogy(t[1:], pos[-1], label=name)
        a2.semilogy(t[1:], ori[-1], label=name)
    if pos:
        set_robust_limits(a1, np.concatenate(pos), what="errors")
        set_robust_limits(a2, np.concatenate(ori), what="errors")
    a1.set(xlabel="time [s]", ylabel="mean rod position error [m]", title="long-horizon rollout")
    a2.set(xlabel="time [s]", ylabel="mean rod orientation error [deg]")
    for a in (a1, a2):
        a.grid(True, which="both", alpha=0.3)
        a.legend()
    return save_figure(fig, path)
