"""The named fits of the multi-step scorer on end-cap windows: every fit of a model the
loop compares, accepts or writes out is one of these four presets.

Each is a :class:`~identification.trajectory.windowed_problem.WindowedProblem` solved
by :func:`~identification.trajectory.windowed_problem.fit` with the loop's options
(:func:`~identification.trajectory.end_cap_data.end_cap_options`, through
:func:`~identification.trajectory.end_cap_data.fit_trajectory`):

* **declared fit**: :func:`fit_declared`, the declared model on the many windows and on
  the training windows selection compares on (on data that never leaves the floor,
  with ground contact from the start:
  :func:`~identification.trajectory.floor_declared.fit_declared_on_floor`);
* **screen a candidate**: :func:`screen_candidate`, the candidate's coordinates and the
  windows' states fitted, the declared parameters and the contact held;
* **joint with contact**: :func:`fit_joint`, the candidate fitted jointly with the
  declared model (contact searched on the touchdowns first where it is new);
* **refit on many windows** (an accepted model, and the final refit on more of them):
  :func:`refit_many`.

What the scorer keeps of each candidate is
:class:`~identification.discovery.candidate_fits.EndCapFits`.

The declared model and every accepted one are fitted on **many** windows of the
training split (:attr:`~identification.trajectory.end_cap_data.TrajectorySettings.fit_windows`;
:func:`refit_many`): selection needs only a few windows, but the parameters written
out, the test errors and the next iteration's starting point come from this larger
fit. Without a params file the declared model starts from the regression on smoothed
end caps; its fit on the many windows brings it near the optimum before anything is
compared. On data with a floor the declared model is fitted apart from contact, on
the airborne samples and then on every **airborne stretch whole** (one window each,
however long): cut into short windows, each window's own initial state absorbs part
of the motion the parameters should explain. Once the contact is searched on the
touchdowns, the declared model is refitted on those stretches run on
:data:`PAST_TOUCHDOWN` steps past the touchdowns (contact held), then held.

Window initial states are fitted on **growing prefixes** of each window first
(:data:`~identification.trajectory.window_states.GROW`; ``fit_states``): a state
from smoothing is poor where an impact falls inside the filter's span, and on a long
window the fit may then stop in another basin.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import replace

import numpy as np
import torch

from identification.trajectory.airborne import (
    airborne_stretches,
    cap_radii,
    contact_gate,
    has_airborne_stretch,
    past_touchdown,
)
from identification.trajectory.effect_coords import EffectCoords
from identification.trajectory.end_cap_data import (
    EndCapData,
    TrajectorySettings,
    TrajFit,
    airborne_keep,
    contact_searched,
    declared_start,
    fit_trajectory,
    has_contact,
    held_drag_axis,
    hold_declared,
)
from identification.trajectory.floor_declared import fit_declared_on_floor
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.progress import iteration_bar
from identification.trajectory.touchdown import find_touchdowns, search_contact
from identification.trajectory.window_errors import windows_within
from identification.trajectory.window_states import GROW, fit_states, prefix
from identification.trajectory.windows import STATE_KEYS, Windows, sees_roll
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params

#: steps past each touchdown the declared model is refitted on, contact held
PAST_TOUCHDOWN = 150


def fit_declared(
    data: EndCapData,
    s: TrajectorySettings,
    start: Params | None = None,
    effects: Sequence[PhysicalEffect] = (),
    values: dict[str, np.ndarray] | None = None,
) -> tuple[TrajFit, TrajFit]:
    """The declared model: its fit on the many windows, and on the training windows.

    Every parameter but the anchors is fitted, first on the many windows
    (:func:`refit_many`) from ``start`` (a params file) if given, else from the
    regression on Savitzky-Golay smoothed end caps (far off on fast data: the many
    windows bring it near the optimum), then on the few training windows that
    selection compares candidates on (from there, so both fits share the origin).
    Where end caps reach a floor, the "many windows" are every airborne stretch of the
    training split, each whole (:func:`~identification.trajectory.airborne.airborne_stretches`);
    where there is none, ground contact is fitted with the declared model from the start
    (:func:`~identification.trajectory.floor_declared.fit_declared_on_floor`).

    ``effects`` are fitted with it (a hypothesis that changes the declared springs, such
    as slack cables) and ``values`` replace the stage-1 regression (natural units, as
    :func:`smoothed_regression` returns them).
    """
    # where end caps reach a floor, only samples and windows where they are airborne
    # (contact's gate closed): fitted through impacts, the declared model drifts to make
    # up for contact
    airborne = contact_gate(data.train, data.topology)[0]
    grid = {key: getattr(data.smooth["train"], key) for key in STATE_KEYS}
    if airborne and (data.on_floor or not has_airborne_stretch(data.train.nodes, data.topology)):
        # never airborne long enough to fit apart from contact: contact from the start
        return fit_declared_on_floor(data, s, start, effects, values, data.contact_start)
    vec = declared_start(data, s.anchors, start, values, keep=airborne_keep(data))
    if effects:
        vec = replace(vec, coords=EffectCoords.of(list(effects), held_drag_axis(data),
                                                  data.contact_free))  # fmt: skip
    theta = vec.theta0()
    data.declared_k = int(vec.free.sum())
    # windows of ``window`` steps: longer ones would let a model missing an effect drift
    many_windows = data.windows["fit"]
    if s.fit_window > 0 and s.fit_window != s.window:
        many_windows = data.cut("train", s.window, s.fit_windows, 3)
    # far off without a params file: shorter windows first, which forgive a rough start
    lengths = (max(10, s.window // 4), max(10, s.window // 2)) if start is None else ()
    for k, steps in enumerate((*lengths, s.window)):
        short = data.cut("train", steps, s.fit_windows * s.window // steps, 10 + k, airborne)
        if short.size == 0:
            raise InputError(f"no {steps}-step window of the training split is airborne: "
                             "the declared model cannot be fitted apart from contact")  # fmt: skip
        if steps < s.window:
            theta = fit_trajectory(data, vec, short, theta, s.base_iter).theta
        elif airborne:
            # each airborne stretch whole: far more precise than cut into windows
            stretches = airborne_stretches(data.train.nodes, data.train.control, grid,
                                           data.topology)  # fmt: skip
            many_windows = short if stretches is None else stretches
    many = refit_many(data, vec, theta, s, iters=2 * s.base_iter, windows=many_windows)
    fit = fit_trajectory(data, vec, data.windows["train"], many.theta, s.base_iter)
    fit.origin = many.theta
    if airborne and many.windows.valid is not None:
        data.stretches = many.windows
    return many, fit


def refit_many(
    data: EndCapData, vec: ParamVector, theta: torch.Tensor, s: TrajectorySettings, iters: int,
    windows: Windows | None = None, within: float | None = None, bar: str | None = None,
    stall: float | None = None,
) -> TrajFit:  # fmt: skip
    """``vec`` refitted jointly on the many windows of the training split, from ``theta``.

    The windows' states are fitted first with the model at ``theta``
    (:func:`fit_states`), so a fit on windows whose smoothed states are poor (impacts)
    starts in the right basin. ``within`` [m]: the windows whose states stay above this
    end-cap RMS are left out
    (:func:`~identification.trajectory.window_errors.windows_within`). ``bar``: the
    description of a progress bar over the joint fit's iterations. ``stall``: the joint
    fit also stops once the error stops falling
    (:class:`~identification.trajectory.windowed_problem.FitOptions`). With an effect
    that depends on the rods' roll about their axes (``sees_roll``: quadratic drag),
    each window's rolls are fitted too, in a second pass from the fit without them: from
    a drag still far below its value a joint fit of rolls and parameters stops in
    another basin. The second pass fits each rod's axial spin too: it turns the roll the
    drag sees (:mod:`identification.trajectory.window_states`). Selection's first fits
    leave the roll out: from zero drag its columns are zero. Once such an effect is
    accepted, every later fit and score fits the rolls (``data.roll``).
    """
    engine = vec.engine(data.engine, theta.detach())
    fixed = vec.held_at(theta)
    many = data.windows["fit"] if windows is None else windows
    states = fit_states(engine, fixed, many, s.state_iter, spin=data.spin, roll=data.roll)
    many = states.windows
    if within is not None:
        many, err = windows_within(engine, fixed, many, fixed.theta0(), within)
        data.log(f"    {many.size} of {err.size} windows kept: states within {within * 1e3:.3g} "
                 f"mm at the model (median {np.median(err) * 1e3:.3f}, worst "
                 f"{err.max() * 1e3:.3f} mm)")  # fmt: skip
    with iteration_bar(bar, iters) if bar else nullcontext() as tick:
        fit = fit_trajectory(data, vec, many, theta, iters, progress=tick, stall=stall)
    if sees_roll(engine) and not data.roll:
        # the rolls only matter once the effect is near its size: fitted from there
        t0 = time.perf_counter()
        engine = vec.engine(data.engine, fit.theta.detach())
        states = fit_states(engine, vec.held_at(fit.theta), fit.windows, s.state_iter, spin=True,
                            roll=True)  # fmt: skip
        fit = fit_trajectory(data, vec, states.windows, fit.theta, iters, roll=True, stall=stall)
        data.log(f"    rolls fitted too: end-cap RMS {fit.rms * 1e3:.3f} mm "
                 f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    fit.origin = fit.theta
    return fit


def fit_joint(
    data: EndCapData, current: TrajFit, effects: Sequence[PhysicalEffect], iters: int
) -> TrajFit:
    """Refit jointly with ``effects`` (contact last), from the current model's origin.

    The declared parameters start where ``current`` started (its ``origin``: the
    params file, or the accepted model's fit), not where it ended: a model without
    the missing effect drifts to compensate for it, and from there the effect may
    no longer pay. The windows start from ``current``'s fitted states.
    """
    ordered = [e for e in effects if not e.constraint]  # the contact last, as the engine
    ordered += [e for e in effects if e.constraint]
    origin = current.theta if current.origin is None else current.origin
    axis = held_drag_axis(data)
    vec = replace(current.vec, start=current.vec.full(origin.detach()),
                  coords=EffectCoords.of(ordered, axis, data.contact_free,
                                         data.contact_box))  # fmt: skip
    if contact_searched(vec):
        vec = hold_declared(vec)
    windows, theta = current.windows, vec.theta0()
    if has_contact(vec) and not has_contact(current.vec):
        # The end-cap error is discontinuous in the contact's parameters (see
        # identification.trajectory.touchdown): they come from a derivative-free search on the
        # touchdowns and are held in every fit after it. The states were fitted without
        # a floor: they are refitted on growing prefixes of the windows. Without
        # touchdowns (no trajectory starts airborne) the contact is fitted through the
        # prefixes instead: its parameters and the states, the declared ones held
        # (short prefixes cannot pin them), each stage from the last.
        searched = touchdown_contact(data, vec, theta)
        if searched is not None:
            ordered[-1] = searched
            vec = through_touchdowns(data, replace(vec, coords=EffectCoords.of(ordered, axis, ())),
                                      iters)  # fmt: skip
            theta = vec.theta0()
        n_free = vec.n_free
        for n in [g for g in GROW if g < windows.steps] + [windows.steps]:
            fixed = vec.held_at(theta)
            part = fit_states(vec.engine(data.engine, theta), fixed, prefix(windows, n),
                              iters).windows  # fmt: skip
            if n < windows.steps and searched is None:
                only = replace(fixed, coords=vec.coords)
                tail = fit_trajectory(data, only, part, theta[n_free:], iters).theta
                theta = torch.cat([theta[:n_free], tail])
            windows = replace(windows, state=part.state)
    fit = fit_trajectory(data, vec, windows, theta, iters)
    fit.origin = fit.theta
    return fit


def screen_candidate(
    data: EndCapData, current: TrajFit, effects: Sequence[PhysicalEffect], iters: int
) -> TrajFit:
    """A candidate screened on the floor: ``effects`` fitted with the declared parameters
    and the contact held at ``current``'s fit.

    Only the linear effects' coordinates (the candidate's and those already in the
    model) and the windows' states are fitted, from ``current``'s fitted states, so a
    candidate costs a fraction of a joint fit and cannot trade the contact against its
    own parameters. The result is in the joint layout (declared parameters and contact
    coordinates at ``current``'s values, free; ``origin`` there), so an accepted
    candidate is refitted jointly from it and the BIC counts every parameter of the
    joint model. ``current``'s vector holds the contact as its last effect.
    """
    ordered = [e for e in effects if not e.constraint]
    contact = [e for e in effects if e.constraint]
    axis = held_drag_axis(data)
    theta = current.theta.detach()
    n = current.vec.n_free
    joint = replace(current.vec, start=current.vec.full(theta),
                    coords=EffectCoords.of(ordered + contact, axis, data.contact_free,
                                           data.contact_box))  # fmt: skip
    only = replace(joint, free=torch.zeros_like(joint.free),
                   coords=EffectCoords.of(ordered + contact, axis, ()))  # fmt: skip
    fit = fit_trajectory(data, only, current.windows, only.theta0(), iters)
    k = joint.n_effect - only.n_effect  # the contact's coordinates, held here
    tail = joint.theta0()[len(joint.theta0()) - k :]
    full = torch.cat([theta[:n], fit.theta.detach(), tail])
    se = np.concatenate([current.stderr[:n], fit.stderr, current.stderr[len(current.stderr) - k :]])
    out = TrajFit(joint, full, fit.windows, fit.sse, fit.m, se, extra_k=current.extra_k)
    out.origin = full
    return out


def through_touchdowns(data: EndCapData, vec: ParamVector, iters: int) -> ParamVector:
    """``vec`` (contact held) with the declared parameters refitted, then held.

    The airborne stretches the declared model was fitted on are run on
    :data:`PAST_TOUCHDOWN` steps past their touchdowns, with the searched contact: the
    impacts ring the springs, which says more about damping. Not longer: each window
    has one initial state, which fits worse the more impacts follow it.
    """
    if data.stretches is None:
        return hold_declared(vec)
    t0 = time.perf_counter()
    theta = vec.theta0()
    windows = past_touchdown(data.stretches, data.train.nodes, PAST_TOUCHDOWN)
    states = fit_states(vec.engine(data.engine, theta), vec.held_at(theta), windows, iters)
    fit = fit_trajectory(data, vec, states.windows, theta, iters)
    data.log(f"    declared model refitted {PAST_TOUCHDOWN} steps past the touchdowns (contact "
             f"held): end-cap RMS {fit.rms * 1e3:.3f} mm ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    assert vec.coords is not None
    effects = vec.coords.effects_at(fit.theta[vec.n_free :].detach())
    moved = replace(vec, start=vec.full(fit.theta.detach()),
                    coords=EffectCoords.of(effects, held_drag_axis(data), ()))  # fmt: skip
    return hold_declared(moved)


def touchdown_contact(
    data: EndCapData, vec: ParamVector, theta: torch.Tensor
) -> GroundContact | None:
    """The contact of ``vec`` (its last effect) searched on the touchdowns, or None.

    The declared parameters and the other effects are held at ``theta``. After a search
    the contact is held in every later fit (``data.contact_free``).
    """
    assert vec.coords is not None
    effects = vec.coords.effects_at(theta[vec.n_free :].detach())
    others, contact = effects[:-1], effects[-1]
    assert isinstance(contact, GroundContact)  # narrowing: fits append the floor contact last
    fixed = vec.held_at(theta)
    engine = data.engine.with_effects(others)
    radius = cap_radii(data.topology)
    grid = {k: getattr(data.smooth["train"], k) for k in STATE_KEYS}
    t0 = time.perf_counter()
    touch = find_touchdowns(engine, fixed, data.train.nodes, data.train.control, grid, radius)
    if touch is None:
        return None
    data.log(f"    ground_contact: {touch.size} touchdowns (airborne prefixes fitted to "
             f"{touch.prefix_rms * 1e3:.3f} mm)")  # fmt: skip
    found = search_contact(engine, fixed.params(fixed.start), others, contact, touch, data.log)
    data.log(f"    touchdown search: {found.evaluations} rollouts "
             f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    data.contact_free = ()
    return found.contact
