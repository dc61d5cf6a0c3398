"""The declared model on data that never leaves the floor: fitted with ground contact.

Where end caps reach a floor and no stretch of the training split is airborne long
enough to fit the declared model apart from contact
(:func:`~identification.trajectory.airborne.airborne_stretches`), the loop's starting
model holds ground contact from the start and fits it jointly with the declared
parameters (:mod:`identification.trajectory.floor_fit`). Candidate effects are
screened with the declared parameters and the contact held at this fit's values
(:func:`~identification.trajectory.presets.screen_candidate`); an accepted one is
refitted jointly with them, the contact's parameters
(:data:`~identification.trajectory.floor_fit.FLOOR_FREE`) free within
:func:`~identification.trajectory.floor_fit.contact_box` of the floor fit's values.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from identification.data.dataset import Dataset
from identification.defaults import FLOOR_WINDOW_S
from identification.linear.smoothed import parse_anchors
from identification.trajectory.airborne import contact_gate, has_airborne_stretch
from identification.trajectory.cap_radius_fit import fit_cap_radii, resting_pieces
from identification.trajectory.end_cap_data import (
    STUCK_WINDOW,
    EndCapData,
    TrajectorySettings,
    TrajFit,
    declared_start,
    fit_trajectory,
    held_drag_axis,
)
from identification.trajectory.floor_fit import (
    FLOOR_FREE,
    STATE_ITERS,
    bounded,
    fit_on_floor,
    floor_contact,
    rods_leaning,
    rods_off_floor,
    states_at,
    with_floor,
)
from identification.trajectory.identifier import TrajectoryIdentifier
from identification.trajectory.param_vector import ParamVector, params_values
from identification.trajectory.stage_check import noise_level
from identification.trajectory.window_errors import windows_within
from identification.trajectory.windowed_fit import WindowFit
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology


def floor_steps(dt: float, s: TrajectorySettings) -> int:
    """Steps per window of the fits on the floor, at ``dt`` [s] between samples:
    ``s.floor_window`` where set, else ``s.fit_window`` (or ``s.window``) capped at
    :data:`FLOOR_WINDOW_S` (at least 2). The floor fit may shorten it
    (:func:`windows_from_data`)."""
    if s.floor_window > 0:
        return max(2, s.floor_window)
    return max(2, min(s.fit_window or s.window, round(FLOOR_WINDOW_S / dt)))


#: the floor fit's windows are shortened down to no fewer samples than this
#: (:func:`windows_from_data`)
MIN_FLOOR_STEPS = 4
#: and their count raised to keep the samples fitted, by at most this factor
MAX_WINDOW_GAIN = 4
#: the share of longer windows whose states must fit (not stuck) for the floor fit to
#: go on to them: the fit leaves the stuck ones out, and half of them still carry it
USABLE_SHARE = 0.5
#: the share of the next longer windows whose states must fit for the floor fit to step
#: up to them when no longer length reaches :data:`USABLE_SHARE` (a continuation: the fit
#: there brings the model near enough for the next)
NEXT_SHARE = 0.25
#: the random stream of the training windows that judge the first fits where the data has
#: no validation split (the fits' own windows are stream 3)
JUDGE_STREAM = 4
#: a rod's unknowns in a window's state fit: position, orientation and their rates
ROD_STATE = 12


def state_fit_ratio(steps: int) -> float:
    """The RMS a window's state fit leaves at the true model, as a fraction of the noise.

    A window of ``steps`` steps holds ``steps + 1`` samples of a rod's 6 end-cap
    coordinates against :data:`ROD_STATE` state unknowns, and a least-squares fit
    absorbs that many of the noise's degrees of freedom: ``sqrt(1 - 12 / (6 (steps + 1)))``
    (0.77 on 4 steps, 0.97 on 30), so short windows look closer to the noise than
    they are.
    """
    n = 6 * (steps + 1)
    return float(np.sqrt(max(n - ROD_STATE, 1) / n))


def halvings(steps: int) -> list[int]:
    """``steps`` and its halvings down to :data:`MIN_FLOOR_STEPS`, longest first."""
    out = [steps]
    while (shorter := max(MIN_FLOOR_STEPS, round(out[-1] / 2))) < out[-1]:
        out.append(shorter)
    return out


def state_fits(
    data: EndCapData,
    vec: ParamVector,
    theta: torch.Tensor,
    lengths: Sequence[int],
    count: int,
    noise: float,
    split: str = "train",
    stream: int = 3,
) -> list[tuple[float, int, float]]:
    """The median state fit [m] of ``count`` windows of split ``split`` (random
    ``stream``: 3 draws the floor fit's own training windows) of each of ``lengths``
    steps (longest first) with the model held at ``theta``, the length, and the share
    of the windows whose state fit is within :data:`STUCK_WINDOW` times the ``noise``
    (the others' states are stuck: the floor fit leaves them out); it stops at
    the first length whose median is within :data:`STUCK_WINDOW` times the ``noise``
    [m] scaled by :func:`state_fit_ratio` (the last tried is then the one chosen)."""
    tried: list[tuple[float, int, float]] = []
    engine, held = vec.engine(data.engine, theta), vec.held_at(theta)
    for n in lengths:
        w = data.cut(split, n, count, stream, lift_off=count // 2)
        fit = states_at(data.engine, vec, theta, w, STATE_ITERS)
        err = windows_within(engine, held, fit.windows, torch.zeros(0, dtype=torch.float64),
                             np.inf)[1]  # fmt: skip
        tried.append((float(np.median(err)), n, float(np.mean(err <= STUCK_WINDOW * noise))))
        if within(tried[-1], noise):
            break
    return tried


def within(tried: tuple[float, int, float], noise: float) -> bool:
    """Whether a median state fit ``(median [m], steps, share)`` is within :data:`STUCK_WINDOW`
    times the ``noise`` [m] left by a fit at the true state (:func:`state_fit_ratio`)."""
    median, n = tried[:2]
    return median <= STUCK_WINDOW * noise * state_fit_ratio(n)


def window_count(count: int, steps: int, n: int, share: float = 1.0) -> int:
    """Windows of ``n`` steps fitting about the samples of ``count`` of ``steps``, and
    more by one over the ``share`` of windows whose states fit (the others are left
    out), at most :data:`MAX_WINDOW_GAIN` times ``count``."""
    gain = steps / n / max(share, 0.5)
    return min(MAX_WINDOW_GAIN * count, max(count, round(count * gain)))


def describe(tried: Sequence[tuple[float, int, float]], noise: float) -> str:
    """The state fits tried, longest first, against the noise [m], and the share of
    windows within of the last."""
    why = ", ".join(
        f"{m:d} steps {e * 1e3:.3g} mm" for e, m, _ in sorted(tried, key=lambda x: -x[1])
    )
    share = f"; {100 * tried[-1][2]:.0f} % of the windows within {STUCK_WINDOW:g} of it"
    return f"{why} (noise {noise * 1e3:.3g} mm{share if within(tried[-1], noise) else ''})"


def windows_from_data(
    data: EndCapData, vec: ParamVector, steps: int, count: int, noise: float
) -> tuple[list[tuple[int, int]], str]:
    """Steps and count of the floor fit's first windows, chosen on the data: one choice,
    or several to fit and compare (:func:`first_floor_fit`), and a line saying why.

    A window's initial state is fitted through every contact in it, and how far a
    state fit reaches depends on the motion: the faster a structure tumbles against
    the rate, the narrower the basin of the true state, and shorter windows fit from
    smoothing closer to it (the measurement is in docs/decisions.md). So: windows
    of ``steps``, halved (down to :data:`MIN_FLOOR_STEPS` samples) while the median
    window's states, fitted at the start model, stay above
    :data:`~identification.trajectory.end_cap_data.STUCK_WINDOW` times
    the ``noise`` [m] (:func:`within`): the first length within it is the one choice.
    Where none is, the start model's own error is what the windows show (a far-off
    start, or a model that cannot reach the noise, as on a real robot) and the medians
    cannot tell a stuck state from that error: every length whose median, against its
    :func:`state_fit_ratio`, is within ``STUCK_WINDOW`` times the lowest is a choice
    (the lowest first).
    The count grows as the windows shrink (:func:`window_count`). At a start model far
    from the plant, long windows miss for the model's error rather than the state's
    basin: :func:`floor_fit` goes on to longer windows from its fit
    (:func:`longer_windows`).
    """
    tried = state_fits(data, vec, vec.theta0(), halvings(steps), count, noise)
    why = f"median state fit at the start model: {describe(tried, noise)}"
    if within(tried[-1], noise):
        best = tried[-1]
        return [(best[1], window_count(count, steps, best[1], best[2]))], why
    scaled = [t[0] / state_fit_ratio(t[1]) for t in tried]
    order = np.argsort(scaled, kind="stable")  # the lowest first: kept on a tie
    near = [tried[i] for i in order if scaled[i] <= STUCK_WINDOW * min(scaled)]
    return [(t[1], window_count(count, steps, t[1])) for t in near], why


def first_floor_fit(
    data: EndCapData,
    vec: ParamVector,
    choices: Sequence[tuple[int, int]],
    longest: int,
    count: int,
    noise: float,
    iters: int,
    stuck_at_start: bool = True,
    spread: bool = False,
) -> tuple[WindowFit, int]:
    """The floor fit's first fit (:func:`~identification.trajectory.floor_fit.fit_on_floor`
    of ``iters`` iterations from the start, ``stuck_at_start`` and ``spread`` as there)
    on each of ``choices`` (steps, count), and
    the steps of the one kept: the only one, else the one whose model fits the states
    of ``count`` windows of ``longest`` steps best (:func:`judged`) on the validation
    split, which no choice was fitted on (on
    training windows the fits did not use where there is none; each choice's own
    windows' error cannot be compared across lengths, and the longest choice's would be
    judged on its own windows). Longer windows hold more of the motion between
    contacts, so the model that carries the states furthest is the one that explains
    the motion, not the one that fits short pieces of it.
    """
    fits: list[tuple[float, WindowFit, int]] = []
    for steps, n in choices:
        windows = data.cut("train", steps, n, 3, lift_off=n // 2)
        w = fit_on_floor(data.engine, vec, windows, vec.theta0(), iters, log=data.log,
                         stuck=STUCK_WINDOW * noise, stuck_at_start=stuck_at_start,
                         spread=spread)  # fmt: skip
        if len(choices) == 1:
            return w, steps
        score, where = judged(data, vec, w.theta, longest, count, noise)
        data.log(f"    first fit on {n} windows of {steps} steps: median state fit on "
                 f"{where} {score * 1e3:.3g} mm")  # fmt: skip
        fits.append((score, w, steps))
    score, w, steps = min(fits, key=lambda f: f[0])
    data.log(f"    kept the fit on windows of {steps} steps (median {score * 1e3:.3g} mm on "
             f"{where})")  # fmt: skip
    return w, steps


def judged(
    data: EndCapData, vec: ParamVector, theta: torch.Tensor, longest: int, count: int,
    noise: float,
) -> tuple[float, str]:  # fmt: skip
    """How well the floor model at ``theta`` carries the motion: the median state fit [m]
    (:func:`state_fits`) of ``count`` windows of ``longest`` steps of the validation split
    (training windows the fits do not use, where there is none; inf where it is not
    finite), and those windows in words."""
    split, stream = ("val", 3) if "val" in data.dataset.splits else ("train", JUDGE_STREAM)
    score = state_fits(data, bounded(vec, theta), theta, [longest], count, noise, split,
                       stream)[0][0]  # fmt: skip
    return (score if np.isfinite(score) else np.inf), f"{split} windows of {longest} steps"


def longer_windows(
    data: EndCapData,
    vec: ParamVector,
    theta: torch.Tensor,
    steps: int,
    now: int,
    count: int,
    noise: float,
) -> tuple[int, int, str] | None:
    """Windows longer than ``now`` steps (of ``steps`` and its :func:`halvings`) to fit
    next at the fitted model ``theta``: the longest of which at least
    :data:`USABLE_SHARE` have states that fit within :data:`STUCK_WINDOW` times the
    ``noise`` [m] (the fit leaves the stuck ones out, so these windows carry it), else
    the next length up if at least :data:`NEXT_SHARE` of its windows do (one fit there
    carries the model far enough for the next); their steps, count (:func:`window_count`
    of ``count`` of ``steps``) and a line saying why; None where neither is. Longer
    windows span more of the motion between contacts, which pins the parameters'
    scale that a few samples cannot."""
    lengths = [n for n in halvings(steps) if n > now]
    if not lengths:
        return None
    tried = state_fits(data, bounded(vec, theta), theta, lengths, count, noise)
    why = f"median state fit at the fitted model: {describe(tried, noise)}"
    usable = [t for t in tried if t[2] >= USABLE_SHARE]
    nearest = min(tried, key=lambda t: t[1])
    if usable:
        share, n = usable[0][2], usable[0][1]
    elif nearest[1] == min(lengths) and nearest[2] >= NEXT_SHARE:
        share, n = nearest[2], nearest[1]
    else:
        data.log(f"    floor windows stay at {now} steps; {why}")
        return None
    why += f"; {100 * share:.0f} % of the {n}-step windows within {STUCK_WINDOW:g} of it"
    return n, window_count(count, steps, n, share), why


def rms_of(w: WindowFit) -> float:
    """A window fit's end-cap RMS [m] at its last iteration."""
    return float(np.sqrt(w.history[-1]))


