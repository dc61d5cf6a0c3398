"""The declared model on data that never leaves the floor: fitted with ground contact.

Where end caps reach a floor and no stretch of the training split is airborne long
enough to fit the declared model apart from contact
(:func:`~identification.trajectory.airborne.airborne_stretches`), the loop's starting
model holds ground contact from the start and fits it jointly with the declared
parameters (:mod:`identification.trajectory.floor_fit`). Candidate effects are
screened with the declared parameters and the contact held at this fit's values
(:func:`~identification.discovery.end_cap_fits.screen_with`); an accepted one is
refitted jointly with them, the contact's parameters
(:data:`~identification.trajectory.floor_fit.FLOOR_FREE`) free within
:func:`~identification.trajectory.floor_fit.contact_box` of the floor fit's values.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from identification.data.dataset import Dataset
from identification.defaults import FLOOR_WINDOW_S
from identification.discovery.end_cap_data import (
    STUCK_WINDOW,
    EndCapData,
    TrajectorySettings,
    TrajFit,
    declared_start,
    fit_trajectory,
    held_drag_axis,
)
from identification.discovery.library import contact_gate
from identification.linear.smoothed import parse_anchors
from identification.trajectory.airborne import has_airborne_stretch
from identification.trajectory.floor_fit import (
    FLOOR_FREE,
    STATE_ITERS,
    bounded,
    fit_on_floor,
    floor_contact,
    held_states,
    rods_leaning,
    rods_off_floor,
    states_at,
    with_floor,
)
from identification.trajectory.identifier import TrajectoryIdentifier
from identification.trajectory.param_vector import ParamVector, params_values
from identification.trajectory.stage_check import noise_level
from identification.trajectory.window_errors import windows_within
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


def windows_from_data(
    data: EndCapData, vec: ParamVector, steps: int, count: int, noise: float
) -> tuple[int, int, str]:
    """Steps and count of the floor fit's windows, chosen on the data, and a line saying why.

    A window's initial state is fitted through every contact in it, and how far a
    state fit reaches depends on the motion: the faster a structure tumbles against
    the rate, the narrower the basin of the true state. On a 1.9 m icosahedron rolling
    at up to 5 m/s, 60 Hz and 0.13 mm of noise (``plant_family`` seed 9, the true model
    held), the states of 15-sample windows fitted from smoothing stopped at 1.0 mm (median
    0.6 mm; from the true states, 0.13 mm), of 4-sample windows at 0.26 mm. So: windows
    of ``steps``, halved (down to :data:`MIN_FLOOR_STEPS` samples) while the median
    window's states, fitted at the start model, stay above
    :data:`~identification.discovery.end_cap_data.STUCK_WINDOW` times the ``noise``
    [m]; none within it: the lowest median. The count grows as the windows shrink
    (the samples fitted stay about the same, at most :data:`MAX_WINDOW_GAIN` times
    ``count``).
    """
    tried: list[tuple[float, int]] = []
    n = steps
    while True:
        w = data.cut("train", n, count, 3, lift_off=count // 2)
        fit = states_at(data.engine, vec, vec.theta0(), w, STATE_ITERS)
        err = windows_within(vec.engine(data.engine, vec.theta0()),
                             held_states(vec, vec.theta0()), fit.windows,
                             torch.zeros(0, dtype=torch.float64), np.inf)[1]  # fmt: skip
        median = float(np.median(err))
        tried.append((median, n))
        shorter = max(MIN_FLOOR_STEPS, round(n / 2))
        if median <= STUCK_WINDOW * noise or shorter >= n:
            break
        n = shorter
    median, n = tried[-1] if tried[-1][0] <= STUCK_WINDOW * noise else min(tried)
    k = min(MAX_WINDOW_GAIN * count, max(count, round(count * steps / n)))
    why = ", ".join(f"{m:d} steps {e * 1e3:.3g} mm" for e, m in sorted(tried, key=lambda x: -x[1]))
    return n, k, (f"median state fit at the start model: {why} (noise {noise * 1e3:.3g} mm)")


@dataclass(frozen=True)
class FloorFit:
    """The declared model and ground contact fitted together on the floor windows of the
    training split (``fit``, its vector bounded around the fitted contact)."""

    fit: TrajFit

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
    vec = with_floor(vec, others, begin, held_drag_axis(data))
    data.contact_free = FLOOR_FREE
    steps, count = floor_steps(data.dt, s), s.floor_windows
    if s.floor_window <= 0:  # not set: from the data
        noise = noise_level(data.train.nodes, rods=True)
        steps, count, why = windows_from_data(data, vec, steps, count, noise)
        data.log(f"    floor windows from the data: {count} of {steps} steps; {why}")
    data.floor_steps = steps
    data.log(f"    on the floor: ground contact in the model from the start (floor height "
             f"{float(begin.values['height']) * 1e3:.1f} mm from the end caps); {count} "
             f"windows of {steps} steps")  # fmt: skip
    many_windows = data.cut("train", steps, count, 3, lift_off=count // 2)
    w = fit_on_floor(data.engine, vec, many_windows, vec.theta0(), s.base_iter, log=data.log)
    vec = bounded(vec, w.theta, float(begin.values["height"].reshape(-1)[0]))
    m = w.windows.residuals
    fit = TrajFit(vec, w.theta, w.windows, w.history[-1] * m, m, w.stderr, converged=w.converged)
    fit.origin = fit.theta
    return FloorFit(fit)


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
    :func:`~identification.discovery.end_cap_fits.fit_declared`; without ``selection``
    the second is the first, not refitted).
    """
    t0 = time.perf_counter()
    floor = floor_fit(data, s, start, effects, values, contact)
    adopt_floor_fit(data, floor)
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
    :class:`GroundContact`, standard errors as its ``uncertainty``) and ``effects_`` (the
    declared effects fitted with it, such as tension-only springs).
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
    )  # fmt: skip
