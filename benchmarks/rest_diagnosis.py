"""Why a model does not hold a real take's measured rest: measurements, not a fit.

On a ``bench_real.py --workdir`` take folder (``take.h5``, ``identified.json``) this
measures, at the take's measured resting poses, each candidate reason why a fitted
model settles away from the measured resting shape (docs/decisions.md has the numbers
for the ETH drop take and what they say):

* **Markers onto end caps.** Each rod's cap-to-cap distance against the model's rod
  length in every resting stretch (a rigid rod keeps one length; the import's placement
  moves both caps by one constant per rod), and the shape error no rigid-rod model can
  go below (the measured caps against their projection onto rods of the model's length).
  With ``--raw`` the capture file's resting stretches are read too: markers the camera
  system reconstructs at several spots (each spot still, millimetres apart).
* **Tension-only members.** Each spring's and cable's measured length at rest, its
  rest length and the tension the model gives it there.
* **Balance at the measured rest.** The springs' equilibrium matrix at the measured
  pose (each rod's force and torque per newton of each tension; torques over the rod's
  half length): the least unbalance of any non-negative tension pattern and the
  model's own pattern's, in newtons per newton of tension; and whether tensions >= 0,
  with the floor's reaction at the resting caps inside the friction cone, balance the
  rods under the model's masses, equal masses, or with the winch cables pulling.
* **Contact and cables.** The rest shape (``bench_real.rest_shape``) with the resting
  caps' radii or the floor's friction changed, or the motor-driven cables taut, no refit.
* **How fast, and what the fit sees.** The rest shape's error over time from the
  measured resting state, and on the training split's resting windows the end-cap RMS
  from the measured state (velocities zero) against that from a fitted initial state,
  as the trajectory fit's windows have.
* ``--refit``: rest lengths, stiffnesses, masses (the anchored rod's held) and the
  resting caps' radii (or those of ``--groups``) fitted to 1-s rollouts from the training split's resting states,
  with a prior of weight ``--prior`` (1 mm of end-cap error per 1 mm of rest length or
  radius, per 10 % of a stiffness or mass): how far each must move to hold the rest,
  and what that does to the rest shape, the held-out pieces and the training split's
  moving pieces (open-loop from measured states).

    python benchmarks/rest_diagnosis.py W/eth_T2_drop --robot robot.yaml \
        [--raw recording.csv --up y] [--refit --prior 1 --groups rest_length,stiffness]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import least_squares, lsq_linear, nnls

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_real as br

from identification.data.dataset import Dataset, read_dataset
from identification.data.end_caps import measured_rod_states, rod_states_from_nodes
from identification.data.sample_grid import on_nominal_grid
from identification.trajectory import cap_radius_fit
from identification.trajectory.windows import perturb, rollout_caps
from tensegrity_env.effects import GroundContact
from tensegrity_env.engine import Engine, State
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model
from tensegrity_env.rotations import np_quat_to_matrix

#: a resting cap lies this close [m] to the lowest one: the caps a robot stands on
#: (a 6-bar on a face stands on three caps; the others are tens of centimetres up)
FEET_REACH = 0.03
#: edges of the friction pyramid standing in for the Coulomb cone in the balance
PYRAMID = 8
#: the rest shape's error is read at these times [s] from the measured resting state
DRIFT_TIMES = (1 / 120, 2 / 120, 4 / 120, 8 / 120, 0.25, 0.5, 2.0)
#: how far [m] the motor-driven cables are made taut at the measured rest: a tenth of
#: a millimetre to a millimetre is 5-50 N at the NTRT file's 50 kN/m
TAUT = (1e-4, 1e-3)
#: window lengths [samples] of the fitted-state check (the floor fit's are 4-30)
WINDOW_SAMPLES = (4, 8, 30)
#: the refit's rollouts from resting states [s], as long as the held-out check's
REFIT_HORIZON = 1.0
#: the parameter groups the refit may move
REFIT_GROUPS = ("rest_length", "stiffness", "mass", "radius")


def resting_groups(data: Dataset) -> list[tuple[str, np.ndarray]]:
    """The dataset's pieces that lie in a resting stretch, joined per stretch: a label
    (``"rest a-b s"``) and the end caps (T, 2R, 3) [m]."""
    stretches, placed = json.loads(data.attrs["stretches"]), json.loads(data.attrs["pieces"])
    out: dict[tuple[str, float, float], list[np.ndarray]] = {}
    for split, rows in placed.items():
        for k, (name, a, b) in enumerate(rows):
            for s in stretches.get(name, []):
                if s["kind"] == "rest" and s["start_s"] <= a and b <= s["end_s"]:
                    out.setdefault((name, s["start_s"], s["end_s"]), []).append(
                        data.split(split).nodes[k]
                    )
    return [(f"rest {a:.1f}-{b:.1f} s", np.concatenate(v)) for (_, a, b), v in sorted(out.items())]


def on_rods(caps: np.ndarray, model: Model) -> np.ndarray:
    """End caps (2R, 3) [m] of rods placed on the measured ones (centre of mass and axis
    from ``caps`` (2R, 3)) with the model's end offsets: the model's caps at that pose."""
    st = rod_states_from_nodes(np.repeat(caps[None], 3, 0), model.topology, 1.0)
    rot = np_quat_to_matrix(st["q"][1])  # (R, 3, 3)
    offsets = np.asarray(model.topology.end_offsets)  # (R, 2, 3)
    return (st["p"][1][:, None] + np.einsum("rij,rkj->rki", rot, offsets)).reshape(-1, 3)


def rod_lengths(groups: list[tuple[str, np.ndarray]], model: Model) -> list[str]:
    """Per resting stretch: each rod's median cap distance minus the model's rod length
    and its spread within the stretch [mm]; the rigid-rod floor of the shape error."""
    lines = []
    model_len = np.array([r.length for r in model.topology.rods])
    for label, caps in groups:
        d = np.linalg.norm(caps[:, 1::2] - caps[:, 0::2], axis=-1)  # (T, R)
        with np.errstate(all="ignore"):
            off = 1e3 * (np.nanmedian(d, 0) - model_len)
            spread = 1e3 * (np.nanpercentile(d, 90, 0) - np.nanpercentile(d, 10, 0))
            med = np.nanmedian(caps, 0)
        seen = np.isfinite(med).all(-1)
        floor = np.nan
        if seen.all():
            floor = 1e3 * br._kabsch_rms(on_rods(med, model), med)
        lines.append(f"  {label}: cap distance - rod length [mm] {np.round(off, 2).tolist()}, "
                     f"spread (90-10 %) {np.round(spread, 2).tolist()}; rigid-rod floor of the "
                     f"shape error {floor:.2f} mm")  # fmt: skip
    return lines


def raw_reconstructions(
    raw: Path, up: str, groups: list[tuple[str, np.ndarray]], floor: float
) -> list[str]:
    """Markers of the capture file's resting stretches reconstructed at several still
    spots: each spot (a 3-mm cluster seen in 3 % of the frames or more), grouped where
    spots lie within 15 mm of each other, with their share of the frames, their height
    and how far each lies from the most seen one along and across the rod of the nearest
    end cap (the stretch's median caps, ``floor`` [m] the import's height shift)."""
    from identification.data.mocap.formats import read_recording

    rec = read_recording(raw, up=up)
    lines = []
    for label, caps in groups:
        with np.errstate(all="ignore"):
            med = np.nanmedian(caps, 0) + np.array([0.0, 0.0, floor])
        a, b = (float(x) for x in label.split()[1].split("-"))
        sel = (rec.time >= a) & (rec.time < b)
        pts = rec.points[sel].reshape(-1, 3)
        pts = pts[np.isfinite(pts).all(-1)]
        spots, shares = [], []
        while len(pts):
            c = pts[0]
            for _ in range(5):
                near = np.linalg.norm(pts - c, axis=-1) < 0.003
                c = np.median(pts[near], 0)
            spots.append(c)
            shares.append(near.sum() / sel.sum())
            pts = pts[~near]
        keep = [i for i, s in enumerate(shares) if s >= 0.03]
        sp = np.array([spots[i] for i in keep])
        used: set[int] = set()
        for i in range(len(sp)):
            near = [j for j in range(len(sp)) if np.linalg.norm(sp[j] - sp[i]) < 0.015]
            if len(near) > 1 and i not in used:
                used.update(near)
                gap = max(np.linalg.norm(sp[j] - sp[k]) for j in near for k in near)
                top = max(near, key=lambda j: shares[keep[j]])
                cap = int(np.nanargmin(np.linalg.norm(med - sp[top], axis=-1)))
                axis = med[cap] - med[cap ^ 1]
                axis /= np.linalg.norm(axis)
                d = np.array([sp[j] - sp[top] for j in near if j != top])
                along = np.abs(d @ axis)
                across = np.linalg.norm(d - np.outer(d @ axis, axis), axis=-1)
                lines.append(f"  {label}: one marker at {len(near)} spots up to {1e3 * gap:.1f} mm apart "
                             f"(shares {[round(float(shares[keep[j]]), 2) for j in near]}, heights "
                             f"{[round(float(1e3 * sp[j, 2]), 1) for j in near]} mm in the file's frame; "
                             f"from the most seen one {np.round(1e3 * along, 1).tolist()} mm along the rod of "
                             f"end cap {cap}, {np.round(1e3 * across, 1).tolist()} mm across it)")  # fmt: skip
        if not used:
            lines.append(f"  {label}: every marker at one spot")
    return lines


def tensions(model: Model, caps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Measured lengths (S,) [m] at the model's caps (2R, 3) and the model's tensions
    ``K (l - l0)`` (S,) [N] there (negative: slack)."""
    sn = np.asarray(model.topology.spring_nodes)
    length = np.linalg.norm(caps[sn[:, 0]] - caps[sn[:, 1]], axis=-1)
    p = model.params
    return length, p.stiffness.numpy() * (length - p.rest_length.numpy())


