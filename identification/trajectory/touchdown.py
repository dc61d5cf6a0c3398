"""Ground contact from touchdowns: its parameters by a derivative-free search.

Every other effect is fitted by Levenberg-Marquardt through the windows; contact is
not, because the multi-step end-cap error is **discontinuous** in its parameters.
MuJoCo's soft contact (which the engine copies) applies its damping force from the
first step an end cap is below the floor. A change of parameters that moves an impact
across a time step therefore makes the error jump; the Gauss-Newton model promises
what no step delivers, and the fit stalls far from the optimum (the contact's
stiffness and friction well off, and a drop of that model ending far from MuJoCo's).

Instead:

1. **Touchdowns.** Every trajectory that starts with all end caps above the floor
   gives one: the first sample where a measured cap comes within :data:`TOUCH` of
   touching. The rod states are fitted on the airborne prefix with the model without
   contact (its gate is closed there, so they do not depend on the contact's
   parameters), then rolled on to :data:`LEAD` steps before the touchdown.
2. **Search.** Nelder-Mead over :data:`~identification.trajectory.effect_coords.CONTACT_FREE`
   in log/logit coordinates minimises the mean squared end-cap error of the first
   ``h`` steps after all touchdowns, for growing ``h`` (:data:`HORIZONS`): the first
   impact alone has a single basin; longer horizons add sliding and the next bounces.
   The simplex restarts :data:`RESTARTS` times per horizon, which leaves the local
   minima the error's small jumps make.
3. **Uncertainty.** Standard errors from the Gauss-Newton curvature of the end-cap
   residuals at the optimum (central differences): ``σ̂² (JᵀJ)⁻¹``.

The search needs the rod states only at the touchdowns, so a function evaluation is
one rollout of ``h`` steps, batched over touchdowns.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from scipy.optimize import minimize

from identification.data.dataset import Dataset
from identification.data.end_caps import odd_window, smooth_rod_states
from identification.trajectory.airborne import cap_radii, lowest_seen
from identification.trajectory.effect_coords import CONTACT_FREE, CONTACT_START, from_free, to_free
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.window_states import fit_states
from identification.trajectory.windows import STATE_KEYS, cut_windows, end_caps
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import Engine, State
from tensegrity_env.params import Params

#: a measured end cap this close to touching the floor [m] marks a touchdown (10 σ of
#: motion-capture noise: the noise alone does not reach it)
TOUCH = 0.01
#: the search's windows start this many steps before the touchdown
LEAD = 2
#: steps after the touchdowns the search fits, in turn
HORIZONS = (60, 150)
#: Nelder-Mead runs per horizon, each from a fresh simplex around the last optimum
RESTARTS = 2
#: the fresh simplex's edge in log/logit coordinates (±35 % in stiffness, ...)
SIMPLEX_STEP = 0.3
#: most function evaluations per Nelder-Mead run
MAX_EVALS = 300
#: a touchdown needs this many airborne steps before it to fit the rod states on
MIN_AIRBORNE = 20
#: error returned where a rollout blows up [m^2]
BLOWN_UP = 1.0
#: soft-contact time constants [s] a search with ``spread=True`` also starts from
#: (critically damped): MuJoCo's usual range, from a few physics steps to twice its
#: 20 ms default; a search started at one end of it stays in that end's basin
TIME_CONSTANTS = (0.0025, 0.005, 0.01, 0.02, 0.04)


@dataclass(frozen=True)
class Touchdowns:
    """Rod states just before each touchdown and the measured end caps from there.

    Attributes:
        state: rod states :data:`LEAD` steps before each touchdown, (N, R, ·).
        obs: measured end caps from there, (N, H+1, 2R, 3) [m].
        control: commands over those steps, (N, H, R, 3), or None (no control).
        traj, first: trajectory and sample of each touchdown, (N,).
        prefix_rms: end-cap RMS [m] of the airborne state fits (the noise, if the
            model without contact is right).
        valid: which end caps were seen, (N, H+1, 2R) bool, or None (all); an unseen
            one (a gap) counts in no residual, whatever ``obs`` holds there.
    """

    state: State
    obs: torch.Tensor
    control: torch.Tensor | None
    traj: np.ndarray
    first: np.ndarray
    prefix_rms: float
    valid: torch.Tensor | None = None

    @property
    def size(self) -> int:
        return int(self.obs.shape[0])

    def seen(self, steps: int) -> torch.Tensor:
        """Which end caps count over the first ``steps`` steps, (N, steps+1, 2R) bool."""
        shape = self.obs[:, : steps + 1].shape[:-1]
        return torch.ones(shape, dtype=torch.bool) if self.valid is None else self.valid[:, : steps + 1]


def find_touchdowns(
    engine: Engine,
    vec: ParamVector,
    nodes: np.ndarray,
    control: np.ndarray,
    grid: dict[str, np.ndarray],
    radius: np.ndarray,
    iters: int = 15,
    horizon: int = HORIZONS[-1],
) -> Touchdowns | None:
    """The touchdowns of a split (None if none): see the module docstring, step 1.

    ``engine`` (with every effect of the model but contact) and ``vec`` (nothing free,
    the declared parameters) fit the airborne states. ``nodes`` (N, T+1, 2R, 3) [m]
    and ``control`` (N, T, R, 3) are the split's measurements, ``grid`` its rod states
    from smoothing (N, T+1, R, ·) (where the fits start), ``radius`` (2R,) [m] each
    end cap's radius. A touchdown needs ``horizon`` measured steps after it.
    """
    params = vec.params(vec.start)
    T = nodes.shape[1] - 1
    gap = nodes[..., 2] - radius  # (N, T+1, 2R) [m]
    states, obs, ctrl, traj, first, sse, m = [], [], [], [], [], 0.0, 0
    for i in range(nodes.shape[0]):
        near = np.flatnonzero(lowest_seen(gap[i]) < TOUCH)
        if near.size == 0:
            continue
        n = int(near[0]) - LEAD  # airborne prefix [steps]
        if n < MIN_AIRBORNE or n + horizon > T:
            continue
        win = cut_windows(nodes[i : i + 1, : n + 1], control[i : i + 1, :n],
                          {k: grid[k][i : i + 1] for k in STATE_KEYS}, n)  # fmt: skip
        fit = fit_states(engine, vec, win, iters)
        sse += float(fit.history[-1]) * win.residuals
        m += win.residuals
        left = n - int(win.start[0])  # the window starts later where the smoothing starts in a gap
        with torch.no_grad():
            ctrl_k = None if win.control is None else win.control[:, :left]
            roll = engine.rollout(fit.windows.state, params, left, ctrl_k)
        states.append(roll.index((slice(None), -1)))
        obs.append(torch.as_tensor(nodes[i, n : n + horizon + 1]))  # gaps: NaN until below
        ctrl.append(torch.as_tensor(control[i, n : n + horizon]))
        traj.append(i)
        first.append(n + LEAD)
    if not states:
        return None
    state = State(*(torch.cat([getattr(s, k) for s in states]) for k in STATE_KEYS))
    commands = torch.stack(ctrl)
    seen_obs = torch.stack(obs)
    valid = torch.isfinite(seen_obs).all(-1)
    return Touchdowns(
        state=state, obs=torch.nan_to_num(seen_obs, nan=0.0),
        control=commands if bool(commands.any()) else None, traj=np.array(traj),
        first=np.array(first), prefix_rms=float(np.sqrt(sse / m)),
        valid=None if bool(valid.all()) else valid,
    )  # fmt: skip


def contact_at(
    contact: GroundContact, x: np.ndarray, keys: Sequence[str] = CONTACT_FREE
) -> GroundContact:
    """``contact`` with ``keys`` at coordinates ``x`` (len(keys),) (log/logit/as is)."""
    values = {k: from_free(contact.PARAMS[k], torch.tensor(float(x[j]), dtype=torch.float64))
              for j, k in enumerate(keys)}  # fmt: skip
    return contact.with_values(validate=False, **values)


def touchdown_residual(
    engine: Engine,
    params: Params,
    others: Sequence[PhysicalEffect],
    contact: GroundContact,
    touch: Touchdowns,
    steps: int,
) -> torch.Tensor:
    """Predicted minus measured end caps over ``steps`` after the touchdowns,
    (N, steps+1, 2R, 3); 0 where an end cap was not seen (:meth:`Touchdowns.seen`)."""
    eng = engine.with_effects([*others, contact])
    ctrl = None if touch.control is None else touch.control[:, :steps]
    with torch.no_grad():
        roll = eng.rollout(touch.state, params, steps, ctrl)
        r = end_caps(eng, roll.p, roll.q) - touch.obs[:, : steps + 1]
        return torch.where(touch.seen(steps)[..., None], r, torch.zeros_like(r))


@dataclass(frozen=True)
class ContactSearch:
    """The searched contact (its ``uncertainty`` set), the RMS [m] per horizon, evaluations."""

    contact: GroundContact
    rms: dict[int, float]
    evaluations: int


def search_contact(
    engine: Engine,
    params: Params,
    others: Sequence[PhysicalEffect],
    start: GroundContact,
    touch: Touchdowns,
    log: Callable[[str], None] = lambda s: None,
    horizons: Sequence[int] = HORIZONS,
    keys: Sequence[str] = CONTACT_FREE,
    restarts: int = RESTARTS,
    what: str = "touchdowns",
    bounds: dict[str, tuple[float, float]] | None = None,
    spread: bool = False,
) -> ContactSearch:
    """Contact parameters from the touchdowns (module docstring, steps 2 and 3).

    ``engine`` and ``params``: the model without contact; ``others``: its effects
    (contact acts after them); ``start``: the contact the search starts from (its
    parameters outside ``keys`` are kept); ``horizons``: steps after the touchdowns
    fitted in turn (at most the touchdowns' length); ``keys``: the contact parameters
    searched (default :data:`CONTACT_FREE`); ``restarts``: Nelder-Mead runs per horizon; ``what``: the
    windows' name in the log; ``bounds``: limits (lo, hi) of some of ``keys`` in the
    search's coordinates (log, logit, m), the simplex and the search kept within them;
    ``spread``: start from the best of ``start`` and :func:`time_constant_starts` (by
    the error at the first horizon).
    """
    evals = 0

    def error(x: np.ndarray, steps: int) -> float:
        nonlocal evals
        evals += 1
        r = touchdown_residual(engine, params, others, contact_at(start, x, keys), touch, steps)
        value = float((r**2).sum()) / max(3 * int(touch.seen(steps).sum()), 1)
        return value if np.isfinite(value) else BLOWN_UP

    x = np.array([to_free(start.PARAMS[k], float(start.values[k].reshape(-1)[0]))
                  for k in keys])  # fmt: skip
    box = [(bounds or {}).get(k, (-np.inf, np.inf)) for k in keys]
    lo, hi = np.array([b[0] for b in box]), np.array([b[1] for b in box])
    x = np.clip(x, lo, hi)
    if spread:
        tried = [x, *(np.clip(y, lo, hi) for y in time_constant_starts(start, keys))]
        x = min(tried, key=lambda y: error(y, horizons[0]))
    # a bounded coordinate's simplex edge: at most half its range (a vertex clipped onto
    # the bound would leave the simplex flat in it)
    step = np.minimum(SIMPLEX_STEP, (hi - lo) / 2)
    rms: dict[int, float] = {}
    for steps in horizons:
        for _ in range(restarts):
            simplex = np.vstack([x, x + np.diag(np.where(x + step <= hi, step, -step))])
            res = minimize(error, x, args=(steps,), method="Nelder-Mead",
                           bounds=list(zip(lo, hi, strict=True)) if bounds else None,
                           options={"initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-14,
                                    "maxfev": MAX_EVALS})  # fmt: skip
            x = res.x
        rms[steps] = float(np.sqrt(res.fun))
        found = contact_at(start, x, keys)
        log(f"    {what}, {steps} steps: end-cap RMS {rms[steps] * 1e3:.3f} mm; "
            + ", ".join(f"{k} {float(found.values[k]):.4g}" for k in keys))  # fmt: skip
    contact = contact_at(start, x, keys)
    se = _stderr(engine, params, others, start, touch, x, horizons[-1], keys)
    for k, s in zip(keys, se, strict=True):
        spec, v = start.PARAMS[k], float(contact.values[k].reshape(-1)[0])
        slope = v * (1 - v) if spec.unit_interval else (abs(v) if spec.positive else 1.0)
        contact.uncertainty[k] = slope * float(s)
    return ContactSearch(contact, rms, evals)


def time_constant_starts(start: GroundContact, keys: Sequence[str]) -> list[np.ndarray]:
    """``start``'s ``keys`` in the search's coordinates with its stiffness and damping
    those of a critically damped soft contact of each of :data:`TIME_CONSTANTS`
    (``K = 1/(d tc)^2``, ``B = 2/(d tc)`` at its impedance ``d``), (len(keys),) each."""
    d = float(start.values["impedance"].reshape(-1)[0])
    return [np.array([to_free(start.PARAMS[k], {"stiffness": 1.0 / (d * tc) ** 2, "damping": 2.0 / (d * tc)}
                      .get(k, float(start.values[k].reshape(-1)[0]))) for k in keys])
            for tc in TIME_CONSTANTS]  # fmt: skip


def _stderr(
    engine: Engine,
    params: Params,
    others: Sequence[PhysicalEffect],
    start: GroundContact,
    touch: Touchdowns,
    x: np.ndarray,
    steps: int,
    keys: Sequence[str] = CONTACT_FREE,
    h: float = 1e-4,
) -> np.ndarray:
    """Standard errors of the coordinates ``x`` (central differences of the residuals).

    The larger of the Gauss-Newton ``σ̂² (JᵀJ)⁻¹`` (independent samples) and the
    sandwich ``(JᵀJ)⁻¹ (Σ_i g_i g_iᵀ) (JᵀJ)⁻¹ · N/(N-1)`` with one cluster per
    touchdown (``g_i = J_iᵀ r_i``): after an impact the errors of neighbouring samples
    are far from independent, which the Gauss-Newton value ignores.
    """

    def r(y: np.ndarray) -> np.ndarray:
        res = touchdown_residual(engine, params, others, contact_at(start, y, keys), touch, steps)
        return res.reshape(touch.size, -1).numpy()

    r0 = r(x)  # (N, m_i)
    J = np.stack([(r(x + h * e) - r(x - h * e)) / (2 * h) for e in np.eye(len(x))], axis=-1)
    Jf, rf = J.reshape(-1, len(x)), r0.reshape(-1)
    try:
        bread = np.linalg.inv(Jf.T @ Jf)
    except np.linalg.LinAlgError:
        return np.full(len(x), np.inf)
    sigma2 = float(rf @ rf) / max(3 * int(touch.seen(steps).sum()) - len(x), 1)
    g = np.einsum("imk,im->ik", J, r0)  # per-touchdown scores, (N, len(keys))
    n = touch.size
    sandwich = bread @ (g.T @ g) @ bread * (n / max(n - 1, 1))
    var = np.maximum(sigma2 * np.diag(bread), np.diag(sandwich))
    return np.sqrt(np.clip(var, 0.0, None))


def contact_from_dataset(
    dataset: Dataset,
    params: Params,
    effects: Sequence[PhysicalEffect] = (),
    start: GroundContact | None = None,
    split: str = "train",
    smoothing: float = 0.1,
    log: Callable[[str], None] = lambda s: None,
) -> ContactSearch | None:
    """Contact from a dataset's touchdowns, the declared model known (a calibration).

    ``params`` and ``effects``: the model without contact; ``start``: where the search
    starts (None: :data:`~identification.trajectory.effect_coords.CONTACT_START`); ``smoothing``
    [s]: the Savitzky-Golay window of the states the airborne fits start from. None
    when no trajectory of the split starts airborne.
    """
    topo, s = dataset.topology, dataset.split(split)
    vec = ParamVector.at(topo, params)
    engine = Engine(topo, dataset.dt, list(effects), native=True)
    smooth = smooth_rod_states(s.nodes, dataset.dt, vec.axes, odd_window(smoothing / dataset.dt))
    grid = {k: getattr(smooth, k) for k in STATE_KEYS}
    radius = cap_radii(topo)
    touch = find_touchdowns(engine, vec, s.nodes, s.control, grid, radius)
    if touch is None:
        return None
    log(f"{touch.size} touchdowns; airborne prefixes fitted to {touch.prefix_rms * 1e3:.3f} mm")
    if start is None:
        generic: dict[str, Any] = dict(CONTACT_START)  # parameter name -> value
        start = GroundContact(topo, **generic)
    return search_contact(engine, params, effects, start, touch, log)
