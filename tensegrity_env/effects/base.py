"""The common base of every candidate effect: named physical parameters with units.

Each effect of :mod:`tensegrity_env.effects` subclasses :class:`PhysicalEffect`,
declares its parameters once in :attr:`PhysicalEffect.PARAMS` (name -> unit and
default) and overrides the engine hook(s) where it acts (see
:mod:`tensegrity_env.engine.effects`). Parameter values are torch tensors, so an
effect can be fitted through the differentiable engine: build it with tensors that
``requires_grad`` (:meth:`PhysicalEffect.with_values`).

An effect serialises to the params file's ``effects`` list as::

    {"name": "ground_contact",
     "params": {"stiffness": 3.1e4, ...},
     "units": {"stiffness": "N/m", ...},
     "uncertainty": {"stiffness": 120.0, ...}}

Beside its force, a class declares, as data the rest of the project reads without
knowing the class: its :attr:`~PhysicalEffect.gate` (where in the data it can act),
its :attr:`~PhysicalEffect.fit_form` (fit coordinates, bounds and start), its
:attr:`~PhysicalEffect.native` form in the C kernel's effects block (or
:attr:`~PhysicalEffect.no_native`, the reason it has none) and its
:attr:`~PhysicalEffect.plant` (how a MuJoCo model carries it). The residual loop's
library, the trajectory fit's coordinates, the kernel packing and the planted
benchmarks are generated from :data:`tensegrity_env.effects.EFFECTS`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Self

import numpy as np
import torch

from tensegrity_env.engine.effects import EffectBase
from tensegrity_env.engine.forces import kinematics_wrench
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params, check_numbers
from tensegrity_env.topology import Topology


@dataclass(frozen=True)
class ParamSpec:
    """One physical parameter of an effect.

    Attributes:
        unit: its unit, as written into the params file.
        default: value used when a document omits it (scalar or per-element list).
        per: ``""`` for a scalar or fixed-size vector, ``"spring"`` / ``"rod"`` for one
            value per spring / rod (a scalar default is broadcast).
        shape: trailing shape of each value, e.g. ``(3,)`` for a vector.
        integer: an index list (not fitted; e.g. which springs are cables).
        positive: physically >= 0 (fitted in log space); False for signed values.
        unit_interval: physically in (0, 1) (fitted in logit space).
    """

    unit: str
    default: Any = 0.0
    per: str = ""
    shape: tuple[int, ...] = ()
    integer: bool = False
    positive: bool = True
    unit_interval: bool = False


@dataclass(frozen=True)
class Gate:
    """Where in the data an effect can act (read by the residual loop's library).

    Attributes:
        text: why it may act, one line (shown when ``needs`` is ``""``).
        needs: what the data must show: ``""`` nothing (it may act everywhere),
            ``"commands"`` control commands, ``"floor"`` end caps on a floor that stops
            them, ``"scorer"`` a test each scorer makes its own way.
    """

    text: str
    needs: str = ""


@dataclass(frozen=True)
class FitForm:
    """How fits see an effect's parameters.

    Attributes:
        route: ``"regression"`` (linear in its parameters, or index-only: inside the
            one-step regression), ``"engine"`` (fitted through the engine on trajectory
            windows after the regression, coordinates ``free``) or ``"search"`` (a
            one-dimensional search over its single parameter around the regression).
        free: the parameters an engine fit moves, in their unconstrained coordinates
            (log, logit); the last stage frees them all.
        stages: the parameters freed in each stage of an engine fit (empty: ``free`` at once).
        start: parameter values an engine fit starts from (natural units).
        roll_entry: the index in ``theta()`` of the first of three per-rod-axis rotational
            entries; in end-cap fits the one about the end-cap axis is held (the spin about
            it is invisible). None: no such entries.
    """

    route: str = "regression"
    free: tuple[str, ...] = ()
    stages: tuple[tuple[str, ...], ...] = ()
    start: Mapping[str, float] | None = None
    roll_entry: int | None = None

    @property
    def n_extra(self) -> int:
        """Parameters fitted outside the regression (for an information criterion)."""
        return {"engine": len(self.free), "search": 1}.get(self.route, 0)


@dataclass(frozen=True)
class NativeForm:
    """How the C kernel holds an effect (read by :mod:`tensegrity_env.native.pack`).

    Attributes:
        kind: ``"block"`` (the values of ``keys``, flattened one after the other, added
            into each slot of ``slots``), ``"mask"`` (1 at the indices in ``keys[0]`` of
            each slot) or ``"contact"`` (the kernel's contact law and end-cap radii).
        slots: names of slots of the kernel's effects block
            (:data:`tensegrity_env.native.pack.EFFECT_SLOTS`).
        keys: the parameters packed.
        constants: ``(slot, value)`` pairs of fixed numbers of the law (not parameters)
            written into one-entry slots, e.g. a regularisation velocity [m/s].
    """

    kind: str
    slots: tuple[str, ...] = ()
    keys: tuple[str, ...] = ()
    constants: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True)
class MujocoPlant:
    """How a MuJoCo model carries an effect (read by
    :mod:`identification.simulation.planted`).

    Attributes:
        element: ``"option"`` (an attribute of ``<option>``) or ``"tendon"`` (an attribute
            of every spatial tendon).
        attribute: the MJCF attribute the strength is written to.
        ignore: the model check's feature names that the plant deliberately uses
            (:data:`tensegrity_env.defaults.FEATURES`).
        params: the effect's parameters in the ground-truth record, each equal to the
            strength (empty: the record names MuJoCo's attribute instead).
        note: the MuJoCo model it stands for, for the ground-truth record.
    """

    element: str
    attribute: str
    ignore: tuple[str, ...] = ()
    params: tuple[str, ...] = ()
    note: str = ""


class PhysicalEffect(EffectBase):
    """An effect with named physical parameters (see the module docstring).

    Args:
        topology: the assembly the effect acts on (radii, springs, rods).
        uncertainty: one standard error per parameter, same shapes (optional).
        validate: run the physical checks (:meth:`check`); fits pass False and ask
            :meth:`physical` afterwards.
        **values: parameter values (array-likes or tensors); omitted ones take
            their :attr:`PARAMS` default.
    """

    name: ClassVar[str] = "effect"
    #: what the effect is, in one line (printed in reports)
    summary: ClassVar[str] = ""
    #: parameter name -> :class:`ParamSpec`
    PARAMS: ClassVar[dict[str, ParamSpec]] = {}
    #: whether the effect depends on each rod's roll about its own axis (which end caps
    #: cannot see); fits through end caps then fit each window's roll too
    sees_roll: ClassVar[bool] = False
    #: whether the effect can only remove energy from the rods (drag): a fit in which it
    #: adds energy over the data is unphysical, whatever its standard errors
    dissipative: ClassVar[bool] = False
    #: where in the data it can act (see :class:`Gate`)
    gate: ClassVar[Gate] = Gate("acts everywhere")
    #: how fits see its parameters (see :class:`FitForm`)
    fit_form: ClassVar[FitForm] = FitForm()
    #: its form in the C kernel, read from the class itself (a subclass that changes the
    #: force declares its own); None: it has none, for the reason :attr:`no_native`
    native: ClassVar[NativeForm | None] = None
    #: why the kernel does not compute it (logged once when a step falls back to PyTorch)
    no_native: ClassVar[str] = "its class declares none"
    #: whether it acts on the command sequence before a rollout (``filter_commands``,
    #: control lag) rather than through a wrench in each step
    filters_commands: ClassVar[bool] = False
    #: how a MuJoCo model carries it; None: not by one attribute (see the planted data)
    plant: ClassVar[MujocoPlant | None] = None

    def __init__(
        self,
        topology: Topology,
        uncertainty: Mapping[str, Any] | None = None,
        *,
        validate: bool = True,
        **values: Any,
    ) -> None:
        unknown = sorted(set(values) - set(self.PARAMS))
        if unknown:
            raise InputError(
                f"effect '{self.name}': unknown parameter(s) {unknown} (has {sorted(self.PARAMS)})"
            )
        self.topology = topology
        self.values: dict[str, torch.Tensor] = {}
        for key, spec in self.PARAMS.items():
            self.values[key] = self._tensor(key, spec, values.get(key, spec.default))
        self.uncertainty: dict[str, Any] = dict(uncertainty or {})
        if validate:
            self.check()

    # ------------------------------------------------------------------ values
    def _count(self, spec: ParamSpec) -> int | None:
        return {"spring": self.topology.n_springs, "rod": self.topology.n_rods}.get(spec.per)

    def _tensor(self, key: str, spec: ParamSpec, value: Any) -> torch.Tensor:
        if not isinstance(value, torch.Tensor):
            check_numbers(value, f"'{key}'", f"effect '{self.name}'")
        if spec.integer:
            try:
                idx = np.asarray(value, dtype=float).reshape(-1)
            except (TypeError, ValueError) as e:
                raise InputError(f"effect '{self.name}': '{key}' is not numeric ({e})") from None
            if not (np.isfinite(idx).all() and (idx == np.round(idx)).all()):
                raise InputError(f"effect '{self.name}': '{key}' must be whole numbers")
            return torch.as_tensor(idx.astype(np.int64))
        if isinstance(value, torch.Tensor):
            t = value if value.is_floating_point() else value.double()
        else:
            try:
                t = torch.as_tensor(np.asarray(value, dtype=float), dtype=torch.float64)
            except (TypeError, ValueError) as e:
                raise InputError(f"effect '{self.name}': '{key}' is not numeric ({e})") from None
        n = self._count(spec)
        shape = ((n,) if n is not None else ()) + spec.shape
        if tuple(t.shape) != shape:
            if t.numel() == 1 or (n is not None and tuple(t.shape) == spec.shape):
                t = t.reshape(()) if t.numel() == 1 else t
                t = t.expand(shape) if t.requires_grad else t.expand(shape).clone()
            else:
                raise InputError(
                    f"effect '{self.name}': '{key}' has shape {tuple(t.shape)}, expected {shape}"
                )
        if not torch.isfinite(t.detach()).all() and key not in self.allow_infinite:
            raise InputError(f"effect '{self.name}': '{key}' contains NaN or inf")
        return t

    #: parameters that may be +inf (e.g. an unlimited slack width)
    allow_infinite: ClassVar[frozenset[str]] = frozenset()

    def check(self) -> None:
        """Physical sign checks of the values; raise :class:`InputError`. Override."""

    def check_nonnegative(self, why: str) -> None:
        """Raise :class:`InputError` where a value is below 0 by more than 3 of its standard
        errors (none given: any negative value; an infinite one, the data cannot see it:
        none). ``why``: the physical reason, for the message."""
        for k, v in self.values.items():
            se = np.nan_to_num(np.asarray(self.uncertainty.get(k, 0.0), float), nan=0.0,
                               posinf=np.inf, neginf=np.inf)  # fmt: skip
            x = v.detach().cpu().numpy()
            se = np.broadcast_to(se, x.shape)
            bad = np.flatnonzero(x < -3 * se)
            if bad.size:
                i = int(bad[0])
                raise InputError(
                    f"effect '{self.name}': '{k}' must be >= 0 ({why}), got "
                    f"[{i}] = {x.reshape(-1)[i]:.4g} ± {se.reshape(-1)[i]:.2g} {self.PARAMS[k].unit}"
                )

    def violation(self) -> str:
        """Why the values fail :meth:`check` (its message), or ``""`` when they pass."""
        try:
            self.check()
        except InputError as e:
            return str(e)
        return ""

    def physical(self) -> bool:
        """Whether the values pass :meth:`check` (a fit may give unphysical ones)."""
        return not self.violation()

    def clearance(self, state: State, kin: Kinematics) -> torch.Tensor | None:
        """How far each rod's end caps are from where the gate lets the effect act,
        (B, R, 2) [m], below 0 where it acts; None (the default): the gate does not
        depend on where the end caps are. ``state``, ``kin``: the rods (B rows)."""
        return None

    def elastic(self, length: torch.Tensor, rest: torch.Tensor) -> torch.Tensor | None:
        """Where each spring still carries its elastic tension ``K (l - l0)``: a bool
        (B, S) from spring lengths ``length`` (B, S) [m] and rest lengths ``rest`` (S,)
        [m]; None (the default): the effect switches no spring's elasticity off."""
        return None

    def filter_commands(
        self, control: torch.Tensor, dt: float, explicit: bool = False
    ) -> torch.Tensor:
        """The commands that act, from those given ``control`` (B, T, ...) (time on dim 1)
        at step ``dt`` [s]; ``explicit``: MuJoCo's explicit filter form, for cable commands.
        The default: unchanged (an effect with :attr:`filters_commands` overrides it)."""
        return control

    def floor_height(self) -> float | None:
        """The height [m] of the floor at which the effect stops end caps; None (the
        default): the effect is no floor."""
        return None

    def value(self, key: str, like: torch.Tensor) -> torch.Tensor:
        """Parameter ``key`` on the dtype and device of ``like``."""
        v = self.values[key]
        if v.dtype != like.dtype or v.device != like.device:
            v = v.to(dtype=like.dtype, device=like.device)
        return v

    def with_values(self, validate: bool = True, **values: Any) -> Self:
        """A copy with some parameters replaced (tensors kept as given: differentiable).

        ``validate=False`` skips the physical checks (see :meth:`physical`).
        """
        merged = {**self.values, **values}
        return type(self)(self.topology, uncertainty=self.uncertainty, validate=validate, **merged)

    def fitted_params(self) -> list[str]:
        """Names of the parameters a fit may change (non-index ones)."""
        return [k for k, s in self.PARAMS.items() if not s.integer]

    # ------------------------------------------------------------------ (de)serialise
    def to_dict(self) -> dict[str, Any]:
        """``{"name", "params", "units", "uncertainty"}`` (JSON-able)."""

        def plain(x: Any) -> Any:
            if isinstance(x, torch.Tensor):
                x = x.detach().cpu().numpy()
            if isinstance(x, np.ndarray):
                return x.tolist()
            return x

        return {
            "name": self.name,
            "params": {k: plain(v) for k, v in self.values.items()},
            "units": {k: s.unit for k, s in self.PARAMS.items()},
            "uncertainty": {k: plain(v) for k, v in self.uncertainty.items()},
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any], topology: Topology) -> PhysicalEffect:
        """Rebuild from :meth:`to_dict` output (params missing from ``doc`` take defaults)."""
        params = doc.get("params", {})
        if not isinstance(params, Mapping):
            raise InputError(f"effect '{cls.name}': 'params' must be a mapping")
        uncertainty = doc.get("uncertainty") or {}
        if not isinstance(uncertainty, Mapping):
            raise InputError(f"effect '{cls.name}': 'uncertainty' must be a mapping")
        # an infinite standard error (the data does not see the parameter) is stored as null
        unseen = {k: inf_for_null(v) for k, v in uncertainty.items()}
        return cls(topology, uncertainty=unseen, **dict(params))

    def describe(self) -> str:
        """One line: name and parameter values with units."""
        parts = []
        for k, spec in self.PARAMS.items():
            v = self.values[k].detach().cpu().numpy()
            text = f"{float(v):.4g}" if v.ndim == 0 else np.array2string(v, precision=3)
            parts.append(f"{k}={text} {spec.unit}".rstrip())
        return f"{self.name}: " + ", ".join(parts)

    def __repr__(self) -> str:
        return f"<{self.describe()}>"


class LinearEffect(PhysicalEffect):
    """An effect whose wrench is linear in its (non-index) parameters θ.

    ``wrench = Σ_j θ_j basis_j``: subclasses give :meth:`basis`, the force and torque
    on every rod per unit of each parameter entry. Such an effect can join the linear
    regression's design matrix (``identification.linear.extended``).
    """

    #: its parameters are forces (per velocity, per length cubed, ...): scaling every
    #: mass, inertia, stiffness and damping by a common factor leaves the motion the same
    #: only if they scale with it (False where a parameter is a length or a ratio)
    mass_scaled: ClassVar[bool] = True

    def basis(
        self, state: State, kin: Kinematics, params: Params
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Force (B, R, 3, P) [N/unit] and torque (B, R, 3, P) [N*m/unit], world frame."""
        raise NotImplementedError

    def transition_basis(
        self, s0: State, s1: State, kin: Kinematics, params: Params
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The basis in a one-step regression from ``s0`` to ``s1`` (``kin`` of ``s0``).

        :meth:`basis` at ``s0``, unless the effect is integrated implicitly (its wrench
        then acts at ``s1``'s velocities).
        """
        return self.basis(s0, kin, params)

    def theta(self) -> torch.Tensor:
        """All fitted parameter entries, flattened in :attr:`PARAMS` order, (P,)."""
        return torch.cat([self.values[k].reshape(-1) for k in self.fitted_params()])

    def theta_lower(self) -> torch.Tensor:
        """The physical lower bound of each entry of :meth:`theta`, (P,): 0 where its
        parameter is ``positive`` (a drag coefficient), ``-inf`` where it is signed."""
        return torch.cat([
            torch.full((self.values[k].numel(),), 0.0 if self.PARAMS[k].positive else -np.inf,
                       dtype=torch.float64)
            for k in self.fitted_params()
        ] or [torch.zeros(0, dtype=torch.float64)])  # fmt: skip

    def theta_names(self) -> list[str]:
        """A name per entry of :meth:`theta`, e.g. ``translational[x]``."""
        names = []
        for k in self.fitted_params():
            n = self.values[k].numel()
            spec = self.PARAMS[k]
            if n == 1:
                names.append(k)
            elif spec.per == "spring":
                names += [f"{k}[{s.name}]" for s in self.topology.springs]
            elif spec.per == "rod":
                names += [f"{k}[{r.name}]" for r in self.topology.rods]
            else:
                names += [f"{k}[{'xyz'[i] if n == 3 else i}]" for i in range(n)]
        return names

    def with_theta(self, theta: Any, stderr: Any = None) -> Self:
        """A copy with :meth:`theta` replaced (and its standard errors, same layout)."""
        theta = torch.as_tensor(theta, dtype=torch.float64).reshape(-1)
        values, unc, i = {}, {}, 0
        for k in self.fitted_params():
            shape = self.values[k].shape
            n = self.values[k].numel()
            values[k] = theta[i : i + n].reshape(shape)
            if stderr is not None:
                unc[k] = np.asarray(stderr, dtype=float).reshape(-1)[i : i + n].reshape(shape)
            i += n
        new = self.with_values(validate=False, **values)
        if stderr is not None:
            new.uncertainty = unc
        return new

    def wrench(
        self,
        state: State,
        kin: Kinematics,
        params: Params,
        applied: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        force, torque = self.basis(state, kin, params)
        th = self.theta().to(force)
        return force @ th, torque @ th


class SpringLawEffect(LinearEffect):
    """A linear effect that adds a tension ``ΔT_s = θ_s φ_s`` [N] to every spring.

    Subclasses define the per-spring factor ``φ`` (:meth:`factor`, (B, S)) of their
    one per-spring parameter ``θ`` (S,). :meth:`basis` is the dense regression design
    (a wrench column per spring); :meth:`wrench`, which the engine calls every step,
    sums the tensions through the springs' nodes instead (:func:`spring_tension_wrench`):
    the same wrench at the cost of one spring force, not of S.
    """

    def factor(self, state: State, kin: Kinematics, params: Params) -> torch.Tensor:
        """The tension per unit parameter of each spring, (B, S)."""
        raise NotImplementedError

    def basis(
        self, state: State, kin: Kinematics, params: Params
    ) -> tuple[torch.Tensor, torch.Tensor]:
        force, torque, _ = spring_unit_wrench(kin, self.topology)
        phi = self.factor(state, kin, params)[:, None, None]
        return force * phi, torque * phi

    def wrench(
        self,
        state: State,
        kin: Kinematics,
        params: Params,
        applied: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        phi = self.factor(state, kin, params)
        return spring_tension_wrench(kin, self.topology, phi * self.theta().to(phi))


def spring_lengths(kin: Kinematics, topology: Topology) -> tuple[torch.Tensor, torch.Tensor]:
    """Each spring's length (B, S) [m] and unit axis from node a to node b (B, S, 3)."""
    nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long, device=kin.x.device)
    d = kin.x[:, nodes[:, 1]] - kin.x[:, nodes[:, 0]]
    length = torch.linalg.vector_norm(d, dim=-1)
    return length, d / length.unsqueeze(-1)


def spring_tension_wrench(
    kin: Kinematics, topology: Topology, tension: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Force and torque (B, R, 3) on every rod, world frame, of spring tensions (B, S) [N].

    A positive tension pulls the spring's two nodes towards each other (as the
    engine's springs); equal to ``spring_unit_wrench`` contracted with ``tension``.
    """
    nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long, device=kin.x.device)
    _, axis = spring_lengths(kin, topology)
    pull = tension.unsqueeze(-1) * axis  # on node a, (B, S, 3)
    node_f = (
        torch.zeros_like(kin.x).index_add(1, nodes[:, 0], pull).index_add(1, nodes[:, 1], -pull)
    )
    return kinematics_wrench(node_f, kin)


def spring_unit_wrench(
    kin: Kinematics, topology: Topology
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Wrench on every rod from a unit tension (1 N) in each spring, and the lengths.

    Returns force (B, R, 3, S) [N/N], torque (B, R, 3, S) [N*m/N], world frame, and the
    spring lengths (B, S) [m]. A spring pulls its two nodes towards each other.
    """
    nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long, device=kin.x.device)
    a, b = nodes[:, 0], nodes[:, 1]
    length, axis = spring_lengths(kin, topology)  # (B, S), (B, S, 3)
    S, R = topology.n_springs, topology.n_rods
    # node_rod one-hot (N, R) and each node's lever (B, N, 3): end caps, anchors, points
    member = torch.zeros(kin.x.shape[1], R, dtype=kin.x.dtype, device=kin.x.device)
    node_rod = torch.as_tensor(topology.node_rod, device=kin.x.device)
    on_rod = torch.nonzero(node_rod >= 0)[:, 0]
    member[on_rod, node_rod[on_rod]] = 1.0
    inc = torch.zeros(kin.x.shape[1], S, dtype=kin.x.dtype, device=kin.x.device)
    idx = torch.arange(S, device=kin.x.device)
    inc[a, idx] = 1.0
    inc[b, idx] = -1.0
    node_f = inc[None, :, None, :] * axis.transpose(1, 2)[:, None]  # (B, N, 3, S)
    force = torch.einsum("nr,bnks->brks", member, node_f)
    lever = kin.node_arms.unsqueeze(-1).expand_as(node_f)
    torque = torch.einsum("nr,bnks->brks", member, torch.cross(lever, node_f, dim=-2))
    return force, torque, length


def inf_for_null(value: Any) -> Any:
    """A standard error read from JSON: ``null`` (an infinite one, as
    :func:`~tensegrity_env.io_utils.strict_json` writes it) back to ``inf``, in lists too."""
    if value is None:
        return float("inf")
    if isinstance(value, list):
        return [inf_for_null(v) for v in value]
    return value