def equilibrium_matrix(model: Model, caps: np.ndarray, members: list[int]) -> np.ndarray:
    """(6R, len(members)): each rod's force and torque about its centre (over its half
    length, so in newtons; the axial torque dropped) per newton of each member's tension."""
    R = model.topology.n_rods
    c2 = caps.reshape(R, 2, 3)
    centre, axis = c2.mean(1), c2[:, 1] - c2[:, 0]
    half = np.linalg.norm(axis, axis=-1) / 2
    axis = axis / (2 * half[:, None])
    sn = np.asarray(model.topology.spring_nodes)
    cols = []
    for s in members:
        a, b = sn[s]
        d = (caps[b] - caps[a]) / np.linalg.norm(caps[b] - caps[a])
        cols.append(point_wrench([(a, d), (b, -d)], caps, centre, axis, half))
    return np.array(cols).T


def point_wrench(forces: list[tuple[int, np.ndarray]], caps: np.ndarray, centre: np.ndarray,
                 axis: np.ndarray, half: np.ndarray) -> np.ndarray:  # fmt: skip
    """(6R,) wrench of point forces ``(cap index, force [N])`` on their rods."""
    w = np.zeros((len(centre), 6))
    for node, f in forces:
        r = node // 2
        w[r, :3] += f
        w[r, 3:] += np.cross(caps[node] - centre[r], f) / half[r]
    w[:, 3:] -= np.einsum("ri,ri->r", w[:, 3:], axis)[:, None] * axis
    return w.ravel()


