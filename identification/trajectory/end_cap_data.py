"""End-cap windows and the fits the multi-step scorer compares: the data, the settings,
a fitted model (:class:`TrajFit`), and held-out scores.

Models are fitted through the engine on windows of the measured end caps (the
windowed trajectory fit of :mod:`identification.trajectory.identifier`: maximum
likelihood under Gaussian position noise), each candidate's effect parameters
appended to the fitted vector (:class:`~identification.trajectory.effect_coords.EffectCoords`).
A held-out score fits only the windows' initial states, the model held
(:func:`heldout`). In flight the rods' **axial spins** are not fitted until a roll is:
under millimetre noise the spin is barely seen, and a fit free to step to large spins
meets the explicit gyroscopic integration's (as in MuJoCo's Euler integrator) blow-up
on long windows.
A rod's **roll** about its own axis is fitted once an effect that depends on it is in
the model (:attr:`EndCapData.roll`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from identification.data.dataset import Dataset, Split
from identification.data.end_caps import RodAxes, odd_window, smooth_rod_states
from identification.defaults import FINAL_FLOOR_WINDOWS, FINAL_ITERATIONS, FLOOR_WINDOWS
from identification.linear.smoothed import parse_anchors, smoothed_regression
from identification.trajectory.airborne import AIRBORNE, airborne_samples, cap_radii, contact_gate
from identification.trajectory.effect_coords import CONTACT_FREE
from identification.trajectory.fitted_model import FittedModel
from identification.trajectory.identifier import TrajectoryIdentifier
from identification.trajectory.param_vector import ParamVector, params_values
from identification.trajectory.window_errors import better_states
from identification.trajectory.window_states import fit_states
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
from identification.trajectory.windows import STATE_KEYS, Windows, cut_windows, end_caps
from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import PHYSICS_DT, Engine, substeps_for
from tensegrity_env.model import Model
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology

#: steps per window of the final fits (declared model's many-window fit excepted): long
#: windows fit a drag better than short ones (docs/decisions.md); selection still
#: compares on ``window``
FIT_WINDOW = 300

#: a window whose states, fitted at the selected model, stay above this multiple of the
#: noise level is left out of the final floor refit and of the floor fit's rounds
#: (stuck in another basin through an impact;
#: :func:`~identification.trajectory.window_errors.windows_within`)
STUCK_WINDOW = 1.5


@dataclass(frozen=True)
class TrajectorySettings:
    """How the loop fits end-cap data.

    Attributes:
        anchors: known values fixing the scale, e.g. ``{"mass[rod0]": 1.95}``.
        window: steps per window (short windows forgive a missing effect at the start).
        train_windows, val_windows, test_windows: random windows used per split.
        base_iter, candidate_iter, state_iter: Levenberg-Marquardt iterations of the
            declared fit, of each candidate fit, of the held-out state fits.
        smoothing: Savitzky-Golay window [s] of the starting states and regression.
        seed: seed of the window draws.
        fit_windows: windows of the training split for the declared model's and every
            accepted model's final fit (parameters reported, test errors, next start).
        fit_window: steps per window of that fit (0: ``window``; default
            :data:`FIT_WINDOW`); longer windows carry more information per sample once
            the model holds the effect.
        floor_windows: windows of the training split for the joint fit of the declared
            model and ground contact on data that never leaves the floor (default
            :data:`FLOOR_WINDOWS`); its cost grows in proportion, and the spread of the
            fitted spring damping shrinks as its inverse square root.
        final_floor_windows: windows of the training split for the final refit of the
            selected model on such data (default :data:`FINAL_FLOOR_WINDOWS`; none at
            or below ``floor_windows``).
        floor_window: steps per window of the fits on the floor (0: ``fit_window`` or
            ``window``, at most :data:`~identification.trajectory.floor_fit.FLOOR_WINDOW_S`;
            :func:`~identification.trajectory.floor_declared.floor_steps`).
        final_floor_window: steps per window of that refit (0: as the floor windows,
            :func:`~identification.trajectory.floor_declared.floor_steps`).
        final_iter: most Levenberg-Marquardt iterations of the final refit (default
            :data:`FINAL_ITERATIONS`).
        physics_dt: the longest physics step [s]; the engine substeps between samples
            (:func:`tensegrity_env.engine.substeps_for`) and is compared with the data at
            the sample times.
        second_start: a floor fit from the regression runs again from a spread of soft
            contacts and the two are compared
            (:class:`~identification.trajectory.floor_declared.StartCheck`); False halves
            its cost and leaves a second minimum unseen.
    """

    anchors: dict[str, float] = field(default_factory=dict)
    window: int = 100
    train_windows: int = 8
    val_windows: int = 8
    test_windows: int = 8
    base_iter: int = 10
    candidate_iter: int = 10
    state_iter: int = 15
    smoothing: float = 0.1
    seed: int = 0
    fit_windows: int = 32
    fit_window: int = FIT_WINDOW
    floor_windows: int = FLOOR_WINDOWS
    final_floor_windows: int = FINAL_FLOOR_WINDOWS
    final_floor_window: int = 0
    floor_window: int = 0
    final_iter: int = FINAL_ITERATIONS
    physics_dt: float = PHYSICS_DT
    second_start: bool = True


@dataclass
class TrajFit:
    """A model fitted through the windows of the training split.

    Attributes:
        vec: the fitted vector's layout (log-parameters and effect coordinates).
        theta: fitted values, (n_free + n_effect,).
        windows: training windows with fitted initial states.
        sse, m: sum of squared end-cap errors [m^2] and number of residuals.
        stderr: standard error of every fitted coordinate, (n_free + n_effect,).
        origin: where the next fits start (declared parameters and effect coordinates,
            same layout as ``theta``): the fit on the many windows, once there is one.
    """

    vec: ParamVector
    theta: torch.Tensor
    windows: Windows
    sse: float
    m: int
    stderr: np.ndarray
    origin: torch.Tensor | None = None

    @property
    def params(self) -> Params:
        return self.vec.params(self.vec.full(self.theta.detach()))

    @property
    def effects(self) -> list[PhysicalEffect]:
        """The fitted effects, with standard errors as their ``uncertainty``."""
        if self.vec.coords is None:
            return []
        n = self.vec.n_free
        return self.vec.coords.effects_at(self.theta.detach()[n:], self.stderr[n:])

    @property
    def uncertainty(self) -> dict[str, float]:
        """Standard errors of the fitted declared parameters by name, in their units
        (``value x`` the standard error of its logarithm); ``inertia_perp[rod]`` is the
        perpendicular inertia both perpendicular axes share."""
        n = self.vec.n_free
        full = torch.exp(self.vec.full(self.theta.detach())).numpy()
        names = self.vec.names()
        free = torch.nonzero(self.vec.free)[:, 0].tolist()
        return {names[i]: float(full[i] * se) for i, se in zip(free, self.stderr[:n], strict=True)}

    def fitted_model(self, topology: Topology, dt: float) -> FittedModel:
        """The fit as the loop's model: parameters, effects, fitted-parameter count and
        the declared parameters' standard errors."""
        model = Model(topology, self.params, tuple(self.effects), dt)
        return FittedModel(model, self.k, uncertainty=self.uncertainty)

    @property
    def start_effects(self) -> list[PhysicalEffect]:
        """The effects at ``origin`` (where the next fits start)."""
        if self.vec.coords is None or self.origin is None:
            return self.effects
        return self.vec.coords.effects_at(self.origin.detach()[self.vec.n_free :])

    #: global parameters fitted elsewhere and held here (the searched contact's, and the
    #: declared ones fitted on airborne windows)
    extra_k: int = 0
    #: the joint fit met its stopping rule (not just its iteration count)
    converged: bool = True
    #: Levenberg-Marquardt iterations the joint fit took (one Jacobian each)
    iterations: int = 0

    @property
    def k(self) -> int:
        """Global parameters: the fitted vector's and :attr:`extra_k`."""
        return len(self.theta) + self.extra_k

    @property
    def bic(self) -> float:
        return self.m * float(np.log(self.sse / self.m)) + self.k * float(np.log(self.m))

    @property
    def rms(self) -> float:
        return float(np.sqrt(self.sse / self.m))


