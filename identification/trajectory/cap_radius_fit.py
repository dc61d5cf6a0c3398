"""Each end cap's contact radius, fitted where the robot rests on its floor.

A real robot's end caps differ in size, and its markers sit on their surfaces a few
millimetres from the points the model calls end caps: at rest on a flat floor, the
caps it stands on lie at different heights above it (on one 6-bar, 6 to 17 mm), where
the robot file's one radius per rod would have them all touch. The ground contact
gives each end cap its own radius (``cap_radius`` of
:class:`~tensegrity_env.effects.GroundContact`); this fit finds those of the caps the
robot rests on from the stretches where it does:

* **Residual.** From measured states of the resting pieces (zero velocity, the first
  one in every :data:`START_EVERY`), the model is rolled out for :data:`REST_HORIZON`; the
  residual is its end caps against the measured ones at every step: a model whose
  caps do not carry the robot where the data shows it sinks, tilts or rolls.
* **Free radii.** The end caps within :data:`CAP_REACH` of touching the floor (at
  the robot file's radius) in a resting piece, the caps a resting robot may stand
  on; each starts touching the floor where it is measured (its radius its height
  above the floor, if within bounds) and stays within ``[0, file + CAP_REACH]``.
  The floor's height and the contact law are held at the floor fit's (the height and
  the radii trade off; the floor fit pins the height).
* **Fit.** Bounded nonlinear least squares (``scipy.optimize.least_squares``, trust
  region reflective, finite differences); standard errors from the Gauss-Newton
  covariance ``s² (JᵀJ)⁻¹``, ``s²`` the residual variance (the residuals of one
  rollout are correlated in time: the errors are lower bounds). A radius the
  residual does not move (a cap that never touches in the fit) keeps the file's
  value and no standard error.

The radii are kept only where they lower the residual (:attr:`CapRadii.kept`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import least_squares

from identification.data.dataset import Dataset
from identification.data.end_caps import measured_rod_states
from identification.trajectory.windows import rollout_caps
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import Engine, State
from tensegrity_env.params import Params

#: how long [s] each rollout from a measured resting state runs: several of a soft
#: contact's time constants (0.02-0.1 s), so the caps reach the depth that carries their
#: load, and long enough for a robot standing on the wrong caps to visibly tilt
REST_HORIZON = 0.5
#: a rollout starts every this [s] of a resting piece
START_EVERY = 0.5
#: the measured starting states' Gaussian smoothing [s] (as the held-out check's)
SMOOTHING = 0.01
#: how far [m] above touching the floor (at the file's radius) a resting end cap may
#: still be one the robot stands on, and how far its radius may grow beyond the file's:
#: real end caps and marker mounts differ by up to a centimetre or two
CAP_REACH = 0.02
#: a radius whose residual column stays below this [m per m of radius] is not seen
UNSEEN = 1e-6
#: finite-difference step of the radii [m]
STEP = 1e-4


@dataclass(frozen=True)
class CapRadii:
    """What :func:`fit_cap_radii` found.

    Attributes:
        contact: the ground contact with the fitted radii (standard errors in its
            ``uncertainty['cap_radius']``, inf where not seen) if :attr:`kept`, else
            the one given.
        free: (R, 2) bool, the radii the fit moved.
        before: end-cap RMS [m] of the rollouts with the given radii.
        after: the same with the fitted radii.
        starts: how many rollouts the residual holds.
    """

    contact: GroundContact
    free: np.ndarray
    before: float
    after: float
    starts: int

    @property
    def kept(self) -> bool:
        return self.after < self.before

    def lines(self) -> list[str]:
        """What the fit did, in a few lines."""
        r = self.contact.radius.detach().cpu().numpy()
        se = np.broadcast_to(
            np.asarray(self.contact.uncertainty.get("cap_radius", np.inf), float), r.shape
        )
        caps = [f"{self.contact.topology.rods[i].name}.{e} {1e3 * r[i, e]:.2f} ± {1e3 * se[i, e]:.2f} mm"
                for i, e in zip(*np.nonzero(self.free), strict=True)]  # fmt: skip
        verdict = "kept" if self.kept else "not kept (no better)"
        return [f"end caps' contact radii from {self.starts} rollouts of {REST_HORIZON:g} s at rest: "
                f"{'; '.join(caps) or 'none free'}; end-cap RMS {1e3 * self.before:.2f} -> "
                f"{1e3 * self.after:.2f} mm, {verdict}"]  # fmt: skip


def resting_pieces(dataset: Dataset, split: str = "train") -> list[np.ndarray]:
    """End caps (T, 2R, 3) [m] of ``split``'s pieces that lie in a resting stretch of
    their take (the import's ``stretches`` and ``pieces`` attributes); none without."""
    stretches, placed = dataset.attrs.get("stretches"), dataset.attrs.get("pieces")
    if not stretches or not placed or split not in dataset.splits:
        return []
    stretches, placed = json.loads(stretches), json.loads(placed)
    nodes = dataset.split(split).nodes
    return [nodes[k] for k, (name, a, b) in enumerate(placed.get(split, []))
            if any(s["kind"] == "rest" and s["start_s"] <= a and b <= s["end_s"]
                   for s in stretches.get(name, []))]  # fmt: skip


def rest_states(pieces: Sequence[np.ndarray], engine: Engine) -> tuple[State, np.ndarray] | None:
    """Measured states at rest (zero velocity), (K,) rows, and the measured end caps
    (K, L+1, 2R, 3) over :data:`REST_HORIZON` from each; None where there is none."""
    dt, L = engine.dt, max(1, round(REST_HORIZON / engine.dt))
    every = max(1, round(START_EVERY / dt))
    rows, caps = [], []
    for piece in pieces:
        if piece.shape[0] <= L:
            continue
        _, st = measured_rod_states(piece[None], engine.topology, dt, "gaussian", SMOOTHING)
        known = np.isfinite(st["p"][0]).all((-1, -2)) & np.isfinite(st["q"][0]).all((-1, -2))
        for slot in range(0, piece.shape[0] - L, every):  # the first measured state in each slot
            hit = np.flatnonzero(known[slot : min(slot + every, piece.shape[0] - L)])
            if hit.size:
                a = slot + int(hit[0])
                rows.append((st["p"][0, a], st["q"][0, a]))
                caps.append(piece[a : a + L + 1])
    if not rows:
        return None
    p = torch.as_tensor(np.array([r[0] for r in rows]))
    q = torch.as_tensor(np.array([r[1] for r in rows]))
    return State(p, torch.zeros_like(p), q, torch.zeros_like(p)), np.array(caps)


def fit_cap_radii(
    engine: Engine,
    params: Params,
    effects: Sequence[PhysicalEffect],
    pieces: Sequence[np.ndarray],
) -> CapRadii | None:
    """Fit the contact radii of the end caps a robot rests on (module docstring).

    ``engine``: the engine without effects (its ``dt`` the pieces' sample interval [s]);
    ``params`` the fitted declared parameters; ``effects`` the fitted effects, the
    :class:`GroundContact` among them; ``pieces``: resting pieces' end caps (T, 2R, 3)
    [m]. None where there is no contact, no resting state, or no cap near the floor.
    """
    contact = next((e for e in effects if isinstance(e, GroundContact)), None)
    start = None if contact is None else rest_states(pieces, engine)
    if contact is None or start is None:
        return None
    init, measured = start
    others = [e for e in effects if e is not contact]
    R = engine.topology.n_rods
    file_r = contact.radius.detach().cpu().numpy().copy()
    height = contact.floor_height()
    # each cap's lowest height above the floor at the rollouts' starts, (R, 2) [m]
    lifted = np.fmin.reduce(measured[:, 0, :, 2].reshape(-1, R, 2), axis=0) - height
    free = np.isfinite(lifted) & (lifted - file_r < CAP_REACH)
    if not free.any():
        return None
    lo, hi = np.zeros(int(free.sum())), file_r[free] + CAP_REACH
    x0 = np.clip(lifted[free], lo, hi)
    seen = np.isfinite(measured).all(-1)
    zeros = torch.zeros(init.p.shape[0], measured.shape[1] - 1, R, 3, dtype=torch.float64)

    def with_radii(x: np.ndarray) -> GroundContact:
        r = file_r.copy()
        r[free] = x
        return contact.with_values(cap_radius=torch.as_tensor(r))

    def residual(x: np.ndarray) -> np.ndarray:
        eng = engine.with_effects([*others, with_radii(x)])
        with torch.no_grad():
            caps = rollout_caps(eng, params, init, zeros).numpy()
        d = np.where(seen[..., None], caps - measured, 0.0)
        return np.nan_to_num(d, nan=1.0, posinf=1.0, neginf=-1.0).reshape(-1)

    def rms(r: np.ndarray) -> float:
        return float(np.sqrt((r**2).sum() / max(3 * int(seen.sum()), 1)))

    before = rms(residual(file_r[free]))
    fit = least_squares(residual, x0, bounds=(lo, hi), diff_step=STEP / np.maximum(x0, STEP),
                        method="trf", x_scale=1e-3)  # fmt: skip
    J = fit.jac
    moved = np.linalg.norm(J, axis=0) > UNSEEN * np.sqrt(J.shape[0])
    se = np.full(free.shape, np.inf)
    if moved.any():
        dof = max(J.shape[0] - int(moved.sum()), 1)
        s2 = float(fit.fun @ fit.fun) / dof
        cov = s2 * np.linalg.pinv(J[:, moved].T @ J[:, moved])
        idx = np.argwhere(free)[moved]
        se[idx[:, 0], idx[:, 1]] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    x = np.where(moved, fit.x, file_r[free])
    after = rms(residual(x))
    fitted = with_radii(x)
    fitted.uncertainty = {**contact.uncertainty, "cap_radius": se}
    out = fitted if after < before else contact
    free_moved = np.zeros_like(free)
    free_moved[free] = moved
    return CapRadii(out, free_moved, before, after, int(init.p.shape[0]))
