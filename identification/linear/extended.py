"""The linear regression extended by effects: the joint refit of the residual loop.

:class:`ExtendedIdentifier` is :class:`~identification.linear.regression.SpringRodIdentifier`
with the model's effects folded into the same design matrix:

* a :class:`~tensegrity_env.effects.base.LinearEffect` (drag, force field, cubic
  stiffness, rest-length offset) adds its columns ``-basis`` (force per unit
  parameter, torque in the rod frame) and is identified jointly with K, K·l0, c,
  M, I, h;
* an effect that switches springs' elasticity off
  (:meth:`~tensegrity_env.effects.base.PhysicalEffect.elastic`: slack cables, while
  shorter than rest) switches their elastic columns off (the break point is the
  reference rest length; :meth:`ExtendedIdentifier.fit` iterates it);
* an effect whose gate depends on where the end caps are
  (:meth:`~tensegrity_env.effects.base.PhysicalEffect.clearance`: ground contact) is
  not linear in its parameters: rods the gate says it touches are left out of the
  regression, and its parameters are fitted through the engine
  (:mod:`identification.trajectory.windowed_problem`);
* ``compression_columns`` adds, per spring, ``ΔK_s (l - l0) [l < l0]``: a linear
  probe for springs that lose stiffness when compressed (cables go slack).

Effects' own values (for example a slack spring's break point ``l0`` and cubic
stiffness' ``l0``) are read from ``reference`` params, the previous fit.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from identification.data.dataset import Dataset, Split
from identification.linear.design import (
    ParameterLayout,
    RodSlots,
    accumulate_normal,
    rod_blocks,
    rod_slots,
)
from identification.linear.features import (
    cable_commands_at,
    drawn_transitions,
    transition_features,
    transitions_of,
)
from identification.linear.regression import SpringRodIdentifier
from tensegrity_env.effects import LinearEffect
from tensegrity_env.effects.base import PhysicalEffect, spring_unit_wrench
from tensegrity_env.engine import Engine, State
from tensegrity_env.engine.kinematics import AttachmentPoints, node_kinematics
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params

DTYPE = torch.float64


class ExtendedIdentifier(SpringRodIdentifier):
    """Linear regression of the declared parameters jointly with linear effects.

    Args:
        effects: the model's effects (see the module docstring for how each enters).
        reference: params for break points and rest lengths the effects need
            (the previous fit); None: estimated by a first plain fit.
        compression_columns: add the per-spring compression probe ``ΔK_s``.
        contact_margin: with a gated (contact) effect, leave out rods with an end cap
            within this distance of the floor [m].
        iterations: at most this many refits updating ``reference`` from the last fit
            (break points), until no rest length moves more than ``tolerance`` [m].
        **kwargs: :class:`SpringRodIdentifier` settings (anchors, init_params, ...).

    After ``fit``: everything of :class:`SpringRodIdentifier`, plus ``effects_`` (the
    effects with identified values and standard errors), ``compression_`` (ΔK per
    spring [N/m] and its standard error, when probed), ``rows_used_`` (fraction of
    rod equations kept).
    """

    def __init__(
        self,
        effects: Sequence[PhysicalEffect] = (),
        reference: Params | None = None,
        compression_columns: bool = False,
        contact_margin: float = 0.0,
        iterations: int = 20,
        tolerance: float = 1e-11,
        **kwargs: Any,
    ) -> None:
        super().__init__(**kwargs)
        self.effects = list(effects)
        self.reference = reference
        self.compression_columns = compression_columns
        self.contact_margin = contact_margin
        self.iterations = iterations
        self.tolerance = tolerance

    # ------------------------------------------------------------------ fitting
    def fit(self, dataset: Dataset, split: str = "train") -> ExtendedIdentifier:
        if dataset.topology.n_winches:  # its design has no winding columns
            raise InputError(f"{dataset.path or 'dataset'}: the robot has winches; the effect "
                             "regression does not take them (SpringRodIdentifier does)")  # fmt: skip
        # effects inside the regression read break points and rest lengths from a reference
        needs_reference = (
            any(e.fit_form.route == "regression" for e in self.effects)
            or self.compression_columns
        )
        self._ref = self.reference
        passes = self.iterations if needs_reference else 1
        if self._ref is None and needs_reference:
            plain = ExtendedIdentifier(
                effects=[e for e in self.effects if e.fit_form.route != "regression"],
                contact_margin=self.contact_margin, **self._base_kwargs(),
            ).fit(dataset, split)  # fmt: skip
            self._ref = plain.params_
        lagged = self._lagged(dataset)
        for _ in range(passes):
            before = self._ref
            super().fit(lagged, split)
            self._ref = self.params_
            if before is not None:
                moved = (self.params_.rest_length - before.rest_length).abs().max()
                if float(moved) < self.tolerance:
                    break
        self.effects_ = self._fitted_effects()
        return self

    def _base_kwargs(self) -> dict[str, Any]:
        keys = ("solver", "shared", "fit_rest_length", "anchors", "init_params", "freeze",
                "gravity", "chunk_size", "max_transitions", "fraction", "seed")  # fmt: skip
        return {k: getattr(self, k) for k in keys}

    def _lagged(self, dataset: Dataset) -> Dataset:
        """The dataset with lagged commands where the model has a control lag."""
        lag = next((e for e in self.effects if e.filters_commands), None)
        if lag is None:
            return dataset
        splits = {}
        for name, s in dataset.splits.items():
            ctrl = lag.filter_commands(torch.as_tensor(s.control), dataset.dt).numpy()
            cables = cable_commands_for(self.effects, s.cable_control, dataset.dt)
            splits[name] = Split(nodes=s.nodes, control=ctrl, p=s.p, v=s.v, q=s.q, omega=s.omega,
                                 cable_control=cables)  # fmt: skip
        return Dataset(dataset.topology, dataset.dt, splits, dataset.attrs, dataset.path)

    def _extra(self) -> list[tuple[int, LinearEffect]]:
        return [(i, e) for i, e in enumerate(self.effects) if isinstance(e, LinearEffect)]  # the abstract base: columns -basis

    def _normal_equations(
        self, dataset: Dataset, data: Split, layout: ParameterLayout, index: np.ndarray
    ) -> tuple[torch.Tensor, int]:
        topo = dataset.topology
        slots = rod_slots(layout)
        P, R, S = layout.n_params, topo.n_rods, topo.n_springs
        extra = self._extra()
        sizes = [int(e.theta().numel()) for _, e in extra]
        n_comp = S if self.compression_columns else 0
        E = sum(sizes) + n_comp
        cols = slots.columns.clone()
        cols[cols == P] = P + E
        cols = torch.cat([cols, (P + torch.arange(E)).expand(R, E)], dim=1)
        slots_ext = RodSlots(slots.spring, slots.node, slots.sign, cols, slots.cable)
        g = torch.tensor(self.gravity, dtype=DTYPE)
        rest = None
        if not layout.fit_rest_length:
            assert self.init_params is not None
            rest = self.init_params.rest_length.detach().double()
        ref = self._ref
        normal = torch.zeros(P + E + 1, P + E + 1, dtype=DTYPE)
        kept = 0.0
        ends = torch.as_tensor(topo.end_offsets, dtype=DTYPE)
        anchors = torch.as_tensor(topo.anchor_positions, dtype=DTYPE)
        points = AttachmentPoints.of(topo)
        for start in range(0, len(index), self.chunk_size):
            chunk = index[start : start + self.chunk_size]
            s0, s1, u = transitions_of(data, chunk)
            feat = transition_features(topo, s0, s1, u, dataset.dt, cable_commands_at(data, chunk))
            A = rod_blocks(feat, slots, g, rest)  # (n, R, 6, L)
            kin = node_kinematics(s0, ends, anchors, points)
            l0 = ref.rest_length.double() if ref is not None else None
            elastic = [] if l0 is None else [
                m for e in self.effects if (m := e.elastic(feat.springs.length, l0)) is not None
            ]  # fmt: skip
            if elastic:  # springs whose elastic tension an effect switches off (slack cables)
                taut = torch.stack(elastic).all(0)  # (n, S)
                t = taut[:, slots.spring].to(DTYPE)  # (n, R, J)
                J = slots.spring.shape[1]
                for k in (4, 5):  # K and K*l0 columns of every slot
                    idx = torch.arange(J) * 3 + k
                    A[..., idx] = A[..., idx] * t.unsqueeze(2)
            blocks = [A]
            for _, effect in extra:
                f, tq = effect.transition_basis(
                    s0, s1, kin, ref if ref is not None else _dummy(topo)
                )
                tq_l = torch.einsum("nrji,nrjp->nrip", kin.rot, tq)
                blocks.append(-torch.cat([f, tq_l], dim=2))
            if n_comp:
                assert l0 is not None
                f, tq, length = spring_unit_wrench(kin, topo)
                comp = (length - l0) * (length < l0)
                tq_l = torch.einsum("nrji,nrjp->nrip", kin.rot, tq)
                blocks.append(-torch.cat([f, tq_l], dim=2) * comp[:, None, None])
            A = torch.cat(blocks, dim=-1)
            # rods within the margin of where a gated effect (contact) acts are left out
            clear = [d for e in self.effects if (d := e.clearance(s0, kin)) is not None]
            if clear:
                touch = torch.zeros(A.shape[:2], dtype=torch.bool)
                for dist in clear:
                    touch |= (dist < self.contact_margin).any(-1)
                A = A * (~touch).to(DTYPE)[..., None, None]
                kept += float((~touch).sum())
            else:
                kept += A.shape[0] * R
            accumulate_normal(A, slots_ext, P + E, normal)
        self.rows_used_ = kept / max(len(index) * R, 1)
        self._sizes, self._n_comp = sizes, n_comp
        return normal, int(kept) * 6

    def _fitted_effects(self) -> list[PhysicalEffect]:
        theta, stderr = self.solution_.theta, self.solution_.stderr
        P = self.layout_.n_params
        out = list(self.effects)
        i = P
        for (k, effect), n in zip(self._extra(), self._sizes, strict=True):
            out[k] = effect.with_theta(np.nan_to_num(theta[i : i + n]), stderr[i : i + n])
            i += n
        if self._n_comp:
            self.compression_ = (theta[i : i + self._n_comp], stderr[i : i + self._n_comp])
        return out

    # ------------------------------------------------------------------ using the fit
    def engine(self) -> Engine:
        base = super().engine()
        return base.with_effects(self.effects_)


def _dummy(topology: Any) -> Params:
    S, R = topology.n_springs, topology.n_rods
    return Params.create(np.ones(S), np.zeros(S), np.zeros(S), np.ones(R), np.ones((R, 3)))


# ---------------------------------------------------------------------- evaluation
def commands_for(
    effects: Sequence[PhysicalEffect], control: torch.Tensor, dt: float
) -> torch.Tensor:
    """The commands that act, (B, T, R, 3): lagged where the model has a control lag."""
    for e in effects:
        if e.filters_commands:
            control = e.filter_commands(control, dt)
    return control


def cable_commands_for(
    effects: Sequence[PhysicalEffect], cables: np.ndarray | None, dt: float
) -> np.ndarray | None:
    """The cable commands that act, (N, T, C): through MuJoCo's actuator filter where
    the model has a control lag (None stays None)."""
    lag = next((e for e in effects if e.filters_commands), None)
    if cables is None or lag is None:
        return cables
    return lag.filter_commands(torch.as_tensor(cables), dt, explicit=True).numpy()


def acting_split(effects: Sequence[PhysicalEffect], data: Split, dt: float) -> Split:
    """``data`` with the commands that act: control forces (B, T, R, 3) and cable
    commands (B, T, C) through the model's control lag, if it has one (else ``data``)."""
    if not any(e.filters_commands for e in effects):
        return data
    control = commands_for(effects, torch.as_tensor(data.control), dt).numpy()
    cables = cable_commands_for(effects, data.cable_control, dt)
    return dataclasses.replace(data, control=control, cable_control=cables)


