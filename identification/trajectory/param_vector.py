"""The trajectory fit's parameter vector: log-parameters of the declared model per group,
anchors fixed, and (optionally) effect coordinates.

The method is described in :mod:`identification.trajectory.identifier`; the rod geometry
seen by end caps is :class:`identification.data.end_caps.RodAxes`, the anchors' names
:func:`identification.linear.smoothed.parse_anchors`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from identification.data.end_caps import RodAxes
from identification.trajectory.effect_coords import EffectCoords
from tensegrity_env.engine import Engine
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology

DTYPE = torch.float64
#: the groups of the trajectory fit's log-parameter vector, in order (``cable_gain``:
#: the log of each cable actuator's gain magnitude, its sign held; empty without them)
GROUPS = ("stiffness", "damping", "rest_length", "mass", "inertia_perp", "control_gain", "cable_gain")
#: the trajectory fit keeps every parameter within a factor e^LOG_BOX (1e4) of its
#: stage-1 start, so that one the data barely sees cannot run off towards 0, where
#: its effect (and so its Jacobian column) drops below round-off and it never returns
LOG_BOX = float(np.log(1e4))


# ---------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class ParamVector:
    """The trajectory fit's log-parameters: ``log [K, c, l0, M, I_perp, h]`` (n_full,).

    ``free`` marks the fitted entries; the others stay at ``start``. Inertia is
    ``I_perp`` on both perpendicular axes and ``M a`` on the axis, with ``axial`` the
    axial moment per unit mass ``a`` [m^2], (R,), held: the start model's where one is
    given (its axial spin, which friction drives on a floor, depends on it), else the
    robot file's (None: :attr:`~tensegrity_env.topology.Topology.axial_gyrations`).
    A cable actuator's gain is ``cable_sign * exp(log |h_c|)`` (a tendon actuator's gain
    may be negative: its sign comes from the start and is held).
    """

    topology: Topology
    rod_axes: RodAxes | None
    start: torch.Tensor
    free: torch.Tensor
    gravity: torch.Tensor
    coords: EffectCoords | None = None
    cable_sign: torch.Tensor | None = None
    axial: torch.Tensor | None = None

    @classmethod
    def at(cls, topology: Topology, params: Params) -> ParamVector:
        """``params`` with nothing free (rollouts and state-only fits at known values).

        Inertia follows the vector's convention: ``I_perp`` from a perpendicular axis,
        ``params``' axial moment per unit mass on the end-cap axis. Unusable values (a control gain of 0 on data
        without control) become 1.
        """
        axes = RodAxes.of(topology)
        values = params_values(params, axes)
        sign = gain_sign(values["cable_gain"])
        values["cable_gain"] = np.abs(values["cable_gain"])
        v = np.concatenate([values[g] for g in GROUPS])
        v[~(np.isfinite(v) & (v > 0))] = 1.0
        start = torch.as_tensor(np.log(v), dtype=DTYPE)
        free = torch.zeros(len(start), dtype=torch.bool)
        return cls(topology, axes, start, free, torch.as_tensor(params.gravity, dtype=DTYPE),
                   cable_sign=sign, axial=axial_per_mass(values, axes))  # fmt: skip

    @classmethod
    def coordinates_only(cls, topology: Topology, params: Params) -> ParamVector:
        """No log-parameters and no end-cap axes: a vector for fits of effect coordinates
        alone, the declared ``params`` held as given by the problem (rods whose end caps
        lie off their principal axes are fine here: nothing is read from end caps)."""
        return cls(topology, None, torch.zeros(0, dtype=DTYPE), torch.zeros(0, dtype=torch.bool),
                   torch.as_tensor(params.gravity, dtype=DTYPE))  # fmt: skip

    @property
    def axes(self) -> RodAxes:
        """Each rod's end-cap axis (:class:`~identification.data.end_caps.RodAxes`)."""
        if self.rod_axes is None:
            raise ValueError("a vector of effect coordinates alone has no end-cap axes")
        return self.rod_axes

    @property
    def n_effect(self) -> int:
        """Number of effect coordinates appended to the free log-parameters."""
        return 0 if self.coords is None else self.coords.n

    def theta0(self) -> torch.Tensor:
        """Start of the fitted vector: free log-parameters, then effect coordinates."""
        tail = [] if self.coords is None else [self.coords.start()]
        return torch.cat([self.start[self.free], *tail])

    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Box of the fitted vector (see :data:`LOG_BOX` and :class:`EffectCoords`)."""
        lo, hi = self.start[self.free] - LOG_BOX, self.start[self.free] + LOG_BOX
        if self.coords is None:
            return lo, hi
        elo, ehi = self.coords.bounds()
        return torch.cat([lo, elo]), torch.cat([hi, ehi])

    def hard_bounds(self) -> torch.Tensor:
        """Which entries of the fitted vector (n_free + n_effect,) bool have a physical
        bound (:meth:`EffectCoords.hard_bounds`); the log-parameters' :data:`LOG_BOX` is a
        search range."""
        tail = torch.zeros(0, dtype=torch.bool) if self.coords is None else self.coords.hard_bounds()
        return torch.cat([torch.zeros(self.n_free, dtype=torch.bool), tail])

    def mass_scaled(self) -> torch.Tensor:
        """Which entries of the fitted vector (n_free + n_effect,) are effect force
        coefficients that scale with a common scale of the masses
        (:meth:`~identification.trajectory.effect_coords.EffectCoords.mass_scaled`)."""
        tail = torch.zeros(0, dtype=torch.bool) if self.coords is None else self.coords.mass_scaled()
        return torch.cat([torch.zeros(self.n_free, dtype=torch.bool), tail])

    def held_at(self, theta: torch.Tensor) -> ParamVector:
        """This vector at ``theta`` (n_free + n_effect,) with nothing free and no effect
        coordinates: the model held there (a fit of the windows' states alone, with the
        effects at ``theta`` in the engine: :meth:`engine`)."""
        return replace(self, start=self.full(theta.detach()), free=torch.zeros_like(self.free),
                       coords=None)  # fmt: skip

    def split(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``theta`` (..., n_free + n_effect) -> log-parameters and effect coordinates."""
        n = self.n_free
        return theta[..., :n], theta[..., n:]

    def engine(self, engine: Engine, theta: torch.Tensor) -> Engine:
        """``engine`` with the effects at the coordinates in ``theta`` (unbatched)."""
        if self.coords is None:
            return engine
        return engine.with_effects(self.coords.effects_at(self.split(theta)[1]))

    def effects(self, theta: torch.Tensor) -> list[Any]:
        """The fitted effects at ``theta`` (empty without effect coordinates)."""
        return [] if self.coords is None else self.coords.effects_at(self.split(theta)[1])

    @property
    def sizes(self) -> dict[str, int]:
        S, R, C = self.topology.n_springs, self.topology.n_rods, self.topology.n_cables
        return dict(zip(GROUPS, (S, S, S, R, R, 1, C), strict=True))

    def offset(self, group: str) -> int:
        return sum(list(self.sizes.values())[: GROUPS.index(group)])

    @property
    def n_free(self) -> int:
        return int(self.free.sum())

    def selector(self) -> torch.Tensor:
        """(n_full, n_free) 0/1 matrix placing free values into the full vector."""
        idx = torch.nonzero(self.free)[:, 0]
        sel = torch.zeros(len(self.free), len(idx), dtype=DTYPE)
        sel[idx, torch.arange(len(idx))] = 1.0
        return sel

    def full(self, theta: torch.Tensor) -> torch.Tensor:
        """Full log vector (..., n_full) from the free values ``theta`` (..., n_free)."""
        theta = theta[..., : self.n_free]
        return torch.where(self.free, 0.0, self.start) + theta @ self.selector().T

    def params(self, log_full: torch.Tensor) -> Params:
        """Engine parameters from a full log vector (n_full,) (differentiable).

        A batch of vectors (B, n_full) gives per-batch parameters, (B, ·), which the
        engine broadcasts against states of batch B (used to fold tangents).
        """
        val = torch.exp(log_full)
        g = {k: val[..., self.offset(k) : self.offset(k) + n] for k, n in self.sizes.items()}
        axial = torch.as_tensor(np.eye(3)[self.axes.axis], dtype=DTYPE)  # (R, 3)
        a = self.axial if self.axial is not None else torch.as_tensor(self.topology.axial_gyrations, dtype=DTYPE)
        inertia = (
            g["inertia_perp"].unsqueeze(-1) * (1 - axial) + (g["mass"] * a).unsqueeze(-1) * axial
        )
        gain = g["control_gain"][..., 0]
        sign = self.cable_sign if self.cable_sign is not None else torch.ones(self.sizes["cable_gain"], dtype=DTYPE)
        return Params(
            stiffness=g["stiffness"], damping=g["damping"], rest_length=g["rest_length"],
            mass=g["mass"], inertia=inertia, gravity=self.gravity,
            control_gain=gain if log_full.dim() == 1 else gain[:, None, None],
            cable_gain=sign * g["cable_gain"],
        )  # fmt: skip

    def names(self) -> list[str]:
        """Name of every entry of the full vector, e.g. ``stiffness[spring3]``."""
        rods = [r.name for r in self.topology.rods]
        springs = [s.name for s in self.topology.springs]
        driven = [self.topology.springs[c].name for c in self.topology.cable_actuators]
        labels = {"mass": rods, "inertia_perp": rods, "control_gain": None, "cable_gain": driven}
        out = []
        for group in GROUPS:
            els = labels.get(group, springs)
            out += [group] if els is None else [f"{group}[{e}]" for e in els]
        return out