def kept_longer(shorter: WindowFit, longer: WindowFit, noise: float) -> bool:
    """Whether the fit on longer windows replaces the one on shorter windows: unless it
    ends above both the shorter fit's end-cap RMS and :data:`STUCK_WINDOW` times the
    ``noise`` [m] (windows whose states it could not fit, which the stuck rule kept
    because too few of them were within, pulled it off)."""
    return rms_of(longer) <= max(rms_of(shorter), STUCK_WINDOW * noise)


def windowed_floor_fit(
    data: EndCapData,
    vec: ParamVector,
    s: TrajectorySettings,
    choices: Sequence[tuple[int, int]],
    longest: int,
    count: int,
    noise: float,
    stuck_at_start: bool = True,
    spread: bool = False,
) -> tuple[WindowFit, int]:
    """The floor fit from ``vec``'s start: the first fit on each of ``choices``
    (:func:`first_floor_fit`, ``stuck_at_start`` and ``spread`` as there), then on to
    longer windows (up to ``longest`` steps; ``spread`` in their contact searches too)
    from its fit while their states fit
    (:func:`longer_windows`, :func:`kept_longer`; only where ``s.floor_window`` is not
    set). Returns the last fit kept and its window steps."""
    w, steps = first_floor_fit(data, vec, choices, longest, count, noise, s.base_iter,
                               stuck_at_start, spread)  # fmt: skip
    while s.floor_window <= 0 and steps < longest:  # on to longer windows from the fit
        longer = longer_windows(data, vec, w.theta, longest, steps, count, noise)
        if longer is None:
            break
        n, many, why = longer
        data.log(f"    floor windows from the fit: {many} of {n} steps; {why}")
        many_windows = data.cut("train", n, many, 3, lift_off=many // 2)
        longer_fit = fit_on_floor(data.engine, vec, many_windows, w.theta, s.base_iter,
                                  log=data.log, stuck=STUCK_WINDOW * noise,
                                  spread=spread)  # fmt: skip
        if not kept_longer(w, longer_fit, noise):
            data.log(f"    floor windows stay at {steps} steps: the fit on {n}-step windows "
                     f"ends at {rms_of(longer_fit) * 1e3:.3g} mm, above both "
                     f"{rms_of(w) * 1e3:.3g} mm on {steps} steps and {STUCK_WINDOW:g} "
                     "noise levels (stuck windows it kept)")  # fmt: skip
            break
        w, steps = longer_fit, n
    return w, steps


#: the largest relative difference of a mass, inertia or stiffness between the floor
#: fit's two starts above which the model is written with a warning: the default start's
#: tolerance on those groups (of two fits further apart, one is off by more than half of it)
STARTS_APART = 0.03
#: the groups the two starts are compared on: those the end caps pin
COMPARED = ("mass", "inertia_perp", "stiffness")


@dataclass(frozen=True)
class StartCheck:
    """The floor fit from its two starts, compared: the parameter of :data:`COMPARED`
    whose values differ most (``name``, ``difference``: ``exp |log a - log b| - 1``),
    each start's :func:`judged` score [m] (``judged``: first, second) and which start's
    fit is kept (``kept``: 0 the regression's contact, 1 the spread of contacts; the
    lower score, the first on a tie), ``where``: the judge's windows in words."""

    name: str
    difference: float
    judged: tuple[float, float]
    kept: int
    where: str

    @property
    def apart(self) -> bool:
        """Whether the two starts end in models more than :data:`STARTS_APART` apart:
        the data, or the fit, does not single out one model."""
        return not self.difference <= STARTS_APART

    def line(self) -> str:
        """One line: how far apart the starts end and which is kept."""
        a, b = (f"{x * 1e3:.3g} mm" for x in self.judged)
        verdict = (f"more than {100 * STARTS_APART:g} % apart: two minima"
                   if self.apart else f"within {100 * STARTS_APART:g} %")  # fmt: skip
        return (f"floor fit's two starts: largest difference {self.name} "
                f"{100 * self.difference:.3g} % ({verdict}); median state fit on {self.where} "
                f"{a} and {b}, kept the {('first', 'second')[self.kept]}")  # fmt: skip

    def as_dict(self) -> dict[str, Any]:
        """The check as a params file's provenance holds it."""
        return {"largest_difference": {"name": self.name, "relative": self.difference},
                "judged_m": list(self.judged), "judged_on": self.where,
                "kept": ("first", "second")[self.kept], "apart": self.apart,
                "limit": STARTS_APART}  # fmt: skip


def largest_difference(vec: ParamVector, a: torch.Tensor, b: torch.Tensor) -> tuple[str, float]:
    """The entry of :data:`COMPARED` whose values at fitted vectors ``a`` and ``b`` differ
    most, and by how much (``exp |log a - log b| - 1``)."""
    gap = (vec.full(a.detach()) - vec.full(b.detach())).abs()
    names = vec.names()
    picked = [i for i, n in enumerate(names) if n.split("[")[0] in COMPARED]
    i = max(picked, key=lambda j: float(gap[j]))
    return names[i].replace("inertia_perp", "inertia"), float(torch.expm1(gap[i]))


def compare_starts(
    data: EndCapData, vec: ParamVector, thetas: Sequence[torch.Tensor], longest: int,
    count: int, noise: float,
) -> StartCheck:  # fmt: skip
    """The floor fit's two fitted vectors ``thetas`` compared (:class:`StartCheck`): how
    far apart, and each one's :func:`judged` score on the same windows."""
    name, difference = largest_difference(vec, thetas[0], thetas[1])
    scores = [judged(data, vec, t, longest, count, noise) for t in thetas]
    kept = int(scores[1][0] < scores[0][0])
    return StartCheck(name, difference, (scores[0][0], scores[1][0]), kept, scores[0][1])


@dataclass(frozen=True)
class FloorFit:
    """The declared model and ground contact fitted together on the floor windows of the
    training split (``fit``, its vector bounded around the fitted contact) and, where it
    started from the regression, its two starts compared (``starts``)."""

    fit: TrajFit
    starts: StartCheck | None = None

    @property
    def box(self) -> dict[str, tuple[float, float]]:
        """The range each contact parameter may move in later joint fits
        (:func:`~identification.trajectory.floor_fit.contact_box` of the fitted values)."""
        coords = self.fit.vec.coords
        assert coords is not None
        return {k: (lo, hi) for k, lo, hi in coords.box}


def floor_fit(
    data: EndCapData,
    s: TrajectorySettings,
    start: Params | None = None,
    effects: Sequence[PhysicalEffect] = (),
    values: dict[str, np.ndarray] | None = None,
    contact: GroundContact | None = None,
) -> FloorFit:
    """The declared model and ground contact (and ``effects``) fitted together on
    ``s.floor_windows`` windows of the training split, each at most
    :data:`~identification.defaults.FLOOR_WINDOW_S` long, half of them
    starting in the air where the data has such windows.

    The declared parameters start from ``values`` (a regression), else ``start`` (a
    params file), else the regression on the rods away from the floor; the contact from
    the one in ``effects``, else ``contact`` (a params file's), else the default start.
    The fit's windows and contact range are returned, not kept in ``data``
    (:func:`adopt_floor_fit` does that).
    """
    data.on_floor = True
    vec = declared_start(data, s.anchors, start, values, rod_keep=floor_rows(data))
    data.declared_k = int(vec.free.sum())
    others = [e for e in effects if not e.constraint]
    given = [e for e in effects if e.constraint]
    begin = floor_contact(data.topology, data.train.nodes, given[0] if given else contact)
    rest = resting_pieces(data.dataset, "train")
    begin = rest_radii(data, vec.params(vec.full(vec.theta0())), others, begin, rest)
    vec = with_floor(vec, others, begin, held_drag_axis(data))
    data.contact_free = FLOOR_FREE
    longest, count0 = floor_steps(data.dt, s), s.floor_windows
    steps, count = longest, count0
    noise = noise_level(data.train.nodes, rods=True)
    choices = [(steps, count)]
    if s.floor_window <= 0:  # not set: from the data
        choices, why = windows_from_data(data, vec, longest, count0, noise)
        said = " or ".join(f"{n} of {m} steps" for m, n in choices)
        data.log(f"    floor windows from the data: {said}; {why}")
    data.log(f"    on the floor: ground contact in the model from the start (floor height "
             f"{float(begin.values['height']) * 1e3:.1f} mm from the end caps); "
             + " or ".join(f"{n} windows of {m} steps" for m, n in choices))  # fmt: skip
    # the regression's misfit on a window is its own error, not a stuck state
    from_regression = start is None and values is None
    fits = [windowed_floor_fit(data, vec, s, choices, longest, count0, noise,
                               stuck_at_start=not from_regression)]  # fmt: skip
    check = None
    if from_regression and s.second_start:
        data.log("    the floor fit again, from its second start (the contact search from a "
                 "spread of soft contacts)")  # fmt: skip
        fits.append(windowed_floor_fit(data, vec, s, choices, longest, count0, noise,
                                       stuck_at_start=False, spread=True))  # fmt: skip
        check = compare_starts(data, vec, [f[0].theta for f in fits], longest, count0, noise)
        data.log(f"    {check.line()}")
    w, steps = fits[check.kept if check is not None else 0]
    data.floor_steps = steps
    vec = bounded(vec, w.theta, float(begin.values["height"].reshape(-1)[0]))
    m = w.windows.residuals
    fit = TrajFit(vec, w.theta, w.windows, w.history[-1] * m, m, w.stderr, converged=w.converged)
    *fitted_others, last = fit.effects
    assert vec.coords is not None and isinstance(last, GroundContact)  # as bounded's
    fitted = rest_radii(data, fit.params, fitted_others, last, rest)
    if not fitted.default_radius():  # the fitted radii, in the contact the fit's coordinates move
        last = vec.coords.effects[-1].with_values(cap_radius=fitted.radius)
        if "cap_radius" in fitted.uncertainty:
            last.uncertainty["cap_radius"] = fitted.uncertainty["cap_radius"]
        vec = replace(vec, coords=replace(vec.coords, effects=(*vec.coords.effects[:-1], last)))
        fit = TrajFit(
            vec, w.theta, w.windows, w.history[-1] * m, m, w.stderr, converged=w.converged
        )
    fit.origin = fit.theta
    return FloorFit(fit, check)


def rest_radii(data: EndCapData, params: Params, others: Sequence[PhysicalEffect],
               contact: GroundContact, rest: list[np.ndarray]) -> GroundContact:  # fmt: skip
    """``contact`` with each end cap's radius the resting pieces ``rest`` show (end caps
    (T, 2R, 3) [m]; :func:`~identification.trajectory.cap_radius_fit.fit_cap_radii` with
    ``params`` and the ``others`` effects, where it lowers their residual), logged; as
    given without resting pieces."""
    found = fit_cap_radii(data.engine, params, [*others, contact], rest) if rest else None
    if found is None:
        return contact
    for line in found.lines():
        data.log(f"    {line}")
    return found.contact


def adopt_floor_fit(data: EndCapData, floor: FloorFit) -> None:
    """Later fits use ``floor``'s windows (as the many training windows) and contact range."""
    data.windows["fit"] = floor.fit.windows
    data.contact_box = floor.box


def fit_declared_on_floor(
    data: EndCapData,
    s: TrajectorySettings,
    start: Params | None = None,
    effects: Sequence[PhysicalEffect] = (),
    values: dict[str, np.ndarray] | None = None,
    contact: GroundContact | None = None,
    selection: bool = True,
) -> tuple[TrajFit, TrajFit]:
    """The declared model and ground contact (and ``effects``) fitted together
    (:func:`floor_fit`, starts as there), adopted for the later fits.

    Returns the fit on the many windows of the training split and the fit on the
    training windows selection compares on (as
    :func:`~identification.trajectory.presets.fit_declared`; without ``selection``
    the second is the first, not refitted).
    """
    t0 = time.perf_counter()
    floor = floor_fit(data, s, start, effects, values, contact)
    adopt_floor_fit(data, floor)
    data.starts = floor.starts or data.starts
    many = fit = floor.fit
    if selection:
        data.lift_off_selection()
        fit = fit_trajectory(data, many.vec, data.windows["train"], many.theta, s.base_iter)
        fit.origin = many.theta
    data.log(f"    declared model and contact on {many.windows.size} floor windows: end-cap "
             f"RMS {many.rms * 1e3:.3f} mm ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    return many, fit


def floor_rows(data: EndCapData) -> np.ndarray:
    """The rods' equations the regressions use on the floor: rods away from it, (N, T, R)."""
    return rods_off_floor(data.train.nodes, data.topology, data.sg)


def leaning_rows(data: EndCapData) -> dict[str, np.ndarray]:
    """:func:`floor_rows` and, for each rod that leans on the floor with one end cap
    while its other stays clear, its moment equations about the contact point
    (``smoothed_regression``'s ``rod_keep``, ``pivots``, ``radius``)."""
    nodes, topo = data.train.nodes, data.topology
    return {"rod_keep": floor_rows(data), "pivots": rods_leaning(nodes, topo, data.sg),
            "radius": np.array([r.radius for r in topo.rods])}  # fmt: skip


def on_floor(dataset: Dataset, split: str = "train") -> bool:
    """Whether ``split``'s end caps reach a floor and no stretch is airborne long enough
    to fit the declared model apart from contact."""
    s = dataset.split(split)
    return contact_gate(s, dataset.topology)[0] and not has_airborne_stretch(
        s.nodes, dataset.topology
    )


@dataclass
class FloorIdentification:
    """``identify`` on floor data: the declared parameters and the contact fitted together.

    The attributes mirror :class:`~identification.trajectory.identifier.TrajectoryIdentifier`'s
    (``params_``, ``topology_``, ``stderr_`` relative per free parameter, ``mode_``,
    ``notes_``, ``rms_`` [m], ``converged_``, ``stages_``), plus ``contact_`` (the fitted
    :class:`GroundContact`, standard errors as its ``uncertainty``), ``effects_`` (the
    declared effects fitted with it, such as tension-only springs) and ``starts_`` (the
    floor fit's two starts compared; None where it started from a params file or ran
    from one start).
    """

    params_: Params
    topology_: Topology
    stderr_: dict[str, float]
    mode_: str
    notes_: dict[str, str]
    rms_: float
    converged_: bool
    stages_: list[dict[str, Any]]
    contact_: GroundContact
    effects_: list[PhysicalEffect] = field(default_factory=list)
    starts_: StartCheck | None = None


def identify_on_floor(
    dataset: Dataset,
    settings: TrajectorySettings,
    split: str = "train",
    log: Callable[[str], None] = print,
    start: Params | None = None,
    contact: GroundContact | None = None,
    effects: Sequence[PhysicalEffect] = (),
) -> FloorIdentification:
    """The declared model and ground contact fitted on ``split``'s end caps
    (:func:`fit_declared_on_floor`: ``settings.floor_windows`` windows of
    :func:`floor_steps`), as ``identify`` reports it; from ``start`` and ``contact``
    (a params file's) where given, as :func:`floor_fit`, with the declared ``effects``
    (tension-only springs) in the model."""
    if split != "train":
        splits = {**dataset.splits, "train": dataset.split(split)}
        dataset = Dataset(dataset.topology, dataset.dt, splits, dataset.attrs)
    data = EndCapData(dataset, settings)
    data.log = log
    many, _ = fit_declared_on_floor(data, settings, start=start, effects=effects, contact=contact,
                                    selection=False)  # fmt: skip
    vec, topo = many.vec, dataset.topology
    ident = TrajectoryIdentifier(anchors=settings.anchors)
    has_control = bool(np.any(data.train.control != 0))
    ident.start_vector(topo, data.axes, params_values(many.params, data.axes),
                       parse_anchors(topo, settings.anchors), has_control)  # fmt: skip
    names = vec.names()
    free = torch.nonzero(vec.free)[:, 0].tolist()
    stderr = {names[i]: float(s) for i, s in zip(free, many.stderr[: len(free)], strict=True)}
    fitted = many.effects[-1]
    assert isinstance(fitted, GroundContact)  # narrowing: fits append the floor contact last
    stages = [{"window": many.windows.steps, "windows": many.windows.size, "floor": True,
               "rms": many.rms}]  # fmt: skip
    return FloorIdentification(
        params_=many.params, topology_=topo, stderr_=stderr, mode_=ident.mode_,
        notes_=TrajectoryIdentifier.notes(topo, data.axes, has_control), rms_=many.rms,
        converged_=True, stages_=stages, contact_=fitted, effects_=list(many.effects[:-1]),
        starts_=data.starts,
    )  # fmt: skip
