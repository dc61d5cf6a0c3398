"""Candidate effects of the residual loop: when each may act (its gate), and how it is fitted.

:func:`fit_model` refits the declared parameters jointly with a list of effects:
linear effects and slack cables inside the regression
(:class:`~identification.linear.extended.ExtendedIdentifier`), then ground contact (not
linear in its parameters) through the engine on short trajectory windows
(:func:`~identification.trajectory.windowed_problem.fit`, its dense method) with the regression's
parameters held. :func:`propose` lists the candidates of the effect library
(:data:`LIBRARY`, the registry :data:`tensegrity_env.effects.EFFECTS`) with the physical
gates their classes declare; :func:`slack_probe` names slack cables from the
regression on rod states.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from identification.data.dataset import Dataset, Split
from identification.linear.extended import ExtendedIdentifier, acting_split
from identification.trajectory.airborne import contact_gate
from identification.trajectory.fitted_model import FittedModel
from identification.trajectory.windowed_problem import FitOptions, WindowedProblem, fit
from identification.trajectory.windows import sample_windows
from tensegrity_env.effects import EFFECTS, ControlLag, SlackSprings
from tensegrity_env.effects.base import LinearEffect, PhysicalEffect
from tensegrity_env.engine import Engine
from tensegrity_env.model import Model
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology

#: a spring is a cable when compressing it loses this fraction of its stiffness...
SLACK_LOSS = 0.5
#: ... by at least this many standard errors
SLACK_SIGNIFICANCE = 5.0
#: control lag time constants tried first [s]
LAG_GRID = (0.002, 0.005, 0.01, 0.02, 0.05, 0.1)
#: the lag search ends when log τ is known to this (a relative tolerance on τ)
LAG_TOLERANCE = 0.01


@dataclass
class FitSettings:
    """How models are fitted.

    Attributes:
        anchors: known values fixing the scale, e.g. ``{"mass[rod0]": 1.95}``.
        init_params: starting params (known rest lengths, values for what the data
            cannot identify).
        fit_rest_length: identify rest lengths (else they come from ``init_params``).
        contact_windows: trajectory windows per contact-fit stage (length, count).
        contact_iterations: Levenberg-Marquardt iterations per contact-fit stage.
        seed: seed of window draws.
    """

    anchors: Mapping[str, float] = field(default_factory=dict)
    init_params: Params | None = None
    fit_rest_length: bool = True
    contact_windows: tuple[tuple[int, int], ...] = ((1, 2000),)
    contact_iterations: int = 20
    seed: int = 0


def _through_engine(e: PhysicalEffect) -> bool:
    """Whether ``e`` is fitted through the engine after the regression (contact)."""
    return e.fit_form.route == "engine"


def _ordered(effects: Sequence[PhysicalEffect]) -> list[PhysicalEffect]:
    """Effects fitted through the engine last: contact reads the springs' tensions after
    every other effect."""
    return [e for e in effects if not _through_engine(e)] + [
        e for e in effects if _through_engine(e)
    ]


def fit_model(
    dataset: Dataset, effects: Sequence[PhysicalEffect], settings: FitSettings
) -> FittedModel:
    """Refit the declared parameters jointly with ``effects`` on the training split."""
    effects = _ordered(effects)
    est = ExtendedIdentifier(
        effects=effects,
        anchors=settings.anchors,
        init_params=settings.init_params,
        fit_rest_length=settings.fit_rest_length,
    ).fit(dataset)
    fitted = list(est.effects_)
    n = int(np.sum(~est.solution_.fixed & est.solution_.identifiable))
    notes: dict[str, str] = {}
    for i in [i for i, e in enumerate(fitted) if _through_engine(e)]:
        fitted, extra = _fit_through_engine(dataset, est.params_, fitted, i, settings)
        notes[fitted[i].name] = extra
    n += sum(e.fit_form.n_extra for e in fitted)
    model = Model(dataset.topology, est.params_, tuple(fitted), dataset.dt)
    return FittedModel(model, n, notes, regression_uncertainty(est))


def regression_uncertainty(est: ExtendedIdentifier) -> dict[str, float]:
    """Standard errors of the declared parameters a regression fitted, by name [units]
    (anchored, frozen and unidentifiable ones left out)."""
    return {
        r.name: float(r.stderr)
        for r in est.table_
        if r.status in ("identified", "ratio") and np.isfinite(r.stderr)
    }


def _fit_through_engine(
    dataset: Dataset,
    params: Params,
    effects: list[PhysicalEffect],
    i: int,
    settings: FitSettings,
) -> tuple[list[PhysicalEffect], str]:
    # the commands that act: a window starts with the control lag's state carried
    # from the trajectory's start, not at rest
    split = acting_split(effects, dataset.split("train"), dataset.dt)
    history: list[float] = []
    form = effects[i].fit_form
    engine = Engine(dataset.topology, dataset.dt)
    for length, count in settings.contact_windows:
        windows = sample_windows(split, length, count, seed=settings.seed + length)
        for names in form.stages or (form.free,):
            problem = WindowedProblem.effects_only(engine, params, effects,
                                                   [(i, k) for k in names], windows)  # fmt: skip
            done = fit(problem, FitOptions.dense(max_iter=settings.contact_iterations))
            effects, history = problem.effects_at(done), done.history
            # the standard errors of this stage's parameters alone
            effects[i].uncertainty = {k: effects[i].uncertainty[k] for k in names}
    assert history
    rms = float(np.sqrt(history[-1]))
    return (
        effects,
        f"fitted through the engine on {count} windows of {length} steps (RMS {rms:.2e} m)",
    )


# ---------------------------------------------------------------------- proposals
#: the effect library, in the order its candidates are proposed (the registry's)
LIBRARY: tuple[str, ...] = tuple(EFFECTS)


@dataclass
class Proposal:
    """One candidate: the effect to add (None: its gate is not passed) and why.

    Attributes:
        name: the effect's name (a key of :data:`LIBRARY`).
        effect: the effect at its starting values, or None when not tried.
        gate: why it may act here, or why not.
        start: parameter values its fit starts from (natural units), if not the
            current model's (slack cables on end caps start from their own regression).
    """

    name: str
    effect: PhysicalEffect | None
    gate: str
    start: dict[str, np.ndarray] | None = None


def propose(
    split: Split,
    topology: Topology,
    have: Collection[str],
    names: Sequence[str] | None,
    gates: Mapping[str, Callable[[], Proposal]],
    again: Collection[str] = (),
) -> list[Proposal]:
    """Every library effect not yet in the model (``have``), gated by what ``split`` shows.

    ``names``: only these (None: all). ``gates``: the scorer's own gate for an effect
    (called only when it is proposed), replacing the standard one; ``slack_springs``
    has none here (each scorer names cables its own way). ``again``: proposed even
    when in the model (more cables may show once the first are slack).
    """
    standard = {name: _gated(name, split, topology) for name in LIBRARY}
    out: list[Proposal] = []
    for name in LIBRARY:
        if (name in have and name not in again) or (names is not None and name not in names):
            continue
        gate = gates.get(name, standard[name])
        if gate is None:
            raise ValueError(f"no gate for library effect {name!r}")
        out.append(gate())
    return out


def _gated(name: str, split: Split, topology: Topology) -> Callable[[], Proposal] | None:
    """The standard gate of library effect ``name``, as its class declares it (None: the
    scorer's own, ``needs="scorer"``)."""
    cls = EFFECTS[name]
    needs = cls.gate.needs
    if needs == "scorer":
        return None
    if needs == "floor":
        return lambda: floor_proposal(name, split, topology)
    if needs == "commands":
        return lambda: (
            Proposal(name, cls(topology), cls.gate.text)
            if has_commands(split)
            else Proposal(name, None, "no control in this data")
        )
    if needs:
        raise ValueError(f"effect {name!r}: unknown gate need {needs!r}")
    return lambda: Proposal(name, cls(topology), cls.gate.text)


def _start(name: str, topology: Topology) -> PhysicalEffect:
    """Library effect ``name`` at the start its class declares for an engine fit."""
    cls = EFFECTS[name]
    start: dict[str, Any] = dict(cls.fit_form.start or {})  # parameter name -> value
    return cls(topology, **start)


def floor_proposal(name: str, split: Split, topology: Topology) -> Proposal:
    """An effect that needs a floor (contact) where end caps reach one that stops them."""
    ok, why = contact_gate(split, topology)
    return Proposal(name, _start(name, topology) if ok else None, why)


def contact_proposal(split: Split, topology: Topology) -> Proposal:
    """Ground contact where end caps reach the floor and the floor stops them."""
    return floor_proposal("ground_contact", split, topology)


def slack_probe(
    dataset: Dataset, current: FittedModel, settings: FitSettings
) -> tuple[list[int], str]:
    """Springs whose stiffness drops when compressed: ``ΔK_s (l - l0) [l < l0]`` per spring."""
    if SlackSprings.name in current.names:
        return [], "already in the model"
    regressed = [e for e in current.effects if isinstance(e, LinearEffect) or _through_engine(e)]  # the abstract base: linear in theta()
    est = ExtendedIdentifier(
        effects=regressed,
        anchors=settings.anchors, init_params=settings.init_params,
        fit_rest_length=settings.fit_rest_length, compression_columns=True,
        reference=current.params,
    ).fit(dataset)  # fmt: skip
    dk, se = est.compression_
    k = est.params_.stiffness.detach().numpy()
    loss = -dk / k
    cables = [
        int(s) for s in np.flatnonzero((loss > SLACK_LOSS) & (np.abs(dk) > SLACK_SIGNIFICANCE * se))
    ]
    if not cables:
        return [], f"no spring loses stiffness when compressed (largest loss {loss.max():.0%})"
    names = ", ".join(dataset.topology.springs[s].name for s in cables)
    return (
        cables,
        f"{len(cables)} springs lose {np.median(loss[cables]):.0%} of K when compressed: {names}",
    )


def has_commands(split: Split) -> bool:
    """Whether ``split`` applies any command: control forces f_u or cable commands."""
    cables = split.cable_control
    return bool(np.any(split.control != 0) or (cables is not None and np.any(cables != 0)))


def fit_lag(dataset: Dataset, base: Sequence[PhysicalEffect], settings: FitSettings) -> FittedModel:
    """Control lag: the time constant τ [s] that minimises the regression's residual.

    Given τ the model is linear in its parameters (the regression refits the gains h
    and the cable gains for each τ), so the search is one-dimensional
    (:func:`search_lag`). A lag of zero (no filter) is not in the search: that model is
    ``base`` itself. Where ``base`` has floor contact (held at its values during the
    search), the contact is refitted through the engine with the lag found (as
    :func:`fit_model` fits it), τ is searched again near the first value with that
    contact, and the contact refitted once more.
    """
    best = search_lag(dataset, base, settings)
    if not any(_through_engine(e) for e in base):
        return best
    refit = fit_model(dataset, best.effects, settings)
    lag = next(e for e in refit.effects if e.fit_form.route == "search")
    rest = [e for e in refit.effects if e.fit_form.route != "search"]
    best = search_lag(dataset, rest, settings, near=float(lag.values["time_constant"]))
    return fit_model(dataset, best.effects, settings)


def search_lag(
    dataset: Dataset,
    base: Sequence[PhysicalEffect],
    settings: FitSettings,
    near: float | None = None,
) -> FittedModel:
    """The regression's best τ with ``base`` held: the residual on :data:`LAG_GRID`, then
    a bounded search in log τ between the best grid point's neighbours (to
    :data:`LAG_TOLERANCE` relative); with ``near`` [s], a search within 10 % of it to a
    tenth of that tolerance instead."""
    fits: dict[float, tuple[float, FittedModel]] = {}

    def rss_at(tau: float) -> float:
        if tau not in fits:
            effects = [*base, ControlLag(dataset.topology, time_constant=tau)]
            est = ExtendedIdentifier(
                effects=effects, anchors=settings.anchors, init_params=settings.init_params,
                fit_rest_length=settings.fit_rest_length,
            ).fit(dataset)  # fmt: skip
            n = int(np.sum(~est.solution_.fixed & est.solution_.identifiable)) + 1
            model = Model(dataset.topology, est.params_, tuple(est.effects_), dataset.dt)
            fits[tau] = (
                float(est.solution_.rss),
                FittedModel(model, n, uncertainty=regression_uncertainty(est)),
            )
        return fits[tau][0]

    if near is None:
        grid = [rss_at(tau) for tau in LAG_GRID]
        k = int(np.argmin(grid))
        lo = np.log(LAG_GRID[max(k - 1, 0)])
        hi = np.log(LAG_GRID[min(k + 1, len(LAG_GRID) - 1)])
        tolerance = LAG_TOLERANCE
    else:
        rss_at(near)
        lo, hi, tolerance = np.log(near / 1.1), np.log(near * 1.1), LAG_TOLERANCE / 10
    minimize_scalar(lambda x: rss_at(float(np.exp(x))), bounds=(lo, hi), method="bounded",
                    options={"xatol": tolerance})  # fmt: skip
    return min(fits.values(), key=lambda f: f[0])[1]


def fit_proposal(
    dataset: Dataset, current: FittedModel, proposal: Proposal, settings: FitSettings
) -> FittedModel:
    """A candidate's whole model, fitted jointly: ``current``'s effects plus the proposed one."""
    if proposal.effect is None:
        raise ValueError(f"{proposal.name}: not proposed ({proposal.gate})")
    if proposal.effect.fit_form.route == "search":  # the one searched effect: control lag
        return fit_lag(dataset, current.effects, settings)
    return fit_model(dataset, [*current.effects, proposal.effect], settings)