def params_values(params: Params, axes: RodAxes) -> dict[str, np.ndarray]:
    """``params`` as the trajectory fit's groups (``inertia_perp``: a perpendicular axis)
    and ``axial``: each rod's axial moment per unit mass (R,) [m^2], held by the fit."""
    p = params.numpy()
    inertia = np.asarray(p["inertia"])
    R = inertia.shape[0]
    return {
        "axial": inertia[np.arange(R), axes.axis] / np.asarray(p["mass"], float),
        "stiffness": np.asarray(p["stiffness"], float),
        "damping": np.asarray(p["damping"], float),
        "rest_length": np.asarray(p["rest_length"], float),
        "mass": np.asarray(p["mass"], float),
        "inertia_perp": inertia[np.arange(R), (axes.axis + 1) % 3],
        "control_gain": np.atleast_1d(np.asarray(p["control_gain"], float)),
        "cable_gain": np.atleast_1d(np.asarray(p.get("cable_gain", ()), float)),
    }


def axial_per_mass(values: dict[str, np.ndarray], axes: RodAxes) -> torch.Tensor | None:
    """``values``' axial moment per unit mass (R,) [m^2] where given and usable (finite,
    > 0, every rod), else None (the vector takes the robot file's)."""
    a = values.get("axial")
    if a is None or len(a) != len(axes.axis) or not bool(np.all(np.isfinite(a) & (a > 0))):
        return None
    return torch.as_tensor(np.asarray(a, float), dtype=DTYPE)


def gain_sign(gain: np.ndarray) -> torch.Tensor:
    """(C,) the sign of each cable gain in ``gain`` (+1 where 0 or not finite)."""
    g = np.nan_to_num(np.asarray(gain, dtype=float))
    return torch.as_tensor(np.where(g < 0, -1.0, 1.0), dtype=DTYPE)