def balance(model: Model, caps: np.ndarray, feet: list[int], masses: np.ndarray, members: list[int],
            mu: float) -> float:  # fmt: skip
    """Largest per-rod residual [N] (force, or torque over the half length) when tensions
    >= 0 of ``members`` and the floor's reactions at ``feet`` (inside a pyramid of
    friction ``mu``) balance the rods' weights ``masses`` (R,) [kg]."""
    R = model.topology.n_rods
    c2 = caps.reshape(R, 2, 3)
    centre, axis = c2.mean(1), c2[:, 1] - c2[:, 0]
    half = np.linalg.norm(axis, axis=-1) / 2
    axis = axis / (2 * half[:, None])
    cols = [equilibrium_matrix(model, caps, members)]
    for node in feet:
        for k in range(PYRAMID):
            t = 2 * np.pi * k / PYRAMID
            f = np.array([mu * np.cos(t), mu * np.sin(t), 1.0])
            cols.append(point_wrench([(node, f)], caps, centre, axis, half)[:, None])
    A = np.hstack(cols)
    weight = np.zeros((R, 6))
    weight[:, 2] = -9.81 * masses
    sol = lsq_linear(A, -weight.ravel(), bounds=(0, np.inf))
    return float(np.abs(A @ sol.x + weight.ravel()).max())


