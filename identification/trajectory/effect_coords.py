"""Effect parameters as free coordinates of the trajectory fit (:mod:`identification.trajectory.identifier`).

The windowed trajectory fit minimises end-cap errors over a vector ``theta`` of free
coordinates. :class:`EffectCoords` appends the parameters of a list of effects to it,
as each effect's class declares (its ``fit_form``,
:class:`~tensegrity_env.effects.base.FitForm`):

* a :class:`~tensegrity_env.effects.base.LinearEffect` (drag, force field, cubic or
  compression stiffness, spring friction) contributes every entry of its ``theta()``
  as is (linear: its wrench is linear in them), bounded below by its physical domain
  (drag coefficients >= 0: the fit's steps are projected onto the bound, see
  :meth:`EffectCoords.bounds`), less the entry its ``roll_entry`` declares unseen;
* an effect fitted through the engine (ground contact) contributes its declared
  ``free`` parameters in the unconstrained coordinates of
  :func:`to_free` (log, logit);
* index-only effects (slack cables) contribute nothing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from tensegrity_env.effects import GroundContact
from tensegrity_env.effects.base import LinearEffect, ParamSpec, PhysicalEffect

DTYPE = torch.float64
#: where a contact fit starts (the contact's declared start)
CONTACT_START: dict[str, float] = dict(GroundContact.fit_form.start or {})
#: contact parameters fitted through the engine (the contact's declared coordinates)
CONTACT_FREE: tuple[str, ...] = GroundContact.fit_form.free
#: unconstrained contact coordinates stay within this of their start (log/logit units)
CONTACT_BOX = 5.0


def to_free(spec: ParamSpec, value: float) -> float:
    """A parameter value in the unconstrained coordinates of the fit (log, logit or as is)."""
    if spec.unit_interval:
        return float(np.log(value / (1.0 - value)))
    if spec.positive:
        return float(np.log(max(value, 1e-12)))
    return float(value)


def from_free(spec: ParamSpec, x: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`to_free`."""
    if spec.unit_interval:
        return torch.sigmoid(x)
    if spec.positive:
        return torch.exp(x)
    return x


