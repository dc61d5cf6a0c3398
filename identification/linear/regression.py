"""Identification of K, c, l0, M, I, h by linear regression: the estimator.

Settings go in the constructor, ``fit(dataset) -> self`` learns ``params_`` and the
identifiability report, ``predict``/``simulate`` run the identified engine and
``score`` measures one-step and rollout errors on a split::

    est = SpringRodIdentifier(anchors={"mass[rod0]": 1.95}).fit(dataset)
    est.params_.stiffness        # (S,) [N/m]
    est.score(dataset, "test")   # {'one_step_position_error': ..., ...}

Over 400 lines because it is one estimator class (fit, identifiability report,
predict, simulate, score) whose parts share its fitted state. The user's scale
anchors are read and checked by :mod:`identification.linear.anchors`.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from identification.data.dataset import Dataset, Split
from identification.linear.anchors import check_anchor
from identification.linear.design import (
    ParameterLayout,
    accumulate_normal,
    rod_blocks,
    rod_slots,
    scatter_local_gram,
)
from identification.linear.features import (
    cable_commands_at,
    defined_transitions,
    drawn_transitions,
    transition_features,
    transitions_of,
    winding_at,
)
from identification.linear.native_normal import NativeUnavailable, local_gram_native
from identification.linear.solve import Solution, fit_linear_network, solve_constrained
from tensegrity_env.assemblies import cylinder_inertia
from tensegrity_env.engine import Engine, State
from tensegrity_env.engine.winch import winch_history
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import FIELDS, UNITS, Params

GROUP_UNITS = {**UNITS, "stiffness_rest": "N", "inertia": "kg*m^2",
               "stiffness_winch_speed": "N/s at command 1"}  # fmt: skip
FREEZABLE = (
    "stiffness", "damping", "rest_length", "mass", "inertia", "control_gain", "cable_gain"
)  # fmt: skip


@dataclass(frozen=True)
class ParameterRow:
    """One line of the identification table.

    ``status`` is ``identified``, ``anchored`` (given by the user to fix the scale),
    ``frozen`` (kept from a starting params file), ``ratio`` (identified relative to the
    scale reference), or ``not identifiable`` (then ``value`` is the assumed value used
    for simulation, or NaN, and ``note`` says why).
    """

    name: str
    group: str
    element: int
    value: float
    stderr: float
    unit: str
    status: str
    note: str = ""


class NotFittedError(RuntimeError):
    """The estimator was used before ``fit``."""


class SpringRodIdentifier:
    """Linear-regression identification of a spring-rod assembly.

    Args:
        solver: ``"lstsq"`` (exact least squares, default) or ``"network"`` (the paper's
            single linear layer trained on the MSE loss).
        shared: one K, c, l0 for all springs and one M, I for all rods.
        fit_rest_length: identify rest lengths; if False they come from ``init_params``.
        anchors: known values that fix the common scale, e.g. ``{"mass[rod0]": 1.95}``
            (a weighed rod). Without any anchor or frozen parameter the result is
            reported as ratios to ``mass`` of the first rod.
        init_params: a starting parameter set (for ``freeze``, known rest lengths and
            the values assumed for parameters the data cannot identify).
        freeze: Params fields kept at ``init_params`` values, e.g. everything but
            ``control_gain`` to fit h alone with the other modules frozen.
        gravity: known gravitational acceleration (3,) [m/s^2].
        chunk_size: transitions per chunk when building the design.
        max_transitions: fit on a random subset of this many training transitions.
        fraction: fit on this random fraction of the training transitions.
        seed: seed of the random subset and of the network solver.
        progress: show a progress bar while building the design.
        backend: how the normal matrix is built: ``"native"`` (one C pass over the
            states, :mod:`identification.linear.native_normal`), ``"torch"`` (design blocks in
            PyTorch, chunked) or ``"auto"`` (native where a C compiler works).
        winch_lag: the winch motors' lag [s], one value or one per winch, taken as known
            (:func:`~identification.linear.winch_lag.fit_winch_lag` searches it); None:
            ``init_params``' ``winch_lag``, else 0. With winches, each trajectory must
            start with them at rest at the declared rest lengths, and their rest lengths
            must stay within range in the data (the winding is linear in ``v_max`` there);
            ``v_max = (K·v)/K`` per winch. Their range is ``init_params``', else the span
            of rest lengths the fitted winding covers in the data.
    """

    #: every winch lag tried [s] -> its residual sum of squares, set by
    #: :func:`~identification.linear.winch_lag.fit_winch_lag` on the estimator it returns
    lag_search_: dict[float, float]

    def __init__(
        self,
        solver: str = "lstsq",
        shared: bool = False,
        fit_rest_length: bool = True,
        anchors: Mapping[str, float] | None = None,
        init_params: Params | None = None,
        freeze: Sequence[str] = (),
        gravity: Sequence[float] = (0.0, 0.0, -9.81),
        chunk_size: int = 2_000,
        max_transitions: int | None = None,
        fraction: float | None = None,
        seed: int = 0,
        progress: bool = False,
        backend: str = "auto",
        winch_lag: float | Sequence[float] | None = None,
    ) -> None:
        if backend not in ("auto", "native", "torch"):
            raise ValueError(f"backend must be 'auto', 'native' or 'torch', got {backend!r}")
        if solver not in ("lstsq", "network"):
            raise ValueError(f"solver must be 'lstsq' or 'network', got {solver!r}")
        bad = [f for f in freeze if f not in FREEZABLE]
        if bad:
            raise InputError(f"cannot freeze {bad}; choose from {list(FREEZABLE)}")
        if (freeze or not fit_rest_length) and init_params is None:
            raise InputError("freezing parameters or known rest lengths need init_params")
        self.solver = solver
        self.shared = shared
        self.fit_rest_length = fit_rest_length and "rest_length" not in freeze
        self.anchors = dict(anchors or {})
        self.init_params = init_params
        self.freeze = tuple(freeze)
        self.gravity = tuple(float(g) for g in gravity)
        self.chunk_size = chunk_size
        self.max_transitions = max_transitions
        self.fraction = fraction
        self.seed = seed
        self.progress = progress
        self.backend = backend
        self.winch_lag = winch_lag

    def _winch_lags(self, topology: Any) -> torch.Tensor:
        """The motors' lag (W,) [s] the fit takes as known (see ``winch_lag``)."""
        W = topology.n_winches
        if self.winch_lag is not None:
            lag = torch.as_tensor(np.broadcast_to(np.asarray(self.winch_lag, float), (W,)).copy())
        elif self.init_params is not None and self.init_params.winch_lag.numel() == W:
            lag = self.init_params.winch_lag.detach().double().clone()
        else:
            lag = torch.zeros(W, dtype=torch.float64)
        if not (torch.isfinite(lag).all() and (lag >= 0).all()):
            raise InputError(f"winch_lag must be finite and >= 0 s, got {lag.tolist()}")
        return lag

    # ------------------------------------------------------------------ fitting
    def fit(self, dataset: Dataset, split: str = "train") -> SpringRodIdentifier:
        """Identify the parameters from the transitions of ``split``."""
        data = dataset.split(split)
        if not data.has_states:
            raise InputError(
                f"{dataset.path or 'dataset'}: split '{split}' has end caps only; "
                "derive rod states first (identification.data.end_caps.rod_states_from_nodes)"
            )
        topology = dataset.topology
        layout = ParameterLayout.build(topology, self.shared, self.fit_rest_length)
        self.winch_lag_ = self._winch_lags(topology)
        self._winding = winding_at(data, self.winch_lag_, dataset.dt)  # (N*T, W) or None
        if self._winding is None and topology.n_winches:  # no command log: the motors at rest
            n = data.n_trajectories * data.n_transitions
            self._winding = torch.zeros(n, topology.n_winches, dtype=torch.float64)
        index = self._subset(data)
        normal, n_rows = self._normal_equations(dataset, data, layout, index)
        fixed, mode = self._constraints(layout)
        sol = solve_constrained(normal[:-1, :-1], fixed, n_rows)
        if self.solver == "network":
            theta = fit_linear_network(normal[:-1, :-1], fixed, n_rows, seed=self.seed)
            theta[~sol.identifiable] = np.nan
            sol = Solution(**{**sol.__dict__, "theta": theta})
        self.topology_ = topology
        self.dt_ = dataset.dt
        self.layout_ = layout
        self.solution_ = sol
        self.mode_ = mode
        self.n_transitions_ = len(index)
        self.condition_number_ = sol.condition_number
        self.params_, self.table_ = self._to_params(layout, sol, mode)
        return self

    def _subset(self, data: Split) -> np.ndarray:
        """Flat indices ``n T + t`` of the transitions to fit: those whose two states are
        defined (rod states derived from end caps are NaN in a gap too long to bridge),
        a random ``fraction`` of them, at most ``max_transitions``."""
        usable = defined_transitions(data)
        if len(usable) == 0:
            raise InputError("no transition with both rod states defined (gaps everywhere)")
        total = len(usable)
        n = total
        if self.fraction is not None:
            n = max(1, round(self.fraction * total))
        if self.max_transitions is not None:
            n = min(n, self.max_transitions)
        if n >= total:
            return usable
        return np.sort(np.random.default_rng(self.seed).choice(usable, size=n, replace=False))

    def _normal_equations(
        self, dataset: Dataset, data: Split, layout: ParameterLayout, index: np.ndarray
    ) -> tuple[torch.Tensor, int]:
        slots = rod_slots(layout)
        g = torch.tensor(self.gravity, dtype=torch.float64)
        rest = None
        if not layout.fit_rest_length:
            assert self.init_params is not None
            rest = self.init_params.rest_length.detach().double()
        P = layout.n_params
        normal = torch.zeros(P + 1, P + 1, dtype=torch.float64)
        n_rows = len(index) * dataset.topology.n_rods * 6
        actuated = dataset.topology.n_cables or dataset.topology.n_winches
        if self.backend == "native" and actuated:
            raise NativeUnavailable("the C normal equations have no cable actuator or winch columns")
        if self.backend != "torch" and not actuated:
            try:
                gram = local_gram_native(dataset.topology, data, index, slots, g, dataset.dt, rest)
            except NativeUnavailable as e:
                if self.backend == "native":
                    raise
                warnings.warn(f"C normal equations unavailable ({e}); using PyTorch", stacklevel=3)
            else:
                scatter_local_gram(gram, slots, normal)
                self.backend_ = "native"
                return normal, n_rows
        self.backend_ = "torch"
        chunks = range(0, len(index), self.chunk_size)
        for start in tqdm(chunks, desc="design", disable=not self.progress, unit="chunk"):
            chunk = index[start : start + self.chunk_size]
            s0, s1, u = transitions_of(data, chunk)
            cables = cable_commands_at(data, chunk)
            winding = None if self._winding is None else self._winding[chunk]
            feat = transition_features(dataset.topology, s0, s1, u, dataset.dt, cables, winding)
            accumulate_normal(rod_blocks(feat, slots, g, rest), slots, P, normal)
        return normal, n_rows

    def _constraints(self, layout: ParameterLayout) -> tuple[dict[int, float], str]:
        fixed: dict[int, float] = {}
        for name, value in self.anchors.items():
            check_anchor(name, float(value))
            try:
                fixed[layout.lookup(name)] = float(value)
            except KeyError:
                raise InputError(
                    f"unknown anchor '{name}'; parameters are named like "
                    f"{layout.names[0]}, {layout.names[-2]}, control_gain"
                ) from None
        if self.freeze:
            assert self.init_params is not None
            init = self.init_params.numpy()
            for i, (grp, el) in enumerate(zip(layout.groups, layout.elements, strict=True)):
                if grp in self.freeze:
                    fixed[i] = float(np.ravel(init[grp])[max(el, 0)])
                elif grp == "stiffness_rest" and {"stiffness", "rest_length"} <= set(self.freeze):
                    fixed[i] = float(
                        init["stiffness"][max(el, 0)] * init["rest_length"][max(el, 0)]
                    )
        if any(v != 0 for v in fixed.values()):
            return fixed, "frozen" if self.freeze and not self.anchors else "anchored"
        fixed[layout.index("mass", 0)] = 1.0
        return fixed, "ratios"

    def _to_params(
        self, layout: ParameterLayout, sol: Solution, mode: str
    ) -> tuple[Params, list[ParameterRow]]:
        topo = layout.topology
        S, R = topo.n_springs, topo.n_rods
        theta, stderr = sol.theta, sol.stderr
        values: dict[str, np.ndarray] = {
            "stiffness": np.full(S, np.nan),
            "stiffness_rest": np.full(S, np.nan),
            "damping": np.full(S, np.nan),
            "mass": np.full(R, np.nan),
            "inertia": np.full(3 * R, np.nan),
            "control_gain": np.full(1, np.nan),
            "cable_gain": np.full(topo.n_cables, np.nan),
            "stiffness_winch_speed": np.full(topo.n_winches, np.nan),
        }
        sizes = {k: len(v) for k, v in values.items()}
        for i, (grp, el) in enumerate(zip(layout.groups, layout.elements, strict=True)):
            if el == -1 or (grp == "inertia" and layout.shared):
                sl = slice(None) if grp != "inertia" else slice(el, None, 3)
                values[grp][sl] = theta[i]
            else:
                values[grp][el] = theta[i]
        assert all(len(v) == sizes[k] for k, v in values.items())
        if layout.fit_rest_length:
            rest = values["stiffness_rest"] / values["stiffness"]
        else:
            assert self.init_params is not None
            rest = self.init_params.numpy()["rest_length"]
        mass = values["mass"]
        inertia = values["inertia"].reshape(R, 3)
        assumed, notes = self._assumed_values(topo, mass)
        fill = {
            "stiffness": values["stiffness"],
            "damping": values["damping"],
            "rest_length": rest,
            "mass": mass,
            "inertia": inertia,
            "control_gain": values["control_gain"],
            "cable_gain": values["cable_gain"],
        }
        for f, arr in fill.items():
            nan = np.isnan(arr)
            if nan.any() and f in assumed:
                arr[nan] = np.broadcast_to(assumed[f], arr.shape)[nan]
        params = Params.create(
            stiffness=fill["stiffness"],
            damping=fill["damping"],
            rest_length=fill["rest_length"],
            mass=fill["mass"],
            inertia=fill["inertia"],
            control_gain=fill["control_gain"][0],
            gravity=self.gravity,
            cable_gain=fill["cable_gain"],
            **self._winch_values(topo, values, rest),
        )
        rows = []
        for i, (name, grp, el) in enumerate(
            zip(layout.names, layout.groups, layout.elements, strict=True)
        ):
            if sol.fixed[i]:
                status = "anchored" if name in self.anchors or mode == "ratios" else "frozen"
                if mode == "ratios":
                    status = "scale reference (=1)"
            elif not sol.identifiable[i]:
                status = "not identifiable"
            else:
                status = "ratio" if mode == "ratios" else "identified"
            note = ""
            value = float(theta[i])
            if status == "not identifiable":
                value = (
                    float(np.ravel(fill.get(grp, [np.nan]))[max(el, 0)]) if grp in fill else np.nan
                )
                note = notes.get(grp, "no value assumed")
            rows.append(
                ParameterRow(name, grp, el, value, float(stderr[i]), GROUP_UNITS[grp], status, note)
            )
        if layout.fit_rest_length:  # derived rest lengths get their own rows
            for s in range(S):
                k_i = layout.index("stiffness", s)
                kl_i = layout.index("stiffness_rest", s)
                ok = sol.identifiable[k_i] and sol.identifiable[kl_i]
                rel = (
                    np.hypot(stderr[k_i] / theta[k_i], stderr[kl_i] / theta[kl_i]) if ok else np.nan
                )
                rows.append(
                    ParameterRow(
                        f"rest_length[{topo.springs[s].name}]" if not layout.shared else "rest_length",
                        "rest_length", s, float(rest[s]), float(abs(rest[s]) * rel), "m",
                        "identified" if ok else "not identifiable",
                    )
                )  # fmt: skip
                if layout.shared:
                    break
        for w, spring in enumerate(topo.winches):  # derived winch speeds get their own rows
            k_i = layout.index("stiffness", spring)
            kv_i = layout.index("stiffness_winch_speed", w)
            ok = sol.identifiable[k_i] and sol.identifiable[kv_i]
            v = float(params.winch_speed[w]) if ok else np.nan
            rel = np.hypot(stderr[k_i] / theta[k_i], stderr[kv_i] / theta[kv_i]) if ok else np.nan
            rows.append(
                ParameterRow(
                    f"winch_speed[{topo.springs[spring].name}]", "winch_speed", w, v,
                    float(abs(v) * rel), UNITS["winch_speed"],
                    "identified" if ok else "not identifiable",
                    "" if ok else "the data does not wind this cable",
                )
            )  # fmt: skip
        rows += self._winch_rows(topo, params)
        return params, rows

    def _winch_rows(self, topo: Any, params: Params) -> list[ParameterRow]:
        """Table rows of the winches' lag (taken as known) and range (not seen unless
        reached)."""
        given = self.init_params is not None and self.init_params.winch_min.numel() == topo.n_winches
        note = ("kept from the starting params" if given else
                "the range is not reached in this data: the span the fitted winding covers")  # fmt: skip
        rows = []
        for w, spring in enumerate(topo.winches):
            name = topo.springs[spring].name
            rows.append(ParameterRow(f"winch_lag[{name}]", "winch_lag", w,
                                     float(params.winch_lag[w]), 0.0, UNITS["winch_lag"],
                                     "frozen", "taken as known"))  # fmt: skip
            for f in ("winch_min", "winch_max"):
                rows.append(ParameterRow(f"{f}[{name}]", f, w, float(getattr(params, f)[w]),
                                         float("nan"), UNITS[f], "not identifiable", note))  # fmt: skip
        return rows

    def _winch_values(
        self, topo: Any, values: dict[str, np.ndarray], rest: np.ndarray
    ) -> dict[str, Any]:
        """``winch_*`` keywords of :meth:`Params.create` ((W,) arrays; none without
        winches): ``v_max = (K·v)/K``, the lag taken as known, the range
        from ``init_params`` or the span the winding covers in the fit data (see the
        class doc)."""
        if not topo.n_winches:
            return {}
        springs = list(topo.winches)
        speed = values["stiffness_winch_speed"] / values["stiffness"][springs]
        init = self.init_params
        if init is not None and init.winch_speed.numel() == topo.n_winches:  # where not wound
            speed = np.where(np.isfinite(speed), speed, init.winch_speed.detach().double().numpy())
        assert self._winding is not None
        ends = rest[springs] + speed * np.stack(
            [self._winding.min(0).values.numpy(), self._winding.max(0).values.numpy()]
        )  # the rest lengths the fitted winding reaches in the data, (2, W) [m]
        if self.init_params is not None and self.init_params.winch_min.numel() == topo.n_winches:
            low = self.init_params.winch_min.detach().double().numpy()
            high = self.init_params.winch_max.detach().double().numpy()
            out = [topo.springs[s].name for s, a, b, lo, hi in
                   zip(springs, ends.min(0), ends.max(0), low, high, strict=True)
                   if a < lo or b > hi]  # fmt: skip
            if out:
                warnings.warn(f"winches on {out} reach the end of their range in this data: "
                              "the regression's winding (no range) is biased there", stacklevel=3)  # fmt: skip
        else:
            low, high = np.clip(ends.min(0), 0.0, None), ends.max(0)
        return {"winch_speed": speed, "winch_min": low, "winch_max": high,
                "winch_lag": self.winch_lag_.numpy()}  # fmt: skip

    def _assumed_values(
        self, topology: Any, mass: np.ndarray
    ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
        """Values used for simulation where the data cannot identify a parameter."""
        if self.init_params is not None:
            init = self.init_params.numpy()
            note = "not identifiable from this data; value kept from the starting params"
            return {f: init[f] for f in FIELDS}, {f: note for f in (*FIELDS, "stiffness_rest")}
        lengths = np.array([r.length for r in topology.rods])
        radii = np.array([r.radius for r in topology.rods])
        m = np.where(np.isnan(mass), np.nan, mass)
        inertia = np.stack(
            [cylinder_inertia(m[r : r + 1], lengths[r], radii[r])[0] for r in range(len(m))]
        )
        return (
            {
                "inertia": inertia,
                "damping": np.zeros(1),
                "control_gain": np.ones(1),
                "cable_gain": np.zeros(1),
            },
            {
                "inertia": "not excited in this data; assumed solid cylinder of the identified mass",
                "damping": "not excited in this data; assumed 0",
                "control_gain": "no control force in this data; assumed 1",
                "cable_gain": "no cable command in this data; assumed 0",
            },
        )

    # ------------------------------------------------------------------ using the fit
    def _check_fitted(self) -> None:
        if not hasattr(self, "params_"):
            raise NotFittedError("call fit(dataset) before using the estimator")

    def unidentifiable(self) -> list[str]:
        """Names of the parameters this data could not identify."""
        self._check_fitted()
        return [r.name for r in self.table_ if r.status == "not identifiable"]

    def engine(self) -> Engine:
        self._check_fitted()
        missing = [f for f, v in self.params_.numpy().items() if not np.all(np.isfinite(v))]
        if missing:
            raise InputError(
                f"cannot simulate: {missing} not identifiable from this data and no value assumed "
                f"({', '.join(self.unidentifiable())})"
            )
        return Engine(self.topology_, self.dt_)

    def predict(self, state: State, control: torch.Tensor | None = None) -> State:
        """One engine step from ``state`` (B, R, ·) with the identified parameters."""
        return self.engine().step(state, self.params_, control)

    def simulate(self, state: State, n_steps: int, control: torch.Tensor | None = None) -> State:
        """Roll the identified engine out: (B, n_steps + 1, R, ·)."""
        return self.engine().rollout(state, self.params_, n_steps, control)

    def score(
        self,
        dataset: Dataset,
        split: str = "test",
        max_one_step: int = 50_000,
        horizon: int | None = None,
    ) -> dict[str, Any]:
        """Errors of the identified engine on ``split``.

        Returns one-step mean position error [m], the rollout mean position error at the
        end of each trajectory [m], its mean over the horizon [m], and the per-step
        curve ``rollout_curve`` (T+1,) [m].
        """
        self._check_fitted()
        return evaluate_params(
            self.topology_, self.params_, dataset, split, max_one_step, horizon, self.seed
        )


def evaluate_params(
    topology: Any,
    params: Params,
    dataset: Dataset,
    split: str = "test",
    max_one_step: int = 50_000,
    horizon: int | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """One-step and rollout position errors of ``params`` on a split (see ``score``)."""
    data = dataset.split(split)
    engine = Engine(topology, dataset.dt, native=True)  # no gradient: the C kernel
    idx = drawn_transitions(data, max_one_step, seed)
    s0, s1, u = transitions_of(data, idx)
    cables = cable_commands_at(data, idx)
    winch_ctrl = None
    if topology.n_winches:  # each transition starts from the winch state the log gives
        winch_ctrl = torch.as_tensor(data.winch_control)
        history = winch_history(topology, params, winch_ctrl, dataset.dt)  # (N, T+1, W, 2)
        T_all = data.n_transitions
        s0 = s0.with_winch(history[idx // T_all, idx % T_all])
    with torch.no_grad():
        pred = engine.step(s0, params, u, cables, None if winch_ctrl is None else
                           winch_ctrl[idx // data.n_transitions, idx % data.n_transitions])
        one_step = float(torch.linalg.vector_norm(pred.p - s1.p, dim=-1).mean())
        T = data.n_transitions if horizon is None else min(horizon, data.n_transitions)
        init = State.from_numpy(*(getattr(data, k)[:, 0] for k in ("p", "v", "q", "omega")))
        ctrl = torch.as_tensor(data.control[:, :T])
        cable_ctrl = (
            None if data.cable_control is None else torch.as_tensor(data.cable_control[:, :T])
        )
        roll = engine.rollout(init, params, T, ctrl, cable_ctrl,
                              None if winch_ctrl is None else winch_ctrl[:, :T])  # fmt: skip
        assert data.p is not None  # the initial states above came from it
        err = torch.linalg.vector_norm(roll.p - torch.as_tensor(data.p[:, : T + 1]), dim=-1)
        curve = err.nanmean(dim=(0, 2)).numpy()  # (samples in a gap: left out)
    return {
        "one_step_position_error": one_step,
        "rollout_final_position_error": float(curve[-1]),
        "rollout_mean_position_error": float(curve.mean()),
        "rollout_curve": curve,
        "horizon_steps": T,
    }
