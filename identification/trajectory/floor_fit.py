"""Identification on the floor: the declared model and ground contact fitted together.

A robot that rolls and tumbles on a floor touches it in almost every sample: there is
no airborne stretch to fit the declared model on apart from contact. Here contact is
in the model from the start and its parameters are fitted with the declared ones,
through the engine, on short windows that touch the floor:

1. **Start.** The declared parameters come from the regression on smoothed end caps
   restricted, at each sample, to the **rods** whose end caps are all away from the
   floor (:func:`rods_off_floor`; a rod that does not touch the floor obeys the
   declared model while the others roll on it). The floor height starts at the median
   height (``z - r``) of the lowest end cap over the samples where it is near the
   floor (:func:`floor_height`): a cap resting on a soft floor sinks into it, so the
   height is fitted too. The contact starts from a params file's ``ground_contact``
   when one is given, else from
   :data:`~identification.trajectory.effect_coords.CONTACT_START`.
2. **Rounds** (:func:`fit_on_floor`), :data:`ROUNDS` of them, then more (up to
   :data:`MAX_ROUNDS`) while each lowers the error by :data:`ROUND_GAIN`. The first fits the
   windows' initial states with the model held and runs a derivative-free
   **Nelder-Mead search** over the contact parameters (:data:`FLOOR_FREE`, log/logit
   coordinates) with the declared parameters and the states held
   (:func:`~identification.trajectory.touchdown.search_contact`). Each later round
   starts with a **valley search** (:func:`search_scale`) from the last joint fit: the
   declared parameters move along two directions, one common scale of every mass,
   inertia, stiffness and damping (the anchors held) and one of every rest length,
   with the windows' states following by their Gauss-Newton response, and the
   contact with them (a grid over the common scale, then Nelder-Mead), then fits the
   windows' **states afresh** at that model (:func:`reseeded`): each window keeps the
   better of its fitted state and one fitted again from smoothing, since states fitted
   at the far-off starting model stay in other basins through the impacts. Every round
   ends with **Levenberg-Marquardt** fitting everything jointly (declared parameters,
   contact, states), with a line search along rejected steps (``line_search``); the
   first round holds the **spring damping** at its start (:data:`FIRST_ROUND_HELD`).
   Its states are still those of the starting model, several times the noise off, and
   the damping, the weakest group, would take up their misfit and be driven towards
   zero, from where later rounds do not bring it back. From the first search on, the
   contact stays within :data:`CONTACT_RANGE` of the searched values
   (:func:`contact_box`): a trial step or search point outside is cut at the edge or
   rejected. Without the range, a declared model missing an effect (a drag) trades it
   against the contact: a far softer floor, raised by millimetres.

   The end-cap error jumps where an impact moves across a physics step. The jumps
   stall Gauss-Newton steps on the contact (hence the first search), and they stall
   Levenberg-Marquardt's damping: a rejected step's direction still descends over a
   fraction of its length, while more damping turns it towards the jumps, so steps
   shrink to nothing with every declared parameter a few percent off together. The
   line search takes the fraction instead. The common scale is the flattest
   direction left: only the anchored rod pins it (gravity and the contact, per unit
   effective mass, scale with the masses); the valley search steps along it over the
   jumps.

Where some windows start in the air (a throw or drop before it lands), half the floor
windows are drawn from those (:meth:`~identification.trajectory.end_cap_data.EndCapData.cut`,
``lift_off``): in that flight nothing but the declared model, gravity and a drag acts,
so they pin the masses and a drag that the contact would otherwise take up.

What the data pins: masses, inertias, stiffnesses, damping and rest lengths from the
rods' motion away from and against the floor; the contact's stiffness, impedance and
height together from how deep resting and landing caps sink (the three trade off
against each other on resting caps alone, impacts separate them); its damping from
how impacts die out; friction only from caps that slide or roll (a structure resting
on three caps says nothing about it).

**Axial spin.** Every window's initial state includes each rod's angular velocity
about its own axis (``spin=True`` in the state and joint fits). In free flight it acts
only through a tiny gyroscopic term, but on the floor friction acts at the end cap's
contact point, one radius off the axis: it spins a rod about its axis (tens of rad/s
for a rod rolling on the floor, with its tiny axial inertia), and that spin sets how
the contact point slips. A window started without it (end caps cannot show it) misses
the rolling: even on clean data the true model's windows fitted without it stay off
by more than millimetre noise, and the declared parameters bend to absorb the
difference.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import torch
from scipy.ndimage import minimum_filter1d
from scipy.optimize import minimize

from identification.trajectory import windowed_problem
from identification.trajectory.airborne import AIRBORNE, cap_radii, lowest_seen
from identification.trajectory.effect_coords import (
    CONTACT_FREE,
    CONTACT_START,
    EffectCoords,
    to_free,
)
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.progress import iteration_bar
from identification.trajectory.touchdown import TOUCH, Touchdowns, search_contact
from identification.trajectory.window_errors import better_states, windows_within
from identification.trajectory.window_states import fit_states, forward_seeds, search_spins
from identification.trajectory.windowed_fit import (
    WindowFit,
    group_size,
    state_response,
    trial_sse,
)
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem
from identification.trajectory.windows import Windows, local_basis, perturb
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import Engine
from tensegrity_env.topology import Topology

#: contact parameters fitted on the floor (the floor's height too)
FLOOR_FREE = (*CONTACT_FREE, "height")
#: rounds of search and joint fit at least ...
ROUNDS = 2
#: ... and at most: a round after the second runs while the one before lowered the
#: windows' sum of squares by :data:`ROUND_GAIN` or more (its valley search and states
#: afresh start from a model the last joint fit moved)
MAX_ROUNDS = 4
#: the fraction of the sum of squares a round must remove for another to follow
ROUND_GAIN = 0.05
#: the declared groups the first round's joint fit holds at their start (module docstring)
FIRST_ROUND_HELD = ("damping",)
#: iterations of each round's state fit (the joint fit refits the states)
STATE_ITERS = 5
#: Nelder-Mead runs per search
SEARCH_RESTARTS = 1
#: the declared groups one common scale moves (every parameter but the rest lengths;
#: the anchors stay fixed)
SCALED = ("stiffness", "damping", "mass", "inertia_perp", "control_gain")
#: common log-scale offsets tried along the scale valley (about -14 % to +28 %)
SCALE_GRID = tuple(np.round(np.arange(-0.15, 0.2501, 0.01), 2))
#: the Nelder-Mead simplex's edge for the valley directions and the contact coordinates
#: (log/logit units)
SCALE_SIMPLEX = (0.02, 0.1)
#: most evaluations of the scale-and-contact Nelder-Mead search
SCALE_EVALS = 200
#: how far later fits may move the floor fit's contact: a factor on its positive
#: parameters (stiffness, damping), logit units on the fractions (impedance, friction),
#: metres on the floor height
CONTACT_RANGE = {"factor": 3.0, "logit": 1.0, "height": 0.003}
#: how far [m] the first contact search may move the floor from where the end caps are
#: seen touching it (:func:`floor_height`): the band that measurement reads the caps in.
#: Unbounded, a search on a few short windows of a gapped take (a real 6-bar's jump) put
#: the floor 68 mm above the resting caps, a floor they would be sunk in
FLOOR_SEARCH_RANGE = TOUCH


def rods_off_floor(nodes: np.ndarray, topology: Topology, span: int) -> np.ndarray:
    """Per sample and rod (N, T, R): both end caps :data:`AIRBORNE` above the floor over
    the smoothing filter's ``span`` [samples] around the sample.

    ``nodes`` (N, T+1, 2R, 3) [m] the measured end caps; the floor is taken at z = 0.
    """
    N, T1 = nodes.shape[:2]
    gap = (nodes[..., 2] - cap_radii(topology)).reshape(N, T1, topology.n_rods, 2).min(-1)
    off = (gap > AIRBORNE).astype(np.uint8)
    return minimum_filter1d(off, size=span, axis=1)[:, :-1].astype(bool)


def rods_leaning(nodes: np.ndarray, topology: Topology, span: int) -> np.ndarray:
    """Per sample and rod (N, T, R): the end cap (0 or 1) a rod may lean on the floor
    with while its other cap stays :data:`AIRBORNE` above it over the smoothing
    filter's ``span`` [samples]; -1 where both caps stay clear (:func:`rods_off_floor`)
    or neither does. ``nodes`` (N, T+1, 2R, 3) [m]; the floor is taken at z = 0.
    """
    N, T1 = nodes.shape[:2]
    gap = (nodes[..., 2] - cap_radii(topology)).reshape(N, T1, topology.n_rods, 2)
    clear = minimum_filter1d((gap > AIRBORNE).astype(np.uint8), size=span, axis=1)[:, :-1]
    one = clear.sum(-1) == 1
    return np.where(one, np.argmin(clear, axis=-1), -1).astype(np.int8)


def floor_height(nodes: np.ndarray, topology: Topology) -> float:
    """Starting floor height [m]: the median ``z - r`` of the lowest end cap over the
    samples where it is within :data:`~identification.trajectory.touchdown.TOUCH` of z = 0
    (or below). ``nodes`` (N, T+1, 2R, 3) [m]."""
    lowest = lowest_seen(nodes[..., 2] - cap_radii(topology))
    near = lowest[np.isfinite(lowest) & (lowest < TOUCH)]
    return float(np.median(near)) if near.size else 0.0


def floor_contact(
    topology: Topology, nodes: np.ndarray, start: PhysicalEffect | None = None
) -> GroundContact:
    """The contact a floor fit starts from: ``start``'s values (a params file, or a fit)
    if given, else :data:`CONTACT_START` at the height :func:`floor_height` estimates."""
    values: dict[str, Any] = dict(CONTACT_START)  # parameter name -> value
    values["height"] = floor_height(nodes, topology)
    if start is not None:
        values.update({k: float(start.values[k].reshape(-1)[0]) for k in start.PARAMS
                       if start.PARAMS[k].per == ""})  # fmt: skip
        values.update({k: start.values[k] for k in start.PARAMS if start.PARAMS[k].per != ""})
        radius_se = start.uncertainty.get("cap_radius")
        if radius_se is not None:  # the start's radii, with their standard errors
            return GroundContact(topology, {"cap_radius": radius_se}, **values)
    return GroundContact(topology, **values)


def with_floor(
    vec: ParamVector,
    effects: Sequence[PhysicalEffect],
    contact: GroundContact,
    axis: int | None,
    box: dict[str, tuple[float, float]] | None = None,
) -> ParamVector:
    """``vec`` with ``effects`` and ``contact`` (last) as coordinates, contact's
    :data:`FLOOR_FREE` free (within ``box``, see :func:`contact_box`, if given)."""
    return replace(vec, coords=EffectCoords.of([*effects, contact], axis, FLOOR_FREE, box))


def contact_box(
    contact: GroundContact, keys: Sequence[str] = FLOOR_FREE, floor: float | None = None
) -> dict[str, tuple[float, float]]:
    """Limits (lo, hi) of ``contact``'s ``keys`` in the fit's coordinates (log, logit, m)
    within :data:`CONTACT_RANGE` of its values.

    Later fits on the floor (candidate effects, accepted models) start from the floor
    fit's contact; without limits, a joint fit of a few short windows trades the
    contact against the new effect until the floor is nearly gone (a stiffness near
    zero, the floor centimetres up). Within them, a step that would leave
    the range is cut at its edge (:func:`~identification.trajectory.windowed_problem.fit`).
    ``floor``: where the end caps are seen touching the floor [m] (:func:`floor_height`):
    the height stays within :data:`FLOOR_SEARCH_RANGE` of it too, however many fits
    follow each other (each range is around the last fit's values).
    """
    out = {}
    for k in keys:
        spec = contact.PARAMS[k]
        x = to_free(spec, float(contact.values[k].reshape(-1)[0]))
        if spec.unit_interval:
            r = CONTACT_RANGE["logit"]
        elif spec.positive:
            r = float(np.log(CONTACT_RANGE["factor"]))
        else:
            r = CONTACT_RANGE["height"]
        lo, hi = x - r, x + r
        if k == "height" and floor is not None:
            lo, hi = max(lo, floor - FLOOR_SEARCH_RANGE), min(hi, floor + FLOOR_SEARCH_RANGE)
            lo, hi = min(lo, x), max(hi, x)  # the value itself stays inside
        out[k] = (lo, hi)
    return out


def bounded(vec: ParamVector, theta: torch.Tensor, floor: float | None = None) -> ParamVector:
    """``vec`` with its contact (the last effect) limited to :func:`contact_box` of its
    values at ``theta`` (the height near ``floor`` [m] where given)."""
    assert vec.coords is not None
    contact = vec.coords.effects_at(theta[vec.n_free :].detach())[-1]
    assert isinstance(contact, GroundContact)  # narrowing: fits append the floor contact last
    return replace(vec, coords=vec.coords.with_box(contact_box(contact, floor=floor)))


def contact_height(vec: ParamVector, theta: torch.Tensor) -> float:
    """The floor height [m] of ``vec``'s contact (its last effect) at ``theta``."""
    assert vec.coords is not None
    contact = vec.coords.effects_at(theta[vec.n_free :].detach())[-1]
    return float(contact.values["height"].reshape(-1)[0])


def search_floor_contact(
    engine: Engine,
    vec: ParamVector,
    windows: Windows,
    theta: torch.Tensor,
    log: Callable[[str], None] = lambda s: None,
    spread: bool = False,
) -> torch.Tensor:
    """``theta`` with the contact's coordinates from a Nelder-Mead search on ``windows``.

    The declared parameters, the other effects and the windows' states are held. The
    contact is ``vec``'s last effect, its coordinates the last of ``theta``. The floor
    height stays within :data:`FLOOR_SEARCH_RANGE` of its start (where the end caps are
    seen touching, :func:`floor_height`). ``spread``: the search starts from the best of
    the fit's contact and a spread of soft-contact time constants
    (:data:`~identification.trajectory.touchdown.TIME_CONSTANTS`; the floor fit's second
    start, :func:`~identification.trajectory.floor_declared.floor_fit`).
    """
    assert vec.coords is not None
    n = vec.n_free
    effects = vec.coords.effects_at(theta[n:].detach())
    others, contact = effects[:-1], effects[-1]
    assert isinstance(contact, GroundContact)  # narrowing: fits append the floor contact last
    params = vec.params(vec.full(theta.detach()))
    touch = Touchdowns(state=windows.state, obs=windows.obs, control=windows.control,
                       traj=windows.traj, first=windows.start, prefix_rms=float("nan"),
                       valid=windows.seen())  # fmt: skip
    h = float(contact.values["height"].reshape(-1)[0])
    found = search_contact(engine, params, others, contact, touch, log,
                           horizons=(windows.steps,), keys=FLOOR_FREE,
                           restarts=SEARCH_RESTARTS, what="contact search on floor windows",
                           bounds={"height": (h - FLOOR_SEARCH_RANGE, h + FLOOR_SEARCH_RANGE)},
                           spread=spread)  # fmt: skip
    k = len(FLOOR_FREE)
    x = torch.tensor([float(v) for v in _coords(found.contact)], dtype=theta.dtype)
    return torch.cat([theta[: len(theta) - k], x])


def _coords(contact: GroundContact) -> list[float]:
    """:data:`FLOOR_FREE` of ``contact`` in the fit's coordinates."""
    coords = EffectCoords.of([contact], None, FLOOR_FREE)
    return coords.start().tolist()


def scale_directions(vec: ParamVector, theta: torch.Tensor) -> torch.Tensor:
    """The valley directions of the fitted vector at ``theta``, (2, n_free + n_effect):
    the common scale (1 on the free log-parameters of :data:`SCALED`, and each force
    coefficient of a linear effect times its value) and the common rest-length scale (1
    on the free log rest lengths); 0 on the contact's coordinates.

    Scaling every mass, inertia, stiffness and damping together leaves the motion
    unchanged (gravity and the contact, per unit effective mass, scale with the
    masses) if the effects' forces scale too: a drag held at its value while the
    masses move is no valley (the search stays at scale 1 with the masses off
    together). Only the anchored parameters pin the
    scale, through the rods they act on. Shorter rest lengths with softer springs keep
    the pretension.
    """
    rows = []
    forces = torch.where(vec.mass_scaled(), theta.detach(), torch.zeros_like(theta))
    for groups, effects in ((SCALED, forces), (("rest_length",), torch.zeros_like(forces))):
        rows.append(held_groups(vec, groups).to(torch.float64) + effects)
    return torch.stack(rows)


def search_scale(
    engine: Engine, vec: ParamVector, fit: WindowFit, log: Callable[[str], None] = lambda s: None
) -> tuple[torch.Tensor, Windows]:
    """``fit`` moved along the valley directions and the contact by a derivative-free search.

    The fit's free parameters move by ``a`` along :func:`scale_directions` (log units; the
    effects' force coefficients to first order),
    the windows' states follow by their Gauss-Newton response
    (:func:`~identification.trajectory.windowed_fit.state_response`), and the contact's
    coordinates (the last of ``theta``) are searched with them: first the common scale
    over :data:`SCALE_GRID` with the rest held, then a Nelder-Mead search over ``a`` and
    the contact from the best of the grid. The end-cap error jumps where an impact
    crosses a physics step, which stalls Levenberg-Marquardt's small steps along the
    valley; the search steps over the jumps. Returns ``theta`` and the windows at the
    lowest end-cap error found (``fit``'s own if nothing is lower).
    """
    assert fit.normal is not None and vec.coords is not None
    theta, windows = fit.theta.detach(), fit.windows
    U = scale_directions(vec, theta)
    basis = local_basis(vec.axes, spin=True)
    response = torch.stack([torch.einsum("bl,lrj->brj", state_response(fit.normal, u), basis)
                            for u in U])  # fmt: skip
    n, k = len(U), len(FLOOR_FREE)
    chunk = group_size(basis, theta, windows.size)
    forces = vec.mass_scaled()  # effect coordinates scaled exactly

    def at(x: np.ndarray) -> tuple[torch.Tensor, Windows]:
        a = torch.as_tensor(x[:n], dtype=theta.dtype)
        th = theta + a @ U
        th[forces] = theta[forces] * torch.exp(a[0])
        th[len(th) - k :] = torch.as_tensor(x[n:], dtype=th.dtype)
        d = torch.einsum("i,ibrj->brj", a, response)
        return th, replace(windows, state=perturb(windows.state, d))

    lo, hi = vec.bounds()

    def error(x: np.ndarray) -> float:
        th, w = at(x)
        if bool(((th < lo) | (th > hi)).any()):
            return np.inf  # out of range (the contact's box): rejected
        return trial_sse(engine, vec, w, basis, th, chunk)[1] / windows.residuals

    x0 = np.concatenate([np.zeros(n), theta[len(theta) - k :].numpy()])
    grid = [(error(np.concatenate([[a], x0[1:]])), a) for a in SCALE_GRID]
    x0[0] = min(grid)[1]
    steps = [SCALE_SIMPLEX[0]] * n + [SCALE_SIMPLEX[1]] * k
    simplex = np.vstack([x0, x0 + np.diag(steps)])
    res = minimize(error, x0, method="Nelder-Mead",
                   options={"initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-14,
                            "maxfev": SCALE_EVALS})  # fmt: skip
    start = float(fit.normal.sse / windows.residuals)
    log(f"    scale search: common scale {np.exp(res.x[0]):.4f} (grid {np.exp(x0[0]):.3f}), "
        f"rest lengths {np.exp(res.x[1]):.4f}, end-cap RMS {np.sqrt(start) * 1e3:.3f} -> "
        f"{np.sqrt(min(res.fun, start)) * 1e3:.3f} mm")  # fmt: skip
    return at(res.x) if res.fun < start else (theta, windows)


def fit_on_floor(
    engine: Engine,
    vec: ParamVector,
    windows: Windows,
    theta: torch.Tensor,
    iters: int,
    state_iters: int = STATE_ITERS,
    rounds: int = ROUNDS,
    max_rounds: int = MAX_ROUNDS,
    log: Callable[[str], None] = lambda s: None,
    stuck: float | None = None,
    stuck_at_start: bool = True,
    spread: bool = False,
) -> WindowFit:
    """Declared parameters, effects and contact fitted jointly on floor ``windows``.

    ``vec`` holds the contact as its last effect with :data:`FLOOR_FREE` free
    (:func:`with_floor`); ``theta`` is where the fit starts. The first round (module
    docstring, step 2) fits the windows' states (``state_iters`` iterations per
    prefix) with the model held and searches the contact with the rest held; from
    there the contact stays within :func:`contact_box` of the searched values. Each
    later round searches the valley (:func:`search_scale`); every round ends with a
    joint Levenberg-Marquardt fit of ``iters`` iterations (the first with
    :data:`FIRST_ROUND_HELD` held at the start). ``rounds`` rounds, then more while the
    last one lowered the sum of squares by :data:`ROUND_GAIN` (``max_rounds`` in all
    at most). Returns the last joint fit.

    ``stuck`` [m]: the windows whose end-cap RMS stays above it are left out (their
    states stuck in another basin through an impact: such a window pulls the joint fit
    off the model), in every round (after the states afresh from the second on) where
    the model fits the median window within it
    (:func:`~identification.trajectory.window_errors.windows_within`). Where it fits
    fewer, the model's own error is what the windows show (a far-off start, or a model
    that cannot reach the noise, as on a real robot), and every window is kept. The
    measurements are in docs/decisions.md ("Stuck floor windows left out").
    ``stuck_at_start``: windows are left out in the first round too, at the start
    model; False where that model is the regression (off by tens of per cent: on 5-sample
    windows its median window fits within the limit while the windows above it show its
    error, not stuck states). ``spread``: the first contact search starts from the best
    of a spread of contacts (:func:`search_floor_contact`).
    """
    fit: WindowFit | None = None
    seeds = windows
    for k in range(max(rounds, max_rounds)):
        before = np.inf if fit is None else fit.history[-1]
        t0 = time.perf_counter()
        if k == 0:
            states = states_at(engine, vec, theta, windows, state_iters)
            windows = states.windows
            log(f"    states {np.sqrt(states.history[-1]) * 1e3:.3f} mm")
            if stuck is not None and stuck_at_start:
                windows = without_stuck(engine, vec, theta, windows, stuck, log, near=True)
            floor = contact_height(vec, theta)  # the start: where the caps touch, or a given contact's
            theta = search_floor_contact(engine, vec, windows, theta, log, spread)
            vec = bounded(vec, theta, floor)
        else:
            assert fit is not None
            theta, windows = search_scale(engine, vec, fit, log)
            windows = reseeded(engine, vec, theta, windows, seeds, state_iters, log)
            if stuck is not None:
                windows = without_stuck(engine, vec, theta, windows, stuck, log, near=True)
        hold = held_groups(vec, FIRST_ROUND_HELD) if k == 0 else None
        with iteration_bar(f"floor round {k + 1}: joint fit", iters) as tick:
            fit = windowed_problem.fit(WindowedProblem(engine, vec, windows, theta, hold),
                                       floor_options(iters, tick, log))
        theta, windows = fit.theta, fit.windows
        log(f"    floor round {k + 1}: joint fit {np.sqrt(fit.history[-1]) * 1e3:.3f} mm "
            f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip
        if k + 1 >= rounds and not fit.history[-1] < (1 - ROUND_GAIN) * before:
            break
    assert fit is not None
    return fit


def floor_options(
    iters: int, progress: Callable[[float], None] | None = None,
    log: Callable[[str], None] = lambda s: None,
) -> FitOptions:  # fmt: skip
    """How the floor fit's joint fits are solved: ``iters`` iterations to a Newton
    decrement of 0.1, each rod's axial spin in the window states (friction turns the
    rods about their axes), and the line search (impacts make the error jump)."""
    return FitOptions(max_iter=iters, tol=0.1, spin=True, line_search=True, progress=progress,
                      log=log)  # fmt: skip


def without_stuck(
    engine: Engine, vec: ParamVector, theta: torch.Tensor, windows: Windows, stuck: float,
    log: Callable[[str], None] = lambda s: None, near: bool = False,
) -> Windows:  # fmt: skip
    """``windows`` without those whose end-cap RMS at ``theta`` (their states as they
    are) is above ``stuck`` [m] (the better half kept where fewer are within; ``near``:
    all kept unless the median window is within, as the floor fit calls it), the
    windows left out ``log``-ged."""
    kept, err = windows_within(engine, vec, windows, theta, stuck)
    if near and not float(np.median(err)) <= stuck:
        return windows
    if kept.size < windows.size:
        out = np.sort(err)[kept.size :]
        log(f"    left out {windows.size - kept.size} of {windows.size} windows whose states "
            f"stay above {stuck * 1e3:.3g} mm ({', '.join(f'{e * 1e3:.3g}' for e in out)} mm)")
    return kept


def held_groups(vec: ParamVector, groups: Sequence[str]) -> torch.Tensor:
    """Which entries of the fitted vector (n_free + n_effect,) bool are the free
    log-parameters of ``groups`` (:class:`~identification.trajectory.windowed_problem.WindowedProblem`'s
    ``hold``; as 0/1, :func:`scale_directions`' rows)."""
    full = torch.zeros(len(vec.free), dtype=torch.bool)
    for group in groups:
        full[vec.offset(group) : vec.offset(group) + vec.sizes[group]] = True
    return torch.cat([full[vec.free], torch.zeros(vec.n_effect, dtype=torch.bool)])


def states_at(
    engine: Engine, vec: ParamVector, theta: torch.Tensor, windows: Windows, iters: int
) -> WindowFit:
    """The windows' initial states (axial spins too) fitted on growing prefixes with the
    model held at ``theta``, from three seeds, each window keeping the best: its own
    state (smoothing) and one from its first samples alone
    (:func:`~identification.trajectory.window_states.forward_seeds`), and a third:
    smoothing with each rod's axial spin searched
    (:func:`~identification.trajectory.window_states.search_spins`: a rod rolling on its
    end caps spins fast about its axis, which end caps do not show). Through impacts
    each stops in another basin in some windows, not the same ones from each seed (the
    measurements are in docs/decisions.md)."""
    eng, held = vec.engine(engine, theta), vec.held_at(theta)
    empty = torch.zeros(0, dtype=theta.dtype)
    a = fit_states(eng, held, windows, iters, spin=True)
    b = fit_states(eng, held, forward_seeds(windows, vec.axes, engine.dt), iters, spin=True)
    c = fit_states(eng, held, search_spins(eng, held, windows), iters, spin=True)
    picked, _, best = better_states(eng, held, empty, b.windows, a.windows)
    picked, _, best = better_states(eng, held, empty, c.windows, picked)
    mse = float(best.sum()) / max(picked.residuals, 1)
    return replace(a, windows=picked, history=[*a.history, mse])


def reseeded(
    engine: Engine,
    vec: ParamVector,
    theta: torch.Tensor,
    windows: Windows,
    seeds: Windows,
    state_iters: int,
    log: Callable[[str], None] = lambda s: None,
) -> Windows:
    """``windows`` with each window's state fitted afresh at ``theta`` where that fits it
    better.

    The first round fits the states at the starting model, which can be far off (a
    regression biased by smoothing through the impacts); through an impact, a state
    fitted there can stay in another basin while the joint fit moves the model, which
    then stops above the error the true model's states reach. Afresh means from ``seeds``
    (the states from smoothing) on growing prefixes at the current model; the windows are
    independent given the model, so each keeps the better of its two states. ``seeds``
    may hold windows a joint fit left out (:func:`~identification.trajectory.windowed_problem.fit`); those stay out.
    """
    at = {(int(t), int(s)): i for i, (t, s) in enumerate(zip(seeds.traj, seeds.start, strict=True))}
    seeds = seeds.take(np.array([at[int(t), int(s)] for t, s in  # a fit may leave some out
                                 zip(windows.traj, windows.start, strict=True)]))  # fmt: skip
    fresh = states_at(engine, vec, theta, seeds, state_iters).windows
    picked, now, best = better_states(engine, vec, theta, fresh, windows)
    n_better = int((best < now).sum())
    if n_better:
        m = windows.residuals
        log(f"    states afresh: {n_better} of {windows.size} windows fit better, end-cap RMS "
            f"{np.sqrt(float(now.sum()) / m) * 1e3:.3f} -> "
            f"{np.sqrt(float(best.sum()) / m) * 1e3:.3f} mm")  # fmt: skip
    return picked