@dataclass(frozen=True)
class EffectCoords:
    """The free coordinates of ``effects`` (see the module docstring).

    Attributes:
        effects: the effects at the coordinates' start, in engine order.
        slots: per effect, ``None`` (linear: ``theta()`` entries), a tuple of contact
            parameter names, or ``()`` (nothing free).
    """

    effects: tuple[PhysicalEffect, ...]
    slots: tuple[tuple[str, ...] | None, ...]
    held: tuple[tuple[int, ...], ...] = ()
    #: absolute limits of contact coordinates by parameter name (fit coordinates), in
    #: place of ±:data:`CONTACT_BOX` around the start
    box: tuple[tuple[str, float, float], ...] = ()

    @classmethod
    def of(
        cls,
        effects: Sequence[PhysicalEffect],
        axial: int | None = None,
        contact_free: tuple[str, ...] | None = None,
        box: Mapping[str, tuple[float, float]] | None = None,
    ) -> EffectCoords:
        """Coordinates of ``effects``; ``axial``: the rods' common end-cap axis (rod frame).

        ``contact_free``: the parameters of effects fitted through the engine that are
        coordinates (None: those each declares; ``()``: held at their values, e.g. a
        contact found by :mod:`identification.trajectory.touchdown`).
        ``box``: absolute limits (lo, hi) of contact coordinates in the fit's coordinates
        (log, logit or as is; see
        :func:`~identification.trajectory.floor_fit.contact_box`), for the parameters named.

        A per-axis rotational entry about that axis (an effect's declared ``roll_entry``:
        rotational drag) is held (at its value, 0 to start): the spin about it is
        invisible in end-cap data, so the data cannot see it.
        """
        slots: list[tuple[str, ...] | None] = []
        held: list[tuple[int, ...]] = []
        for e in effects:
            hold: tuple[int, ...] = ()
            form = e.fit_form
            if isinstance(e, LinearEffect):  # the abstract base: theta() is its coordinates
                slots.append(None)
                if form.roll_entry is not None and axial is not None:
                    hold = (form.roll_entry + axial,)
            elif form.route == "engine":
                slots.append(form.free if contact_free is None else contact_free)
            else:
                slots.append(())
            held.append(hold)
        return cls(tuple(effects), tuple(slots), tuple(held)).with_box(box or {})

    def with_box(self, box: Mapping[str, tuple[float, float]]) -> EffectCoords:
        """The same coordinates with the contact's limits ``box`` (see :meth:`of`)."""
        limits = tuple((k, float(lo), float(hi)) for k, (lo, hi) in box.items())
        return EffectCoords(self.effects, self.slots, self.held, limits)

    def _held(self, i: int) -> tuple[int, ...]:
        return self.held[i] if self.held else ()

    def _linear(self, i: int) -> LinearEffect:
        """Effect ``i``, whose coordinates are its ``theta()`` (its slot is None)."""
        e = self.effects[i]
        assert isinstance(e, LinearEffect)  # narrowing: a None slot marks the abstract base
        return e

    def _free_idx(self, i: int) -> np.ndarray:
        """Free entries of linear effect ``i``'s ``theta()``."""
        n = int(self._linear(i).theta().numel())
        return np.setdiff1d(np.arange(n), self._held(i))

    def sizes(self) -> list[int]:
        """Number of coordinates of each effect."""
        return [len(self._free_idx(i)) if s is None else len(s) for i, s in enumerate(self.slots)]

    @property
    def n(self) -> int:
        return sum(self.sizes())

    def start(self) -> torch.Tensor:
        """The coordinates of :attr:`effects`, (n,)."""
        out: list[float] = []
        for i, (e, s) in enumerate(zip(self.effects, self.slots, strict=True)):
            if s is None:
                th = self._linear(i).theta().detach().double()
                out += th[self._free_idx(i)].tolist()
            else:
                out += [to_free(e.PARAMS[k], float(e.values[k].reshape(-1)[0])) for k in s]
        return torch.tensor(out, dtype=DTYPE)

    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Box on the coordinates: for linear ones their physical lower bound
        (:meth:`~tensegrity_env.effects.base.LinearEffect.theta_lower`: drag coefficients
        stay >= 0, signed ones are free), for contact :attr:`box` where it names the
        parameter, else ±:data:`CONTACT_BOX` around the start."""
        lo, hi = [], []
        x0 = self.start()
        limits = {k: (a, b) for k, a, b in self.box}
        i = 0
        for j, (s, n) in enumerate(zip(self.slots, self.sizes(), strict=True)):
            if s is None:
                floor = self._linear(j).theta_lower()[self._free_idx(j)]
            for k in range(n):
                if s is None:
                    lo.append(float(floor[k]))
                    hi.append(np.inf)
                elif s[k] in limits:
                    lo.append(limits[s[k]][0])
                    hi.append(limits[s[k]][1])
                else:
                    lo.append(float(x0[i + k]) - CONTACT_BOX)
                    hi.append(float(x0[i + k]) + CONTACT_BOX)
            i += n
        return torch.tensor(lo, dtype=DTYPE), torch.tensor(hi, dtype=DTYPE)

    def hard_bounds(self) -> torch.Tensor:
        """Which coordinates (n,) bool have a physical bound in :meth:`bounds` (a drag
        coefficient's 0) rather than a search box (contact): the fit holds those on
        their bound (:func:`~identification.trajectory.windowed_fit.bounded_step`)."""
        out: list[bool] = []
        for j, (s, n) in enumerate(zip(self.slots, self.sizes(), strict=True)):
            if s is None:
                floor = self._linear(j).theta_lower()[self._free_idx(j)]
                out += [bool(np.isfinite(float(f))) for f in floor]
            else:
                out += [False] * n
        return torch.tensor(out, dtype=torch.bool)

    def effects_at(self, x: torch.Tensor, stderr: np.ndarray | None = None) -> list[PhysicalEffect]:
        """The effects with coordinates ``x`` (n,) (unvalidated: check ``physical()``).

        ``stderr`` (n,): standard errors of the coordinates, stored as each effect's
        ``uncertainty`` (delta method for log/logit coordinates).
        """
        out: list[PhysicalEffect] = []
        i = 0
        for j_e, (e, s, n) in enumerate(zip(self.effects, self.slots, self.sizes(), strict=True)):
            part = x[i : i + n]
            se = None if stderr is None else np.asarray(stderr[i : i + n], dtype=float)
            if s is None:
                idx = torch.as_tensor(self._free_idx(j_e))
                full = self._linear(j_e).theta().detach().to(part).index_put((idx,), part)
                se_full = None
                if se is not None:
                    se_full = np.zeros(full.numel())
                    se_full[idx.numpy()] = se
                out.append(self._linear(j_e).with_theta(full, se_full))
            elif s:
                vals = {k: from_free(e.PARAMS[k], part[j]) for j, k in enumerate(s)}
                new = e.with_values(validate=False, **vals)
                if se is not None:
                    for j, k in enumerate(s):
                        v = float(new.values[k].detach().reshape(-1)[0])
                        spec = e.PARAMS[k]
                        slope = (
                            v * (1 - v)
                            if spec.unit_interval
                            else (abs(v) if spec.positive else 1.0)
                        )
                        new.uncertainty[k] = slope * float(se[j])
                out.append(new)
            else:
                out.append(e)
            i += n
        return out

    def mass_scaled(self) -> torch.Tensor:
        """Which coordinates (n,) scale with a common scale of every mass (linear effects'
        force coefficients, see :attr:`~tensegrity_env.effects.base.LinearEffect.mass_scaled`;
        contact parameters are per unit of effective mass, and do not)."""
        out: list[bool] = []
        for e, s, n in zip(self.effects, self.slots, self.sizes(), strict=True):
            out += [s is None and bool(getattr(e, "mass_scaled", False))] * n
        return torch.tensor(out, dtype=torch.bool)

    def names(self) -> list[str]:
        """``effect.param`` of every coordinate."""
        out = []
        for i, (e, s) in enumerate(zip(self.effects, self.slots, strict=True)):
            if s is None:
                keys = [self._linear(i).theta_names()[k] for k in self._free_idx(i)]
            else:
                keys = list(s)
            out += [f"{e.name}.{k}" for k in keys]
        return out
