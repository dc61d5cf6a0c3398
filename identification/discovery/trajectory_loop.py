"""The residual loop on measured end caps (motion capture, ~1 mm noise), through the engine.

With noisy end caps, accelerations from differences are useless and smoothing
biases the regression (more than the effects we look for), so the loop compares
models by **multi-step prediction of the measured end caps** instead: the
windowed trajectory fit of :mod:`identification.trajectory.identifier` (maximum likelihood under
Gaussian position noise), with each candidate's effect parameters appended to the
fitted vector (:class:`~identification.trajectory.effect_coords.EffectCoords`).

Each iteration of :func:`diagnose_noisy`

1. fits every candidate whose gate the data passes **jointly** (declared parameters,
   the candidate's and the current effects' parameters, each window's initial state)
   on windows of the training split, starting from the current model;
2. scores it on **held-out** windows (validation split): only the windows' initial
   states are fitted there, parameters held, so the held-out sum of squares
   ``SSE_val`` measures prediction; and by the **BIC** of the training fit,
   ``m ln(SSE/m) + k ln m`` (``k``: global parameters; the window states are common
   to every model);
3. accepts the best candidate only if it lowers the BIC by :data:`MIN_BIC_DROP`, the
   held-out chi-square ``SSE_val / σ̂²`` by :data:`MIN_CHI2_GAIN` (``σ̂``: the
   candidate's held-out RMS, the noise estimate), and its values are physical;
4. flags the attribution when the runner-up also passes, the two held-out
   chi-squares differ by less than :data:`AMBIGUOUS_CHI2` (the held-out data cannot
   prefer one) and the two models' predicted end-cap changes correlate above
   :data:`AMBIGUOUS_CORRELATION`. The runner-up's correlation and chi-square
   difference are reported either way.

Slack cables are named by a segmented regression on the smoothed end caps
(:mod:`identification.trajectory.slack_regression`: a stiffness change below each spring's rest
length); the candidate, those springs as cables, is then fitted like the declared
model, from that regression, and compared with the current model as any other.

The declared model and every accepted one are also fitted on **many** windows of the
training split (:attr:`TrajectorySettings.fit_windows`; :func:`fit_many`): selection
needs only a few windows, but the parameters written out, the test errors and the
next iteration's starting point come from this larger fit. Without a params file the
declared model starts from the regression on smoothed end caps; its fit on the many
windows brings it near the optimum before anything is compared. On data with a
floor the declared model is fitted apart from contact, on the airborne samples and
then on every **airborne stretch whole** (one window each, however long): cut into
100-step windows, each with its own initial state (1.3 s of the 1.8 s fit into
them), they gave stiffness to 1 % and masses to 1.2 %; whole, 0.17 % and 0.08 %
(seed 0, 1 mm noise). Once the contact is searched on the touchdowns, the declared
model is refitted on those stretches run on :data:`PAST_TOUCHDOWN` steps past the
touchdowns (contact held), then held.

Window initial states are fitted on **growing prefixes** of each window first
(:data:`GROW`; :func:`fit_states`): a state from smoothing is poor where an impact
falls inside the filter's span, and on a long window the fit may then stop in another
basin. The rods' **axial spins** are not fitted, with or without contact: friction at
an end cap does turn a rod about its axis, but under 1 mm noise the spin is barely
seen, and the fit stepped to spins of 100+ rad/s whose explicit gyroscopic integration
(as in MuJoCo's Euler integrator) blew up on longer windows.

A rod's **roll** about its own axis is invisible too, but box-form quadratic drag
depends on it (``sees_roll``): once such an effect is in the model, the windows' states
include each rod's roll (:func:`fit_many`'s second pass, then every later fit and score).

Errors before and after are measured on the **test** split: the held-out end-cap
RMS (which cannot fall below the noise) and, when the clean trajectories are known
(planted data), the one-step and rollout errors against them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from identification.data.dataset import Dataset, Split
from identification.data.end_caps import RodAxes, odd_window, smooth_rod_states
from identification.discovery.candidates import FittedModel, contact_gate
from identification.discovery.end_cap_residuals import (
    plot_window_residuals,
    summarize_window_residuals,
    window_residuals,
)
from identification.linear.extended import evaluate_model
from identification.linear.smoothed import parse_anchors, smoothed_regression
from identification.trajectory.airborne import (
    AIRBORNE,
    airborne_samples,
    airborne_stretches,
    cap_radii,
    past_touchdown,
)
from identification.trajectory.effect_coords import CONTACT_FREE, CONTACT_START, EffectCoords
from identification.trajectory.identifier import TrajectoryIdentifier
from identification.trajectory.param_vector import ParamVector, params_values
from identification.trajectory.slack_regression import (
    CABLE_LOSS,
    CABLE_SIGNIFICANCE,
    slack_regression,
)
from identification.trajectory.stage_check import check_stage, fit_diverged, noise_level
from identification.trajectory.touchdown import find_touchdowns, search_contact
from identification.trajectory.window_states import GROW, fit_states, prefix
from identification.trajectory.windowed_fit import fit_windows
from identification.trajectory.windows import STATE_KEYS, Windows, cut_windows, end_caps, sees_roll
from tensegrity_env.effects import (
    CubicStiffness,
    ForceField,
    GroundContact,
    LinearDrag,
    QuadraticDrag,
    SlackSprings,
)
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import PHYSICS_DT, Engine, substeps_for
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model
from tensegrity_env.params import Params

#: steps past each touchdown the declared model is refitted on, contact held
PAST_TOUCHDOWN = 150
#: a candidate must lower the training BIC by this much ...
MIN_BIC_DROP = 10.0
#: ... and the held-out chi-square by this much
MIN_CHI2_GAIN = 10.0
#: two passing candidates whose predicted changes correlate above this ...
AMBIGUOUS_CORRELATION = 0.9
#: ... and held-out chi-squares closer than this cannot be told apart
AMBIGUOUS_CHI2 = 10.0


#: steps per window of the final fits (declared model's many-window fit excepted): on
#: noisy linear drag (seed 0) 300-step windows gave one-step 563x and rollout 5810x
#: where 100-step windows gave 42x and 258x; selection still compares on ``window``
FIT_WINDOW = 300


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
        physics_dt: the longest physics step [s]; the engine substeps between samples
            (:func:`tensegrity_env.engine.substeps_for`) and is compared with the data at
            the sample times.
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
    physics_dt: float = PHYSICS_DT


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
    def start_effects(self) -> list[PhysicalEffect]:
        """The effects at ``origin`` (where the next fits start)."""
        if self.vec.coords is None or self.origin is None:
            return self.effects
        return self.vec.coords.effects_at(self.origin.detach()[self.vec.n_free :])

    #: global parameters fitted elsewhere and held here (the searched contact's, and the
    #: declared ones fitted on airborne windows)
    extra_k: int = 0

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


@dataclass
class Candidate:
    """A candidate fitted and scored (``"nothing"``: the current model)."""

    name: str
    fit: TrajFit
    gate: str = ""
    val_sse: float = float("nan")
    val_m: int = 0
    val_windows: Windows | None = None
    chi2_gain: float = 0.0
    bic_drop: float = 0.0
    physical: bool = True
    accepted: bool = False
    verdict: str = ""
    seconds: float = 0.0

    @property
    def val_rms(self) -> float:
        return float(np.sqrt(self.val_sse / max(self.val_m, 1)))


@dataclass
class NoisyIteration:
    """One pass: the current model, every candidate, the choice and the test errors."""

    before: Candidate
    candidates: list[Candidate]
    skipped: list[tuple[str, str]]
    chosen: Candidate | None
    ambiguous: tuple[str, float] | None
    test_before: dict[str, float]
    test_after: dict[str, float] | None = None
    #: held-out residual numbers of the current model (``summarize_window_residuals``)
    residual: dict[str, float] = field(default_factory=dict)
    #: their PNG (against end-cap height, speed and time in the window), if written
    plot: Path | None = None
    #: the runner-up that also passed: name, correlation of predicted changes with the
    #: chosen one's, and how much more the chosen one lowers the held-out chi-square
    runner_up: tuple[str, float, float] | None = None


@dataclass
class NoisyDiagnoseResult:
    """What :func:`diagnose_noisy` found (``model``: final params and effects)."""

    iterations: list[NoisyIteration]
    model: FittedModel
    baseline_test: dict[str, float]
    final_test: dict[str, float]
    settings: dict[str, Any]
    unexplained: str = ""


# ---------------------------------------------------------------------- fits
class _Data:
    """Windows of every split, their smoothed starting states, and the fixed context."""

    def __init__(self, dataset: Dataset, s: TrajectorySettings) -> None:
        self.topology, self.dt = dataset.topology, dataset.dt
        self.axes = RodAxes.of(self.topology)
        self.engine = Engine(self.topology, self.dt, substeps=substeps_for(self.dt, s.physics_dt))
        self.sg = odd_window(s.smoothing / self.dt)
        self.dataset, self.seed = dataset, s.seed
        self.smooth: dict[str, Any] = {}
        self.windows: dict[str, Windows] = {}
        counts = {"train": s.train_windows, "val": s.val_windows, "test": s.test_windows,
                  "fit": s.fit_windows}  # fmt: skip
        for k, name in enumerate(("train", "val", "test", "fit")):
            steps = s.fit_window if name == "fit" and s.fit_window > 0 else s.window
            self.windows[name] = self.cut("train" if name == "fit" else name, steps,
                                          counts[name], k)  # fmt: skip
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

    def cut(
        self, name: str, steps: int, count: int, stream: int, airborne: bool = False
    ) -> Windows:
        """``count`` random windows of ``steps`` of split ``name``, states from smoothing.

        ``airborne``: only windows whose measured end caps all stay :data:`~identification.trajectory.airborne.AIRBORNE`
        above touching the floor (none if there are none).
        """
        split = self.dataset.split(name if name in self.dataset.splits else "test")
        if name not in self.smooth:
            self.smooth[name] = smooth_rod_states(split.nodes, self.dt, self.axes, self.sg)
        grid = {key: getattr(self.smooth[name], key) for key in STATE_KEYS}
        win = cut_windows(split.nodes, split.control, grid, steps)
        if airborne:
            gap = win.obs[..., 2] - torch.as_tensor(cap_radii(self.topology))
            win = win.take(np.flatnonzero((gap.amin(dim=(1, 2)) > AIRBORNE).numpy()))
        rng = np.random.default_rng([self.seed, stream])
        if win.size > count:
            win = win.take(np.sort(rng.choice(win.size, count, replace=False)))
        return win


def fit_declared(
    data: _Data,
    s: TrajectorySettings,
    start: Params | None = None,
    effects: Sequence[PhysicalEffect] = (),
    values: dict[str, np.ndarray] | None = None,
) -> tuple[TrajFit, TrajFit]:
    """The declared model: its fit on the many windows, and on the training windows.

    Every parameter but the anchors is fitted, first on the many windows
    (:func:`fit_many`) from ``start`` (a params file) if given, else from the
    regression on Savitzky-Golay smoothed end caps (far off on fast data: the many
    windows bring it near the optimum), then on the few training windows that
    selection compares candidates on (from there, so both fits share the origin).
    Where end caps reach a floor, the "many windows" are every airborne stretch of the
    training split, each whole (:func:`~identification.trajectory.airborne.airborne_stretches`).

    ``effects`` are fitted with it (a hypothesis that changes the declared springs, such
    as slack cables) and ``values`` replace the stage-1 regression (natural units, as
    :func:`smoothed_regression` returns them).
    """
    # where end caps reach a floor, only samples and windows where they are airborne
    # (contact's gate closed): fitted through impacts, the declared model drifts to make
    # up for contact
    airborne = contact_gate(data.train, data.topology)[0]
    if values is None and start is None:
        values = smoothed_regression(data.topology, data.smooth["train"], data.train.control,
                                     s.anchors, keep=_airborne_keep(data))  # fmt: skip
    elif values is None:
        assert start is not None
        values = params_values(start, data.axes)
    has_control = bool(np.any(data.train.control != 0))
    anchors = parse_anchors(data.topology, s.anchors)
    vec = TrajectoryIdentifier(anchors=s.anchors).start_vector(
        data.topology, data.axes, values, anchors, has_control
    )
    if effects:
        vec = replace(vec, coords=EffectCoords.of(list(effects), _common_axis(data.axes),
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
            theta = _fit(data, vec, short, theta, s.base_iter).theta
        elif airborne:
            # each airborne stretch whole: far more precise than cut into windows
            grid = {key: getattr(data.smooth["train"], key) for key in STATE_KEYS}
            stretches = airborne_stretches(data.train.nodes, data.train.control, grid,
                                           data.topology)  # fmt: skip
            many_windows = short if stretches is None else stretches
    many = fit_many(data, vec, theta, s, iters=2 * s.base_iter, windows=many_windows)
    fit = _fit(data, vec, data.windows["train"], many.theta, s.base_iter)
    fit.origin = many.theta
    if airborne and many.windows.valid is not None:
        data.stretches = many.windows
    return many, fit


def _airborne_keep(data: _Data) -> np.ndarray | None:
    """The training samples away from a floor (None: no floor in the data, all of them)."""
    if not contact_gate(data.train, data.topology)[0]:
        return None
    return airborne_samples(data.train.nodes, data.topology, data.sg)


def fit_declared_model(dataset: Dataset, settings: TrajectorySettings) -> TrajFit:
    """The declared model alone, fitted on a dataset's end caps (the loop's first stage).

    On data with a floor: from the airborne samples and stretches only (see
    :func:`fit_declared`), so it can be handed to
    :func:`identification.trajectory.touchdown.contact_from_dataset` without a calibration.
    """
    return fit_declared(_Data(dataset, settings), settings)[0]


def fit_many(
    data: _Data, vec: ParamVector, theta: torch.Tensor, s: TrajectorySettings, iters: int,
    windows: Windows | None = None,
) -> TrajFit:  # fmt: skip
    """``vec`` refitted jointly on the many windows of the training split, from ``theta``.

    The windows' states are fitted first with the model at ``theta``
    (:func:`fit_states`), so a fit on windows whose smoothed states are poor (impacts)
    starts in the right basin. With an effect that depends on the rods' roll about their
    axes (``sees_roll``: quadratic drag), each window's rolls are fitted too: on noisy
    quadratic drag (seed 0, 24 windows of 333 steps) the fit went from 4.65 mm RMS to
    1.13 mm (1 mm noise), and the drag coefficients from 8 % to 1 % off. The rolls are
    fitted in a second pass, from the fit without them: from a small drag (0.058 of
    1.44 after the candidate's 10 iterations) a joint fit stopped at 4.3 mm. (A third
    pass with the axial spins went from 1.217 to 1.024 mm in one trial and from 1.130
    to 1.461 mm in the loop: not used.) Selection's first fits leave the roll out: from
    zero drag its columns are zero, and the quadratic drag candidate then converged
    more slowly than the linear one. Once such an effect is accepted, every later fit
    and score fits the rolls (``data.roll``).
    """
    engine = vec.engine(data.engine, theta.detach())
    fixed = _held(vec, theta)
    many = data.windows["fit"] if windows is None else windows
    states = fit_states(engine, fixed, many, s.state_iter, roll=data.roll)
    fit = _fit(data, vec, states.windows, theta, iters)
    if sees_roll(engine) and not data.roll:
        # the rolls only matter once the effect is near its size: fitted from there
        t0 = time.perf_counter()
        engine = vec.engine(data.engine, fit.theta.detach())
        states = fit_states(engine, _held(vec, fit.theta), fit.windows, s.state_iter, roll=True)
        fit = _fit(data, vec, states.windows, fit.theta, iters, roll=True)
        data.log(f"    rolls fitted too: end-cap RMS {fit.rms * 1e3:.3f} mm "
                 f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    fit.origin = fit.theta
    return fit


def _contact_searched(vec: ParamVector) -> bool:
    """Whether ``vec`` holds a contact whose parameters came from the touchdown search."""
    coords = vec.coords
    return coords is not None and any(
        isinstance(e, GroundContact) and not slot
        for e, slot in zip(coords.effects, coords.slots, strict=True)
    )


def _has_contact(vec: ParamVector) -> bool:
    return vec.coords is not None and any(
        isinstance(e, GroundContact) for e in vec.coords.effects_at(vec.coords.start())
    )


def _fit(
    data: _Data, vec: ParamVector, windows: Windows, theta: torch.Tensor, iters: int,
    roll: bool | None = None,
) -> TrajFit:  # fmt: skip
    """``vec`` and the windows' states fitted; ``roll``: each rod's roll in them too
    (None: ``data.roll``). The BIC counts the rolls.
    """
    roll = data.roll if roll is None else roll
    fit = fit_windows(data.engine, vec, windows, theta, iters, tol=0.1, spin=False, roll=roll)
    m = fit.windows.residuals
    rolls = windows.size * data.topology.n_rods if roll else 0  # state unknowns, not common
    return TrajFit(vec, fit.theta, fit.windows, fit.history[-1] * m, m, fit.stderr,
                   extra_k=_extra_k(data, vec) + rolls)  # fmt: skip


def fit_with(
    data: _Data, current: TrajFit, effects: Sequence[PhysicalEffect], iters: int
) -> TrajFit:
    """Refit jointly with ``effects`` (contact last), from the current model's origin.

    The declared parameters start where ``current`` started (its ``origin``: the
    params file, or the accepted model's fit), not where it ended: a model without
    the missing effect drifts to compensate for it, and from there the effect may
    no longer pay. The windows start from ``current``'s fitted states.
    """
    ordered = [e for e in effects if not isinstance(e, GroundContact)]
    ordered += [e for e in effects if isinstance(e, GroundContact)]
    origin = current.theta if current.origin is None else current.origin
    axis = _common_axis(data.axes)
    vec = replace(current.vec, start=current.vec.full(origin.detach()),
                  coords=EffectCoords.of(ordered, axis, data.contact_free))  # fmt: skip
    if _contact_searched(vec):
        vec = _hold_declared(vec)
    windows, theta = current.windows, vec.theta0()
    if _has_contact(vec) and not _has_contact(current.vec):
        # The end-cap error is discontinuous in the contact's parameters (see
        # identification.trajectory.touchdown): they come from a derivative-free search on the
        # touchdowns and are held in every fit after it. The states were fitted without
        # a floor: they are refitted on growing prefixes of the windows. Without
        # touchdowns (no trajectory starts airborne) the contact is fitted through the
        # prefixes instead: its parameters and the states, the declared ones held
        # (short prefixes cannot pin them), each stage from the last.
        searched = _touchdown_contact(data, vec, theta)
        if searched is not None:
            ordered[-1] = searched
            vec = _through_touchdowns(data, replace(vec, coords=EffectCoords.of(ordered, axis, ())),
                                      iters)  # fmt: skip
            theta = vec.theta0()
        n_free = vec.n_free
        for n in [g for g in GROW if g < windows.steps] + [windows.steps]:
            fixed = _held(vec, theta)
            part = fit_states(vec.engine(data.engine, theta), fixed, prefix(windows, n),
                              iters).windows  # fmt: skip
            if n < windows.steps and searched is None:
                only = replace(fixed, coords=vec.coords)
                tail = _fit(data, only, part, theta[n_free:], iters).theta
                theta = torch.cat([theta[:n_free], tail])
            windows = replace(windows, state=part.state)
    fit = _fit(data, vec, windows, theta, iters)
    fit.origin = fit.theta
    return fit


def _through_touchdowns(data: _Data, vec: ParamVector, iters: int) -> ParamVector:
    """``vec`` (contact held) with the declared parameters refitted, then held.

    The airborne stretches the declared model was fitted on are run on
    :data:`PAST_TOUCHDOWN` steps past their touchdowns, with the searched contact: the
    impacts ring the springs, which says more about damping. Longer, the windows'
    states fitted worse (1.12 mm RMS at 400 steps against 1.01 at 150, 1 mm noise).
    """
    if data.stretches is None:
        return _hold_declared(vec)
    t0 = time.perf_counter()
    theta = vec.theta0()
    windows = past_touchdown(data.stretches, data.train.nodes, PAST_TOUCHDOWN)
    states = fit_states(vec.engine(data.engine, theta), _held(vec, theta), windows, iters)
    fit = _fit(data, vec, states.windows, theta, iters)
    data.log(f"    declared model refitted {PAST_TOUCHDOWN} steps past the touchdowns (contact "
             f"held): end-cap RMS {fit.rms * 1e3:.3f} mm ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    assert vec.coords is not None
    effects = vec.coords.effects_at(fit.theta[vec.n_free :].detach())
    moved = replace(vec, start=vec.full(fit.theta.detach()),
                    coords=EffectCoords.of(effects, _common_axis(data.axes), ()))  # fmt: skip
    return _hold_declared(moved)


def _hold_declared(vec: ParamVector) -> ParamVector:
    """``vec`` with the declared parameters held where they are (contact searched).

    With a floor in the data they were fitted on airborne windows; fitted again through
    the impacts (the states' fits there are poorer: no axial spins, the contact's
    small jumps) they drift, by 3.7 mm RMS on the airborne prefixes in a trial.
    """
    return replace(vec, free=torch.zeros_like(vec.free))


def _extra_k(data: _Data, vec: ParamVector) -> int:
    """Parameters of ``vec``'s model fitted outside its vector (see ``TrajFit.extra_k``)."""
    if not _contact_searched(vec):
        return 0
    return len(CONTACT_FREE) + (data.declared_k if not bool(vec.free.any()) else 0)


def _touchdown_contact(data: _Data, vec: ParamVector, theta: torch.Tensor) -> GroundContact | None:
    """The contact of ``vec`` (its last effect) searched on the touchdowns, or None.

    The declared parameters and the other effects are held at ``theta``. After a search
    the contact is held in every later fit (``data.contact_free``).
    """
    assert vec.coords is not None
    effects = vec.coords.effects_at(theta[vec.n_free :].detach())
    others, contact = effects[:-1], effects[-1]
    assert isinstance(contact, GroundContact)
    fixed = _held(vec, theta)
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


def _common_axis(axes: RodAxes) -> int | None:
    """The end-cap axis (rod frame) if every rod has the same one."""
    return int(axes.axis[0]) if np.all(axes.axis == axes.axis[0]) else None


@torch.no_grad()
def _fixed_engine(data: _Data, fit: TrajFit) -> tuple[Engine, ParamVector]:
    """The engine with ``fit``'s effects and a vector with nothing free (its params)."""
    return data.engine.with_effects(fit.effects), _held(fit.vec, fit.theta)


def _held(vec: ParamVector, theta: torch.Tensor) -> ParamVector:
    """``vec`` at ``theta`` with nothing free and no effect coordinates (states-only fits)."""
    return replace(vec, start=vec.full(theta.detach()), free=torch.zeros_like(vec.free),
                   coords=None)  # fmt: skip


def heldout(data: _Data, fit: TrajFit, split: str, iters: int) -> tuple[float, int, Windows]:
    """Sum of squared end-cap errors [m^2] on a split's windows, only their states fitted."""
    engine, vec = _fixed_engine(data, fit)
    w = fit_states(engine, vec, data.windows[split], iters, roll=data.roll)
    m = w.windows.residuals
    return w.history[-1] * m, m, w.windows


@torch.no_grad()
def predicted_caps(data: _Data, fit: TrajFit, windows: Windows) -> torch.Tensor:
    """End caps (B, W+1, 2R, 3) [m] of ``fit`` rolled out from ``windows``' states."""
    engine, vec = _fixed_engine(data, fit)
    roll = engine.rollout(windows.state, vec.params(vec.start), windows.steps, windows.control)
    return end_caps(engine, roll.p, roll.q)


# ---------------------------------------------------------------------- candidates
def _proposals(
    data: _Data, current: TrajFit, names: Sequence[str] | None
) -> list[tuple[str, Any, str]]:
    """``(name, effect or None, gate text)`` for every candidate not yet in the model."""
    topo, have = data.topology, {e.name for e in current.effects}
    out: list[tuple[str, Any, str]] = []

    def add(name: str, effect: Any, gate: str) -> None:
        again = name == "slack_springs"  # more cables may show once the first are slack
        if (again or name not in have) and (names is None or name in names):
            out.append((name, effect, gate))

    ok, gate = contact_gate(data.train, topo)
    add("ground_contact", GroundContact(topo, **CONTACT_START) if ok else None, gate)
    add("slack_springs", "probe", "springs shorter than rest (segmented regression)")
    add("linear_drag", LinearDrag(topo), "acts everywhere, opposing v and ω")
    add("quadratic_drag", QuadraticDrag(topo), "acts everywhere, opposing v|v| and ω|ω|")
    add("force_field", ForceField(topo), "acts on every rod, always")
    add("cubic_stiffness", CubicStiffness(topo), "acts along every spring, grows with (l - l0)^3")
    add("rest_length_offset", None, "rest lengths are fitted already")
    if np.any(data.train.control != 0):
        add("control_lag", None, "not yet available for end-cap-only data")
    else:
        add("control_lag", None, "no control in this data")
    return out


def slack_hypothesis(
    data: _Data, current: TrajFit, s: TrajectorySettings
) -> tuple[SlackSprings | None, str, dict[str, np.ndarray] | None]:
    """Cables from the segmented regression (:mod:`identification.trajectory.slack_regression`).

    Returns the candidate (every cable, old and new; None when no new one shows), its
    gate text, and the regression's parameter values it starts from.
    """
    old = [e for e in current.effects if isinstance(e, SlackSprings)]
    known = {int(i) for e in old for i in e.values["springs"].tolist()}
    reg = slack_regression(data.topology, data.smooth["train"], data.train.control, s.anchors,
                           keep=_airborne_keep(data))  # fmt: skip
    new = sorted(set(reg.cables()) - known)
    if not new:
        free = [i for i in range(data.topology.n_springs) if i not in known]
        z = reg.significance[free]
        lo, hi = CABLE_LOSS
        return (
            None,
            (
                f"no (further) spring loses {lo:.0%}-{hi:.0%} of K when compressed by "
                f"{CABLE_SIGNIFICANCE:g} standard errors (largest significance {z.max():.3g})"
            ),
            None,
        )
    cables = sorted(known | set(new))
    loss = reg.loss[new]
    gate = (f"{len(new)} {'more ' if known else ''}springs lose {np.median(loss):.0%} of K "
            f"when compressed (segmented regression, ≥{reg.significance[new].min():.0f} "
            f"standard errors)")  # fmt: skip
    return SlackSprings(data.topology, springs=cables), gate, reg.values


def fit_slack(
    data: _Data, current: TrajFit, effect: SlackSprings, values: dict[str, np.ndarray],
    s: TrajectorySettings,
) -> TrajFit:  # fmt: skip
    """The cable hypothesis fitted like the declared model, from its own regression.

    Started from the current model instead, a fit stays near the compromise the springs
    made for the missing cables (lower stiffness, shorter rest length). With a searched
    contact in the model (its parameters held) the usual joint fit runs instead.
    """
    effects = [*current.start_effects, effect]
    if _contact_searched(current.vec):
        return fit_with(data, current, effects, s.candidate_iter)
    many, fit = fit_declared(data, s, effects=effects, values=values)
    data.log(f"    {effect.name}: fitted from the segmented regression, end-cap RMS "
             f"{many.rms * 1e3:.3f} mm on {many.windows.size} windows")  # fmt: skip
    return fit


def _judge(c: Candidate, current: Candidate) -> None:
    c.bic_drop = current.fit.bic - c.fit.bic
    sigma2 = c.val_sse / max(c.val_m, 1)
    c.chi2_gain = (current.val_sse - c.val_sse) / sigma2 if np.isfinite(c.val_sse) else -np.inf
    if not c.physical:
        c.verdict = "rejected: identified values are unphysical"
    elif not c.bic_drop >= MIN_BIC_DROP:
        c.verdict = f"rejected: BIC drops only {c.bic_drop:.3g} (< {MIN_BIC_DROP:g})"
    elif not c.chi2_gain >= MIN_CHI2_GAIN:
        c.verdict = f"rejected: held-out chi-square drops only {c.chi2_gain:.3g}"
    else:
        c.accepted = True
        c.verdict = f"passes (held-out chi-square -{c.chi2_gain:.4g}, ΔBIC -{c.bic_drop:.4g})"


def _corr(x: torch.Tensor, y: torch.Tensor) -> float:
    x, y = x.reshape(-1) - x.mean(), y.reshape(-1) - y.mean()
    den = float(torch.linalg.vector_norm(x) * torch.linalg.vector_norm(y))
    return float((x * y).sum()) / den if den > 0 else 0.0


# ---------------------------------------------------------------------- the loop
def diagnose_noisy(
    dataset: Dataset,
    settings: TrajectorySettings,
    max_effects: int = 3,
    candidates: Sequence[str] | None = None,
    clean: Dataset | None = None,
    horizon_s: float = 1.0,
    start: Params | None = None,
    log: Callable[[str], None] = print,
    plots: Path | None = None,
) -> NoisyDiagnoseResult:
    """Run the loop on end-cap data (see the module docstring).

    ``clean``: the same trajectories without noise, with rod states (planted data),
    for the test errors against the truth; never used for fitting or selection.
    ``plots``: folder for each iteration's held-out residual PNG.
    """
    data = _Data(dataset, settings)
    data.log = log
    t0 = time.perf_counter()
    noise = noise_level(dataset.split("train").nodes)
    log(f"noise level estimated from the training end caps: {noise * 1e3:.3g} mm")
    final, base = fit_declared(data, settings, start)
    log(f"declared model: end-cap RMS {final.rms * 1e3:.3f} mm on {final.windows.size} "
        f"training windows ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    for fit in (final, base):
        check_stage("the declared model's fit", fit.rms, noise, "shorter windows (--window), a "
                    "smaller --physics-dt, or a starting params file (--params)")  # fmt: skip
    current = _score(data, Candidate("nothing", base), settings)
    test_now = _test(data, final, settings, clean, horizon_s)
    baseline = test_now
    iterations: list[NoisyIteration] = []
    for _ in range(max_effects):
        tried: list[Candidate] = []
        skipped: list[tuple[str, str]] = []
        for name, effect, gate in _proposals(data, current.fit, candidates):
            t1 = time.perf_counter()
            values = None
            if effect == "probe":
                effect, gate, values = slack_hypothesis(data, current.fit, settings)
            if effect is None:
                skipped.append((name, gate))
                continue
            if values is not None:
                fit = fit_slack(data, current.fit, effect, values, settings)
            else:
                fit = fit_with(
                    data, current.fit, [*current.fit.start_effects, effect], settings.candidate_iter
                )
            if fit_diverged(fit.rms, noise):
                skipped.append((name, f"its fit diverged (end-cap RMS {fit.rms * 1e3:.3g} mm)"))
                continue
            c = _score(data, Candidate(name, fit, gate), settings)
            c.physical = all(e.physical() for e in fit.effects)
            c.seconds = time.perf_counter() - t1
            _judge(c, current)
            log("    " + "; ".join(e.describe() for e in fit.effects))
            log(f"  candidate {name:18s} val RMS {c.val_rms * 1e3:.4f} mm, Δchi2 {c.chi2_gain:+.4g}, "
                f"ΔBIC {-c.bic_drop:+.4g}: {c.verdict} ({c.seconds:.0f} s)")  # fmt: skip
            tried.append(c)
        tried.sort(key=lambda c: (not c.accepted, -c.chi2_gain))
        chosen = tried[0] if tried and tried[0].accepted else None
        ambiguous, runner_up = None, None
        if chosen is not None and len(tried) > 1 and tried[1].accepted:
            runner = tried[1]
            ref = predicted_caps(data, current.fit, current.val_windows)  # type: ignore[arg-type]
            corr = _corr(
                predicted_caps(data, chosen.fit, current.val_windows) - ref,  # type: ignore[arg-type]
                predicted_caps(data, runner.fit, current.val_windows) - ref,  # type: ignore[arg-type]
            )
            gap = chosen.chi2_gain - runner.chi2_gain
            runner_up = (runner.name, corr, gap)
            if corr > AMBIGUOUS_CORRELATION and gap < AMBIGUOUS_CHI2:
                ambiguous = (runner.name, corr)
        it = NoisyIteration(current, tried, skipped, chosen, ambiguous, test_now)
        it.runner_up = runner_up
        _residuals(data, current, it, plots, len(iterations), dataset)
        iterations.append(it)
        if chosen is None:
            break
        fit = fit_with(data, chosen.fit, chosen.fit.effects, settings.base_iter)  # converge
        t1 = time.perf_counter()
        final = fit_many(data, fit.vec, fit.theta, settings, settings.base_iter)
        log(f"  refitted on {final.windows.size} training windows: end-cap RMS "
            f"{final.rms * 1e3:.3f} mm ({time.perf_counter() - t1:.0f} s)")  # fmt: skip
        check_stage(f"the final fit with {chosen.name}", final.rms, noise,
                    "--max-effects to stop before it, or --fit-window shorter")  # fmt: skip
        if not data.roll and sees_roll(_fixed_engine(data, final)[0]):
            # from now on every fit and score fits the windows' rolls too, so the next
            # candidates are not judged on making up for them (without: a 1.2 N "force
            # field" passed on quadratic drag; 0.06 N once the rolls were fitted)
            data.roll = True
            fit = _fit(data, fit.vec, fit.windows, final.theta, settings.base_iter)
        fit.origin = final.theta
        chosen = _score(data, replace(chosen, fit=fit), settings)
        test_now = _test(data, final, settings, clean, horizon_s)
        it.test_after = test_now
        note = ""
        if runner_up is not None:
            note = (f" (runner-up {runner_up[0]}: predicted changes correlate {runner_up[1]:.3f}, "
                    f"held-out chi-square {runner_up[2]:.4g} higher"
                    + ("; CANNOT be told apart)" if ambiguous else ")"))  # fmt: skip
        log(f"added {chosen.name}{note}")
        current = chosen
    model = FittedModel(Model(dataset.topology, final.params, final.effects, dataset.dt), final.k)
    return NoisyDiagnoseResult(
        iterations=iterations, model=model, baseline_test=baseline, final_test=test_now,
        settings={"anchors": dict(settings.anchors), "window": settings.window,
                  "fit_windows": settings.fit_windows, "min_bic_drop": MIN_BIC_DROP,
                  "min_chi2_gain": MIN_CHI2_GAIN},
    )  # fmt: skip


def _residuals(
    data: _Data, current: Candidate, it: NoisyIteration, plots: Path | None, k: int,
    dataset: Dataset,
) -> None:  # fmt: skip
    """The current model's held-out (validation) end-cap residuals: numbers and PNG."""
    assert current.val_windows is not None
    radius = np.repeat([rod.radius for rod in data.topology.rods], 2)
    pred = predicted_caps(data, current.fit, current.val_windows)
    res = window_residuals(pred, current.val_windows.obs, data.dt, radius)
    it.residual = summarize_window_residuals(res)
    if plots is not None:
        label = " + ".join(["declared model", *(e.name for e in current.fit.effects)])
        noise = float(dataset.attrs.get("measurement_noise_std", 0.0))
        it.plot = plot_window_residuals(res, plots / f"residuals_{k}.png",
                                        f"iteration {k}: held-out residuals of {label}", noise)  # fmt: skip


def _score(data: _Data, c: Candidate, s: TrajectorySettings) -> Candidate:
    c.val_sse, c.val_m, c.val_windows = heldout(data, c.fit, "val", s.state_iter)
    return c


def _test(
    data: _Data, fit: TrajFit, s: TrajectorySettings, clean: Dataset | None, horizon_s: float
) -> dict[str, float]:
    """Test-split errors: held-out end-cap RMS [m]; against the clean truth if given."""
    sse, m, _ = heldout(data, fit, "test", s.state_iter)
    out = {"caps_rms": float(np.sqrt(sse / m))}
    if clean is not None:
        ev = evaluate_model(data.topology, fit.params, fit.effects, clean, "test", horizon_s)
        out.update(one_step=float(ev["one_step"]), rollout=float(ev["rollout"]))
    return out