def balance_lines(model: Model, caps: np.ndarray) -> list[str]:
    """The balance section's lines at the model's caps (2R, 3) [m]."""
    names = [s.name for s in model.topology.springs]
    cables = set(model.topology.cable_actuators)
    springs = [s for s in range(len(names)) if s not in cables]
    A = equilibrium_matrix(model, caps, springs)
    n = len(springs)
    T, _ = nnls(np.vstack([A, 1e3 * np.ones(n)]), np.r_[np.zeros(A.shape[0]), 1e3 * n])
    _, t_model = tensions(model, caps)
    t_model = np.clip(t_model[springs], 0.0, None)
    best = np.linalg.norm(A @ T) / np.linalg.norm(T)
    own = np.linalg.norm(A @ t_model) / np.linalg.norm(t_model)
    lines = [f"  springs' unbalance per newton of tension: best non-negative pattern {best:.3f} N/N "
             f"(tensions {T.min():.2f}-{T.max():.2f} x their mean), the model's {own:.3f} N/N "
             f"(mean tension {t_model.mean():.2f} N)"]  # fmt: skip
    z = caps[:, 2]
    feet = [int(i) for i in np.flatnonzero(z < z.min() + FEET_REACH)]
    gc = next((e for e in model.effects if isinstance(e, GroundContact)), None)
    mu = float(gc.value("friction", torch.zeros(1)).item()) if gc is not None else 1.0
    M = model.params.mass.numpy()
    for label, masses, members in (("the model's masses", M, springs),
                                   ("equal masses", np.full_like(M, M.mean()), springs),
                                   ("the model's masses, cables pulling too", M, list(range(len(names))))):  # fmt: skip
        res = balance(model, caps, feet, masses, members, mu)
        lines.append(f"  balance with tensions >= 0 and the floor at caps {feet} (friction {mu:.2f}), "
                     f"{label}: largest residual {res:.2e} N")  # fmt: skip
    return lines


def start_state(model: Model, piece: np.ndarray, dt: float) -> State:
    """The first measured state of ``piece`` (T, 2R, 3) [m], velocities zero."""
    _, st = measured_rod_states(piece[None], model.topology, dt, "gaussian", br.SMOOTHING)
    t = int(np.flatnonzero(np.isfinite(st["p"][0]).all((-1, -2)))[0])
    p, q = torch.as_tensor(st["p"][:, t]), torch.as_tensor(st["q"][:, t])
    return State(p, torch.zeros_like(p), q, torch.zeros_like(p))


def drift(model: Model, piece: np.ndarray, dt: float) -> list[float]:
    """Rest-shape error [m] (after a rigid alignment) at :data:`DRIFT_TIMES` from the
    first measured state of ``piece``, against its median caps."""
    measured = np.nanmedian(piece, 0)
    seen = np.isfinite(measured).all(-1)
    steps = [round(t / dt) for t in DRIFT_TIMES]
    with torch.no_grad():
        caps = rollout_caps(model.engine(), model.params, start_state(model, piece, dt),
                            torch.zeros(1, max(steps), model.topology.n_rods, 3, dtype=torch.float64))[0].numpy()  # fmt: skip
    return [br._kabsch_rms(caps[s][seen], measured[seen]) for s in steps]