#: the window sets of :class:`EndCapData`, in the order of their random streams
SPLIT_WINDOWS = ("train", "val", "test", "fit")


class EndCapData:
    """Windows of every split, their smoothed starting states, and the fixed context."""

    def __init__(self, dataset: Dataset, s: TrajectorySettings) -> None:
        self.topology, self.dt = dataset.topology, dataset.dt
        self.axes = RodAxes.of(self.topology)
        self.engine = Engine(self.topology, self.dt, substeps=substeps_for(self.dt, s.physics_dt),
                             native=True)
        self.sg = odd_window(s.smoothing / self.dt)
        self.dataset, self.seed = dataset, s.seed
        self.smooth: dict[str, Any] = {}
        self.windows: dict[str, Windows] = {}
        self.counts = {"train": s.train_windows, "val": s.val_windows, "test": s.test_windows,
                       "fit": s.fit_windows}  # fmt: skip
        self.window = s.window
        for k, name in enumerate(SPLIT_WINDOWS):
            steps = s.fit_window if name == "fit" and s.fit_window > 0 else s.window
            self.windows[name] = self.cut("train" if name == "fit" else name, steps,
                                          self.counts[name], k)  # fmt: skip
        self.smooth["fit"] = self.smooth["train"]
        self.train: Split = dataset.split("train")
        #: contact parameters fitted by Levenberg-Marquardt; () once they come from the
        #: touchdown search (identification.trajectory.touchdown)
        self.contact_free: tuple[str, ...] = CONTACT_FREE
        #: free declared parameters of the declared model's fit
        self.declared_k = 0
        self.log: Callable[[str], None] = lambda line: None
        #: the declared fit's airborne stretches, states fitted (None: no floor)
        self.stretches: Windows | None = None
        #: every fit also fits the windows' rolls (set once an accepted effect sees them)
        self.roll = False
        #: no airborne stretch: ground contact is in the model from the start
        #: (:mod:`identification.trajectory.floor_declared`)
        self.on_floor = False
        #: where a floor fit starts the contact (a params file's), None: the default
        self.contact_start: GroundContact | None = None
        #: limits of the contact's coordinates in every fit after the floor fit
        #: (:func:`~identification.trajectory.floor_fit.contact_box`; None: no limits)
        self.contact_box: dict[str, tuple[float, float]] | None = None
        #: steps per window the floor fit chose (None: no floor fit yet)
        self.floor_steps: int | None = None
        #: the last floor fit from the regression, its two starts compared
        #: (:class:`~identification.trajectory.floor_declared.StartCheck`; None: none)
        self.starts: Any = None

    @property
    def spin(self) -> bool:
        """Whether the windows' states include each rod's axial spin.

        On the floor (friction turns a rod about its axis), and once the rolls are
        fitted: the spin turns the roll that such an effect sees (box-form quadratic
        drag of a thin rod: a spin set to zero moves the true model's rollout by far
        more than the noise).
        """
        return self.on_floor or self.roll

    def lift_off_selection(self) -> None:
        """On the floor: half of the selection (training) and validation windows drawn
        from those that start in the air (``cut``'s ``lift_off``), as the floor fit's.

        Drawn at random, nearly all of them lie on the floor, where friction holds a
        horizontal force and the contact's fitted stiffness and damping take up a
        vertical one or a drag, so that a drag's screen gains little. The windows'
        flights are short: a force field on the floor shows only with the screens' line
        search (:func:`fit_trajectory`), judged against the screened reference
        (``MultiStepScorer.with_reference``).
        """
        for name in ("train", "val"):
            count = self.counts[name]
            self.windows[name] = self.cut(name, self.window, count,
                                          SPLIT_WINDOWS.index(name), lift_off=count // 2)  # fmt: skip

    def cut(
        self,
        name: str,
        steps: int,
        count: int,
        stream: int,
        airborne: bool = False,
        lift_off: int = 0,
    ) -> Windows:
        """``count`` random windows of ``steps`` of split ``name``, states from smoothing.

        ``airborne``: only windows whose measured end caps all stay :data:`~identification.trajectory.airborne.AIRBORNE`
        above touching the floor (none if there are none). ``lift_off``: up to this many
        of the windows are drawn from those that **start in the air** (every end cap
        that far above the floor at the window's first sample: a throw or a drop before
        it lands, a jump), the rest from the others (from the remaining ones in the air
        only where the others are too few).
        """
        split = self.dataset.split(name if name in self.dataset.splits else "test")
        if name not in self.smooth:
            self.smooth[name] = smooth_rod_states(split.nodes, self.dt, self.axes, self.sg)
        grid = {key: getattr(self.smooth[name], key) for key in STATE_KEYS}
        win = cut_windows(split.nodes, split.control, grid, steps, split.cable_control, least=count)
        if airborne:
            gap = seen_gaps(win, self.topology)
            win = win.take(np.flatnonzero((gap.amin(dim=(1, 2)) > AIRBORNE).numpy()))
        rng = np.random.default_rng([self.seed, stream])
        if lift_off and win.size > count:
            in_air = (seen_gaps(win, self.topology)[:, 0].amin(dim=1) > AIRBORNE).numpy()
            air, ground = (
                rng.permutation(np.flatnonzero(in_air)),
                rng.permutation(np.flatnonzero(~in_air)),
            )
            rest = np.concatenate([ground, air[lift_off:]])  # in the air only if too few others
            pick = np.concatenate([air[:lift_off], rest[: count - min(lift_off, len(air))]])
            return win.take(np.sort(pick))
        if win.size > count:
            win = win.take(np.sort(rng.choice(win.size, count, replace=False)))
        return win


def seen_gaps(win: Windows, topology: Topology) -> torch.Tensor:
    """Height of every measured end cap of ``win`` above touching the floor (z = 0),
    (B, W+1, 2R) [m]; +inf where the end cap is not seen (a gap vetoes nothing)."""
    gap = win.obs[..., 2] - torch.as_tensor(cap_radii(topology))
    return torch.where(win.seen(), gap, torch.full_like(gap, torch.inf))


def airborne_keep(data: EndCapData) -> np.ndarray | None:
    """The training samples away from a floor (None: no floor in the data, all of them)."""
    if not contact_gate(data.train, data.topology)[0]:
        return None
    return airborne_samples(data.train.nodes, data.topology, data.sg)


def common_axis(axes: RodAxes) -> int | None:
    """The end-cap axis (rod frame) if every rod has the same one."""
    return int(axes.axis[0]) if np.all(axes.axis == axes.axis[0]) else None


def held_drag_axis(data: EndCapData) -> int | None:
    """The rod axis whose rotational drag the fits hold (see
    :meth:`~identification.trajectory.effect_coords.EffectCoords.of`): the common end-cap
    axis in free flight, where the spin about it is invisible; none on the floor, where
    friction at the end caps spins each rod about its axis, the windows' states hold
    that spin (:mod:`identification.trajectory.floor_fit`), and a drag about the axis
    (MuJoCo's fluid models damp it) changes how the caps roll and slip."""
    return None if data.on_floor else common_axis(data.axes)


@torch.no_grad()
def fixed_engine(data: EndCapData, fit: TrajFit) -> tuple[Engine, ParamVector]:
    """The engine with ``fit``'s effects and a vector with nothing free (its params)."""
    return data.engine.with_effects(fit.effects), fit.vec.held_at(fit.theta)


def fit_trajectory(
    data: EndCapData, vec: ParamVector, windows: Windows, theta: torch.Tensor, iters: int,
    roll: bool | None = None, progress: Callable[[float], None] | None = None,
    stall: float | None = None,
) -> TrajFit:  # fmt: skip
    """``vec`` and the windows' states fitted; ``roll``: each rod's roll in them too
    (None: ``data.roll``); ``progress``, ``stall``: see :class:`FitOptions`. The BIC
    counts the rolls.
    On the floor the states include each rod's axial spin
    (:mod:`identification.trajectory.floor_fit`), and a rejected step is tried shorter
    before more damping (:func:`~identification.trajectory.windowed_problem.fit`'s line search): the error jumps where an impact
    crosses a physics step, and the damped steps turn towards the jumps, so that without
    the line search a force field's screen on the floor stays near zero.
    """
    roll = data.roll if roll is None else roll
    done = fit(WindowedProblem(data.engine, vec, windows, theta),
               end_cap_options(data, iters, roll, progress, stall))
    m = done.windows.residuals
    # state unknowns, not common: the rolls and (in flight) the spins that turn them
    rolls = done.windows.size * data.topology.n_rods * (1 + (not data.on_floor)) if roll else 0
    return TrajFit(vec, done.theta, done.windows, done.history[-1] * m, m, done.stderr,
                   extra_k=extra_k(data, vec) + rolls, converged=done.converged,
                   iterations=len(done.history) - 1)  # fmt: skip


def end_cap_options(
    data: EndCapData, iters: int, roll: bool, progress: Callable[[float], None] | None = None,
    stall: float | None = None,
) -> FitOptions:  # fmt: skip
    """How every joint fit of the loop's models on end-cap windows is solved: ``iters``
    iterations to a Newton decrement of 0.1 (or, with ``stall``, until the error stops
    falling); each rod's axial spin in the window states on the floor and with ``roll``
    (each rod's roll too); the line search on the floor (see :func:`fit_trajectory`)."""
    return FitOptions(max_iter=iters, tol=0.1, spin=data.on_floor or roll, roll=roll,
                      line_search=data.on_floor, stall=stall, progress=progress,
                      log=data.log)  # fmt: skip


def extra_k(data: EndCapData, vec: ParamVector) -> int:
    """Parameters of ``vec``'s model fitted outside its vector (see ``TrajFit.extra_k``)."""
    if not contact_searched(vec):
        return 0
    return len(CONTACT_FREE) + (data.declared_k if not bool(vec.free.any()) else 0)


def contact_searched(vec: ParamVector) -> bool:
    """Whether ``vec`` holds a contact whose parameters came from the touchdown search."""
    coords = vec.coords
    return coords is not None and any(
        e.gate.needs == "floor" and not slot
        for e, slot in zip(coords.effects, coords.slots, strict=True)
    )


def has_contact(vec: ParamVector) -> bool:
    return vec.coords is not None and any(
        e.gate.needs == "floor" for e in vec.coords.effects_at(vec.coords.start())
    )


def hold_declared(vec: ParamVector) -> ParamVector:
    """``vec`` with the declared parameters held where they are (contact searched).

    With a floor in the data they were fitted on airborne windows; fitted again through
    the impacts (the states' fits there are poorer: the contact's small jumps) they
    drift away from what the airborne samples say.
    """
    return replace(vec, free=torch.zeros_like(vec.free))


def heldout(
    data: EndCapData, fit: TrajFit, split: str, iters: int, warm: Windows | None = None,
    fresh: bool = False,
) -> tuple[float, int, Windows]:  # fmt: skip
    """Sum of squared end-cap errors [m^2] on a split's windows, only their states fitted.

    The states start from smoothing, fitted on growing prefixes; ``warm``: from these
    windows' states instead (fitted at a nearby model), on the whole windows at once;
    ``warm`` and ``fresh``: both, each window keeping the state that fits it better
    (:func:`~identification.trajectory.window_errors.better_states`). On the floor a model
    accepted by the loop is scored so: its states from smoothing alone stop in other
    basins through the impacts, and every later candidate would be judged against those.
    """
    engine, vec = fixed_engine(data, fit)
    start = data.windows[split] if warm is None else warm
    w = fit_states(engine, vec, start, iters, spin=data.spin, roll=data.roll,
                   grow=warm is None)  # fmt: skip
    windows, sse = w.windows, w.history[-1] * w.windows.residuals
    if warm is not None and fresh:
        smooth = heldout(data, fit, split, iters)[2]
        windows, _, best = better_states(engine, vec, torch.zeros(0, dtype=torch.float64), smooth,
                                        windows)  # fmt: skip
        sse = float(best.sum())
    return sse, windows.residuals, windows


@torch.no_grad()
def predicted_caps(data: EndCapData, fit: TrajFit, windows: Windows) -> torch.Tensor:
    """End caps (B, W+1, 2R, 3) [m] of ``fit`` rolled out from ``windows``' states."""
    engine, vec = fixed_engine(data, fit)
    roll = engine.rollout(windows.state, vec.params(vec.start), windows.steps, windows.control,
                          windows.cables)  # fmt: skip
    return end_caps(engine, roll.p, roll.q)


def declared_start(
    data: EndCapData,
    anchors: dict[str, float],
    start: Params | None,
    values: dict[str, np.ndarray] | None,
    **keep: Any,
) -> ParamVector:
    """The declared model's parameter vector to fit from: ``values`` (a regression), else
    ``start`` (a params file), else the regression on the smoothed training end caps
    restricted by ``keep`` (``keep=`` samples or ``rod_keep=`` rod-samples)."""
    if values is None and start is None:
        values = smoothed_regression(data.topology, data.smooth["train"], data.train.control,
                                     anchors, **keep)  # fmt: skip
    elif values is None:
        assert start is not None
        values = params_values(start, data.axes)
    has_control = bool(np.any(data.train.control != 0))
    return TrajectoryIdentifier(anchors=anchors).start_vector(
        data.topology, data.axes, values, parse_anchors(data.topology, anchors), has_control
    )