def evaluate_model(
    topology: Any,
    params: Params,
    effects: Sequence[PhysicalEffect],
    dataset: Dataset,
    split: str = "val",
    horizon_s: float = 1.0,
    max_one_step: int = 20_000,
    seed: int = 0,
) -> dict[str, Any]:
    """One-step and rollout errors [m] of the model (params + effects) on a split.

    ``one_step``: mean rod position error of one engine step from every measured
    state (a random subset of ``max_one_step`` transitions); ``rollout``: mean rod
    position error after ``horizon_s`` seconds rolled out open-loop from each
    trajectory's first state (and from later starts, one per horizon, so every
    sample of the split is used); ``curve``: the rollout error per step (H+1,).
    """
    data = dataset.split(split)
    engine = Engine(topology, dataset.dt, effects=effects, native=True)  # no gradient: C
    T = data.n_transitions
    idx = drawn_transitions(data, max_one_step, seed)
    lagged = acting_split(effects, data, dataset.dt)
    ctrl_all = torch.as_tensor(lagged.control)
    cables_all = lagged.cable_control
    s0, s1, u = transitions_of(lagged, idx)
    cables = cable_commands_at(lagged, idx)
    H = min(T, max(1, round(horizon_s / dataset.dt)))
    starts = np.arange(0, T - H + 1, H)
    assert data.p is not None
    with torch.no_grad():
        pred = engine.step(s0, params, u, cables)
        one = float(torch.linalg.vector_norm(pred.p - s1.p, dim=-1).mean())
        init = State(*(torch.as_tensor(getattr(data, k)[:, starts].reshape(-1, *getattr(data, k).shape[2:]))
                       for k in ("p", "v", "q", "omega")))  # fmt: skip
        t = starts[:, None] + np.arange(H)
        ctrl = ctrl_all[:, t].reshape(-1, H, *ctrl_all.shape[2:])
        cable_ctrl = None
        if cables_all is not None:
            cable_ctrl = torch.as_tensor(cables_all[:, t].reshape(-1, H, cables_all.shape[-1]))
        roll = engine.rollout(init, params, H, ctrl, cable_ctrl)
        tt = starts[:, None] + np.arange(H + 1)
        truth = torch.as_tensor(data.p[:, tt].reshape(-1, H + 1, *data.p.shape[2:]))
        # (rollouts from, or compared at, samples in a gap: NaN, left out)
        curve = torch.linalg.vector_norm(roll.p - truth, dim=-1).nanmean(dim=(0, 2)).numpy()
    return {
        "one_step": one,
        "rollout": float(curve[-1]),
        "rollout_mean": float(curve.mean()),
        "curve": curve,
        "horizon_s": H * dataset.dt,
    }