def with_contact(model: Model, **values: torch.Tensor) -> Model:
    """``model`` with its ground contact's values changed."""
    return model.replace(effects=tuple(e.with_values(**values) if isinstance(e, GroundContact) else e
                                       for e in model.effects))  # fmt: skip


def contact_lines(model: Model, piece: np.ndarray, dt: float) -> list[str]:
    """The rest shape with the resting caps' radii and the friction changed."""
    gc = next((e for e in model.effects if isinstance(e, GroundContact)), None)
    if gc is None:
        return ["  no ground contact in the model"]
    r0 = gc.radius.detach().numpy()
    z = np.nanmedian(piece, 0)[:, 2].reshape(r0.shape)
    feet = z < np.nanmin(z) + FEET_REACH
    mu = float(gc.value("friction", torch.zeros(1)).item())
    out = []
    for label, change in (("as fitted", {}),
                          ("resting caps' radii 6 mm less", {"cap_radius": torch.as_tensor(np.where(feet, np.clip(r0 - 0.006, 0, None), r0))}),
                          ("resting caps' radii 6 mm more", {"cap_radius": torch.as_tensor(np.where(feet, r0 + 0.006, r0))}),
                          ("every radius 12 mm", {"cap_radius": torch.full_like(torch.as_tensor(r0), 0.012)}),
                          ("friction halved", {"friction": torch.tensor(mu / 2)}),
                          ("friction 1.6x", {"friction": torch.tensor(1.6 * mu)})):  # fmt: skip
        shape, why = br.rest_shape(with_contact(model, **change), piece, dt)
        out.append(
            f"  {label}: rest shape " + (f"{1e3 * shape:.2f} mm" if shape is not None else str(why))
        )
    return out


def cable_lines(model: Model, piece: np.ndarray, dt: float) -> list[str]:
    """The rest shape with the motor-driven cables taut at the measured rest: each one's
    rest length its length there less :data:`TAUT` (declared stiffness), no refit."""
    cables = list(model.topology.cable_actuators)
    if not cables:
        return ["  no motor-driven cables"]
    length, _ = tensions(model, on_rods(np.nanmedian(piece, 0), model))
    out = []
    for delta in TAUT:
        l0 = model.params.rest_length.clone()
        l0[cables] = torch.as_tensor(length[cables] - delta)
        shape, why = br.rest_shape(
            model.replace(params=model.params.replace(rest_length=l0)), piece, dt
        )
        out.append(
            f"  cables taut by {1e3 * delta:g} mm: rest shape "
            + (f"{1e3 * shape:.2f} mm" if shape is not None else str(why))
        )
    return out


def window_lines(model: Model, data: Dataset) -> list[str]:
    """On the training split's resting pieces, windows of :data:`WINDOW_SAMPLES`
    starting every 0.5 s: end-cap RMS from the measured state (velocities zero) and from
    an initial state fitted to the window (every rod's pose, velocity and rates)."""
    R = model.topology.n_rods
    engine = Engine(
        model.topology, model.dt, model.effects, substeps=model.engine().substeps, native=True
    )
    out = []
    for n in WINDOW_SAMPLES:
        given, fitted = [], []
        for piece in cap_radius_fit.resting_pieces(data):
            _, st = measured_rod_states(
                piece[None], model.topology, data.dt, "gaussian", br.SMOOTHING
            )
            known = np.isfinite(st["p"][0]).all((-1, -2))
            for s0 in range(0, piece.shape[0] - n - 1, round(0.5 / data.dt)):
                if not known[s0]:
                    continue
                target = piece[s0 : s0 + n + 1]
                seen = np.isfinite(target).all(-1)
                p, q = torch.as_tensor(st["p"][:, s0]), torch.as_tensor(st["q"][:, s0])
                init = State(p, torch.zeros_like(p), q, torch.zeros_like(p))
                zeros = torch.zeros(1, n, R, 3, dtype=torch.float64)

                def residual(x: np.ndarray, init: State = init, target: np.ndarray = target,
                             seen: np.ndarray = seen, zeros: torch.Tensor = zeros) -> np.ndarray:  # fmt: skip
                    with torch.no_grad():
                        caps = rollout_caps(engine, model.params, perturb(init, torch.as_tensor(x).view(1, R, 12)),
                                            zeros)[0].numpy()  # fmt: skip
                    return np.where(seen[..., None], caps - target, 0.0).ravel()

                def rms(r: np.ndarray, seen: np.ndarray = seen) -> float:
                    return float(np.sqrt((r**2).sum() / seen.sum()))

                given.append(rms(residual(np.zeros(12 * R))))
                fitted.append(
                    rms(least_squares(residual, np.zeros(12 * R), diff_step=1e-6, max_nfev=200).fun)
                )
        if given:
            out.append(f"  windows of {n} samples ({n * data.dt:.3f} s), {len(given)} at rest: end-cap RMS "
                       f"{1e3 * np.median(given):.2f} mm from the measured state, {1e3 * np.median(fitted):.2f} mm "
                       "from a fitted one (medians)")  # fmt: skip
    return out or ["  no resting window with every rod's state measured"]


def rest_refit(
    model: Model, data: Dataset, prior: float, groups: tuple[str, ...] = REFIT_GROUPS
) -> tuple[Model, list[str]]:
    """Rest lengths, stiffnesses, masses (the first rod's held: the anchor) and the
    resting caps' radii (those of ``groups``) fitted to :data:`REFIT_HORIZON` rollouts from the training
    split's resting states (each rollout's caps against the measured ones, every 5th
    sample, the centroid's drift removed), with a prior of weight ``prior``: the fitted
    model and what moved."""
    top, P = model.topology, model.params
    cables = set(top.cable_actuators)
    free = [s for s in range(top.n_springs) if s not in cables]
    nS, R = len(free), top.n_rods
    gc = next(e for e in model.effects if isinstance(e, GroundContact))
    others = [e for e in model.effects if e is not gc]
    r0 = gc.radius.detach().numpy().copy()
    engine = Engine(top, model.dt, model.effects, substeps=model.engine().substeps, native=True)
    horizon = cap_radius_fit.REST_HORIZON
    cap_radius_fit.REST_HORIZON = REFIT_HORIZON
    try:
        start = cap_radius_fit.rest_states(cap_radius_fit.resting_pieces(data), engine)
    finally:
        cap_radius_fit.REST_HORIZON = horizon
    if start is None:
        return model, ["  no resting state in the training split to refit from"]
    init, measured = start
    z = measured[:, 0, :, 2].reshape(-1, R, 2).min(0)
    feet = np.argwhere(z < np.nanmin(z) + FEET_REACH)
    seen = np.isfinite(measured).all(-1)
    zeros = torch.zeros(init.p.shape[0], measured.shape[1] - 1, R, 3, dtype=torch.float64)
    scale = np.r_[
        np.full(nS, 1e-3), np.full(nS, 0.1), np.full(R - 1, 0.1), np.full(len(feet), 1e-3)
    ]

    def model_of(x: np.ndarray) -> Model:
        l0, K, M = P.rest_length.clone(), P.stiffness.clone(), P.mass.clone()
        l0[free] += torch.as_tensor(x[:nS])
        K[free] *= torch.as_tensor(np.exp(x[nS : 2 * nS]))
        M[1:] *= torch.as_tensor(np.exp(x[2 * nS : 2 * nS + R - 1]))
        r = r0.copy()
        for k, (i, e) in enumerate(feet):
            r[i, e] = max(r[i, e] + x[2 * nS + R - 1 + k], 0.0)
        params = dataclasses.replace(
            P, rest_length=l0, stiffness=K, mass=M, inertia=P.inertia * (M / P.mass)[:, None]
        )
        return model.replace(
            params=params, effects=(*others, gc.with_values(cap_radius=torch.as_tensor(r)))
        )

    def residual(x: np.ndarray) -> np.ndarray:
        m = model_of(x)
        with torch.no_grad():
            caps = rollout_caps(engine.with_effects(m.effects), m.params, init, zeros).numpy()
        d = np.where(seen[..., None], caps - measured, 0.0)
        d = np.nan_to_num(d - d.mean(2, keepdims=True), nan=1.0)[:, ::5].ravel()
        return np.r_[d, prior * np.sqrt(d.size / x.size) * 1e-3 * x / scale]

    x0 = np.zeros(scale.size)
    sizes = {"rest_length": nS, "stiffness": nS, "mass": R - 1, "radius": len(feet)}
    mask = np.concatenate([np.full(k, g in groups) for g, k in sizes.items()])

    def selected(y: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[mask] = y
        return residual(x)

    fit = least_squares(selected, x0[mask], diff_step=1e-3, method="trf", max_nfev=60)
    n = fit.fun.size - x0.size
    x = x0.copy()
    x[mask] = fit.x
    mass = np.exp(x[2 * nS : 2 * nS + R - 1])
    fitted = model_of(x)
    fitted_mass = fitted.params.mass.numpy()
    return fitted, [
        f"  {', '.join(groups)} fitted to {init.p.shape[0]} rollouts of {REFIT_HORIZON:g} s, prior {prior:g}: end-cap RMS (drift removed) "
        f"{1e3 * np.sqrt(np.mean(residual(x0)[:n] ** 2)):.2f} -> {1e3 * np.sqrt(np.mean(fit.fun[:n] ** 2)):.2f} mm",
        f"  rest lengths moved by up to {1e3 * np.abs(x[:nS]).max():.1f} mm; stiffness x "
        f"{np.exp(x[nS:2 * nS]).min():.2f}-{np.exp(x[nS:2 * nS]).max():.2f}; masses of rods 1.. x "
        f"{np.round(mass, 2).tolist()} (to {np.round(fitted_mass, 3).tolist()} kg); resting caps' radii moved {np.round(1e3 * x[2 * nS + R - 1:], 2).tolist()} mm",
    ]  # fmt: skip


def model_lines(label: str, model: Model, data: Dataset, piece: np.ndarray) -> str:
    """A model's rest shape, held-out end-cap RMS and the training split's moving pieces'
    open-loop end-cap RMS at the benchmark's horizons."""
    shape, _ = br.rest_shape(model, piece, data.dt)
    held, _ = br.open_loop(model, br.held_out(data), data.dt, br.HORIZONS)
    moving = moving_pieces(data)
    no_piece = ["no moving piece in the training split"] * len(br.HORIZONS)
    train, why = (
        br.open_loop(model, moving, data.dt, br.HORIZONS) if moving.size else ([None] * 4, no_piece)
    )

    def cm(v: list[float | None], why: list[str | None] | None = None) -> str:
        return ", ".join(f"- ({why[i]})" if x is None and why else "-" if x is None else f"{1e2 * x:.2f}"
                         for i, x in enumerate(v))  # fmt: skip

    return (f"  {label}: rest shape {'-' if shape is None else f'{1e3 * shape:.2f} mm'}; held-out end-cap RMS "
            f"[cm] at {', '.join(f'{h:g}' for h in br.HORIZONS)} s: {cm(held)}; training split's moving pieces: {cm(train, why)}")  # fmt: skip


def moving_pieces(data: Dataset) -> np.ndarray:
    """End caps (N, T, 2R, 3) [m] of the training split's pieces outside resting stretches."""
    stretches, placed = json.loads(data.attrs["stretches"]), json.loads(data.attrs["pieces"])
    keep = [k for k, (name, a, b) in enumerate(placed.get("train", []))
            if not any(s["kind"] == "rest" and s["start_s"] <= a and b <= s["end_s"] for s in stretches.get(name, []))]  # fmt: skip
    return data.split("train").nodes[keep]


def diagnose_rest(
    folder: Path, robot: Path, raw: Path | None, up: str, refit: tuple[str, ...], prior: float
) -> None:
    """Print every section for the take in ``folder`` (module docstring); raises
    :class:`InputError` (one line) where the take has no resting stretch to look at."""
    data, _ = on_nominal_grid(read_dataset(folder / "take.h5"))
    if "stretches" not in data.attrs or "pieces" not in data.attrs:
        raise InputError(
            f"{folder / 'take.h5'}: no stretches recorded (import it with import-mocap)"
        )
    models = br.models(folder, robot, data.dt)
    model = models.get("identified", models["nominal"])
    piece = br.resting_piece(data)
    groups = resting_groups(data)
    if piece is None or not groups:
        raise InputError(f"{folder / 'take.h5'}: no piece lies in a resting stretch")
    print("markers onto end caps:")
    print("\n".join(rod_lengths(groups, model)))
    if raw is not None:
        floor = json.loads(data.attrs.get("placement", "{}"))
        shift = next(iter(floor.values()), {}).get("floor_height_m", 0.0) if floor else 0.0
        print("\n".join(raw_reconstructions(raw, up, groups, shift)))
    caps = on_rods(np.nanmedian(piece, 0), model)
    names = [s.name for s in model.topology.springs]
    for label, m in models.items():
        length, t = tensions(m, caps)
        print(f"tension-only members at the held-out rest, {label} model:")
        print(
            "  "
            + "; ".join(
                f"{n} {1e3 * x:.1f} mm " + (f"{y:.2f} N" if y >= 0 else "slack")
                for n, x, y in zip(names, length, t, strict=True)
            )
        )
        print(f"balance at the held-out rest, {label} model:")
        print("\n".join(balance_lines(m, caps)))
        print(f"rest shape over time from the measured resting state, {label} model [mm]: "
              + ", ".join(f"{t_:.3f} s {1e3 * d:.2f}" for t_, d in zip(DRIFT_TIMES, drift(m, piece, data.dt), strict=True)))  # fmt: skip
    print("contact (identify's model, no refit):")
    print("\n".join(contact_lines(model, piece, data.dt)))
    print("winch cables (identify's model, no refit):")
    print("\n".join(cable_lines(model, piece, data.dt)))
    print("resting windows (identify's model):")
    print("\n".join(window_lines(model, data)))
    if refit:
        print("refit at rest:")
        fitted, lines = rest_refit(model, data, prior, refit)
        print("\n".join(lines))
        print(model_lines("before", model, data, piece))
        print(model_lines("after", fitted, data, piece))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "folder", type=Path, help="a bench_real --workdir take folder (take.h5, identified.json)"
    )
    ap.add_argument(
        "--robot", type=Path, required=True, help="the robot file the take was imported with"
    )
    ap.add_argument(
        "--raw", type=Path, help="the take's capture file, to look at its resting markers"
    )
    ap.add_argument("--up", default="y", help="the capture file's up axis (with --raw)")
    ap.add_argument(
        "--refit", action="store_true", help="fit the model to the training split's rests"
    )
    ap.add_argument("--groups", default=",".join(REFIT_GROUPS),
                    help=f"what the refit moves (comma-separated among {', '.join(REFIT_GROUPS)})")  # fmt: skip
    ap.add_argument("--prior", type=float, default=1.0, help="the refit prior's weight")
    args = ap.parse_args(argv)
    for path in (args.folder / "take.h5", args.robot, *([args.raw] if args.raw else [])):
        if not path.is_file():
            print(f"rest_diagnosis: {path}: no such file", file=sys.stderr)
            return 2
    groups = tuple(g for g in args.groups.split(",") if g)
    if not set(groups) <= set(REFIT_GROUPS) or not groups:
        print(
            f"rest_diagnosis: --groups {args.groups}: choose among {', '.join(REFIT_GROUPS)}",
            file=sys.stderr,
        )
        return 2
    try:
        diagnose_rest(
            args.folder, args.robot, args.raw, args.up, groups if args.refit else (), args.prior
        )
    except InputError as e:
        print(f"rest_diagnosis: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
