"""What an MJCF file says beyond rods and springs: read what is modelled, refuse the rest.

:func:`contact_of` reads the floor contact an end cap feels (friction, ``solref``,
``solimp``, mixed between the two geoms as MuJoCo mixes them) into the parameters of
:class:`~tensegrity_env.effects.ground_contact.GroundContact`.
:func:`unsupported_features` lists every feature of a compiled model that changes
the dynamics and that the spring-rod model does not have, each under the name the
user passes to ``--ignore`` to simulate it anyway (:data:`tensegrity_env.defaults.FEATURES`). docs/mjcf.md
is the user-facing list.
"""

from __future__ import annotations

import warnings
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from tensegrity_env.defaults import FEATURES
from tensegrity_env.io_utils import InputError


class IgnoredFeatureWarning(UserWarning):
    """An MJCF feature the model leaves out, accepted because the user said ``--ignore``."""


@dataclass(frozen=True)
class Unsupported:
    """One unmodelled feature found in a model.

    Attributes:
        feature: its name in :data:`FEATURES` (what ``--ignore`` takes).
        what: what the file has, e.g. ``tendon 'c3' has length limits``.
    """

    feature: str
    what: str

    @property
    def why(self) -> str:
        return FEATURES[self.feature]


def check_ignore_names(names: Collection[str], where: str = "--ignore") -> None:
    """Raise :class:`InputError` for a name that is not in :data:`FEATURES`."""
    bad = sorted(set(names) - set(FEATURES))
    if bad:
        raise InputError(f"{where}: unknown feature(s) {bad} (choose from {sorted(FEATURES)})")


def refuse_or_warn(found: Sequence[Unsupported], ignore: Collection[str], src: str) -> None:
    """Refuse the first feature not in ``ignore``; warn once for each one that is."""
    check_ignore_names(ignore)
    for f in found:
        if f.feature not in ignore:
            raise InputError(
                f"{src}: {f.what}: {f.why} (pass --ignore {f.feature} to simulate it in MuJoCo"
                " anyway, left out of the identified model)"
            )
    for f in found:
        warnings.warn(
            f"{src}: ignoring {f.what} ({f.why}): the model leaves it out",
            IgnoredFeatureWarning,
            stacklevel=3,
        )


def _name(m: mujoco.MjModel, obj: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(m, obj, i) or f"#{i}"


def _collide(m: mujoco.MjModel, g1: int, g2: int) -> bool:
    return bool(
        (m.geom_contype[g1] & m.geom_conaffinity[g2])
        or (m.geom_contype[g2] & m.geom_conaffinity[g1])
    )


def joint_damping_of(m: mujoco.MjModel, rod_bodies: Sequence[int]) -> float | None:
    """The rods' free-joint damping [N*s/m and N*m*s] when the model has it as implicit
    linear drag, or None when it cannot.

    MuJoCo damps each of a free joint's six velocities (the body origin's, the angular
    one) by ``damping``, implicitly under its Euler integrator: the model's
    ``linear_drag`` in its implicit form, isotropic with ``b = β = damping``, when every
    rod has the same value and its body frame at its centre of mass (else the damping
    force acts off the centre of mass). 0 without damping.
    """
    values = {float(m.dof_damping[d]) for b in rod_bodies
              for d in range(m.body_dofadr[b], m.body_dofadr[b] + m.body_dofnum[b])}  # fmt: skip
    if values <= {0.0}:
        return 0.0
    centred = all(np.allclose(m.body_ipos[b], 0.0, atol=1e-9) for b in rod_bodies)
    return values.pop() if len(values) == 1 and centred else None


def unsupported_features(
    m: mujoco.MjModel, rod_bodies: Sequence[int], floor: Sequence[int], actuators: Sequence[int]
) -> list[Unsupported]:
    """Every dynamics-changing feature of ``m`` that the spring-rod model does not have.

    ``actuators``: the actuator ids the reader already maps to control inputs.
    """
    found: list[Unsupported] = []
    GEOM, TEN, ACT = (
        mujoco.mjtObj.mjOBJ_GEOM,
        mujoco.mjtObj.mjOBJ_TENDON,
        mujoco.mjtObj.mjOBJ_ACTUATOR,
    )

    def add(feature: str, what: str) -> None:
        found.append(Unsupported(feature, what))

    if int(m.opt.integrator) != int(mujoco.mjtIntegrator.mjINT_EULER):
        add("integrator", f"integrator {mujoco.mjtIntegrator(m.opt.integrator).name[6:]}")
    rods = set(int(b) for b in rod_bodies)
    rod_geoms = [g for g in range(m.ngeom) if int(m.geom_bodyid[g]) in rods]
    for i, g1 in enumerate(rod_geoms):
        hit = next(
            (
                g2
                for g2 in rod_geoms[i + 1 :]
                if m.geom_bodyid[g2] != m.geom_bodyid[g1] and _collide(m, g1, g2)
            ),
            None,
        )
        if hit is not None:
            add(
                "rod-collisions",
                f"geoms '{_name(m, GEOM, g1)}' and '{_name(m, GEOM, hit)}' of different rods"
                " can collide (contype/conaffinity)",
            )
            break
    if m.npair:
        add("contact-pairs", f"{m.npair} explicit contact pair(s)")
    if m.neq:
        add("equality", f"{m.neq} equality constraint(s)")
    for t in range(m.ntendon):
        name = _name(m, TEN, t)
        if m.tendon_limited[t]:
            add("tendon-limits", f"tendon '{name}' has length limits")
        if m.tendon_frictionloss[t] > 0 or m.tendon_armature[t] > 0:
            add("tendon-friction", f"tendon '{name}' has friction loss or armature")
        if np.any(m.tendon_stiffnesspoly[t] != 0) or np.any(m.tendon_dampingpoly[t] != 0):
            add("nonlinear-springs", f"tendon '{name}' has a stiffness or damping polynomial")
        lo, hi = m.tendon_lengthspring[t]
        if lo != hi and lo != 0:
            add("nonlinear-springs", f"tendon '{name}' has a spring dead band [{lo:g}, {hi:g}]")
    damping = joint_damping_of(m, rod_bodies)
    for b in rod_bodies:
        dofs = range(m.body_dofadr[b], m.body_dofadr[b] + m.body_dofnum[b])
        if any(m.dof_armature[d] or m.dof_frictionloss[d] for d in dofs):
            add(
                "joint-dynamics",
                f"rod '{_name(m, mujoco.mjtObj.mjOBJ_BODY, b)}' has free-joint armature or"
                " friction loss",
            )
        elif damping is None and any(m.dof_damping[d] for d in dofs):
            add(
                "joint-dynamics",
                f"rod '{_name(m, mujoco.mjtObj.mjOBJ_BODY, b)}' has free-joint damping that"
                " is not one value on every rod and axis, or a body frame off its centre of"
                " mass",
            )
        if m.jnt_stiffness[m.body_jntadr[b]]:
            add(
                "joint-dynamics",
                f"rod '{_name(m, mujoco.mjtObj.mjOBJ_BODY, b)}' has a joint spring",
            )
        if m.body_gravcomp[b]:
            add("gravcomp", f"rod '{_name(m, mujoco.mjtObj.mjOBJ_BODY, b)}' has gravcomp")
    for a in range(m.nu):
        if a not in actuators:
            add("actuators", f"actuator '{_name(m, ACT, a)}' (not a supported control input)")
    if m.opt.density > 0 or m.opt.viscosity > 0 or np.any(m.geom_fluid[:, 0] > 0):
        add("fluid", "fluid forces (density, viscosity or geom fluidshape)")
    D = mujoco.mjtDisableBit
    off = [
        b.name[6:].lower()
        for b in (D.mjDSBL_SPRING, D.mjDSBL_DAMPER, D.mjDSBL_ACTUATION, D.mjDSBL_CONSTRAINT)
        if m.opt.disableflags & int(b)
    ]
    if off:
        add("disabled-physics", f"disabled {', '.join(off)}")
    if floor:
        if int(m.opt.cone) != int(mujoco.mjtCone.mjCONE_PYRAMIDAL):
            add("cone", "an elliptic friction cone")
        if m.opt.impratio != 1 or m.opt.noslip_iterations > 0:
            add("contact-solver", "impratio != 1 or noslip iterations")
        if m.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_OVERRIDE):
            add("contact-solver", "the global contact override")
    return found


def cable_actuator_problem(m: mujoco.MjModel, a: int) -> str | None:
    """Why tendon actuator ``a`` is not a supported cable actuator, or None if it is.

    Supported: force ``gain * gear * u`` along the tendon with a fixed gain, no bias, no
    force or activation limits, and ``u`` the control or its first-order filter
    (``dyntype="filter"``, ``actearly="false"``).
    """
    B, G, D = mujoco.mjtBias, mujoco.mjtGain, mujoco.mjtDyn
    if int(m.actuator_gaintype[a]) != int(G.mjGAIN_FIXED):
        return "a gain that is not fixed"
    if int(m.actuator_biastype[a]) != int(B.mjBIAS_NONE) and np.any(m.actuator_biasprm[a] != 0):
        return "a bias (a position or velocity servo)"
    dyn = int(m.actuator_dyntype[a])
    if dyn not in (int(D.mjDYN_NONE), int(D.mjDYN_FILTER)):
        return f"activation dynamics {D(dyn).name[6:].lower()}"
    if dyn == int(D.mjDYN_FILTER) and (m.actuator_actearly[a] or m.actuator_dynprm[a, 0] <= 0):
        return "a filter with actearly or a non-positive time constant"
    if m.actuator_forcelimited[a] or m.actuator_actlimited[a]:
        return "a force or activation limit"
    if np.any(m.actuator_gear[a, 1:] != 0):
        return "a gear with more than one entry"
    for extra in ("damping", "armature", "dampingpoly", "delay"):  # newer MuJoCo versions
        values = getattr(m, f"actuator_{extra}", None)
        if values is not None and np.any(np.asarray(values)[a] != 0):
            return f"actuator {extra}"
    return None


def contact_of(
    m: mujoco.MjModel, cap_geoms: Sequence[int], floor: Sequence[int], src: str
) -> tuple[dict[str, float], list[Unsupported]]:
    """Floor contact parameters of :class:`GroundContact` and the unmodelled parts.

    Each end-cap geom meets each floor plane it can collide with; the pair's
    friction, ``condim``, ``solref`` and ``solimp`` are mixed as MuJoCo mixes them
    (priority, else ``solmix``-weighted ``solref``/``solimp``, element-wise maximum
    friction and condim). Every pair must give the same parameters (one contact law).

    Returns:
        ``{stiffness, damping, impedance, impedance_min, width, friction}`` and the
        unsupported contact features found (condim, solimp shape, margin).
    """
    found: list[Unsupported] = []
    laws = set()
    for g in cap_geoms:
        for f in floor:
            if not _collide(m, g, f):
                continue
            laws.add(_pair_law(m, g, f))
    if not laws:
        return {}, found
    if len(laws) > 1:
        raise InputError(
            f"{src}: end caps meet the floor with different contact parameters"
            " (the contact model has one friction, solref and solimp)"
        )
    friction, condim, solref, solimp, margin = laws.pop()
    if condim != 3:
        found.append(Unsupported("condim", f"floor contact with condim {condim}"))
    if solimp[3] != 0.5 or solimp[4] != 2 or margin != 0:
        found.append(
            Unsupported("contact-solver", "a solimp midpoint/power other than 0.5/2 or a margin")
        )
    dmax = min(max(solimp[1], 1e-4), 0.9999)
    if solref[0] > 0:
        tc, zeta = solref
        if not m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_REFSAFE):
            tc = max(tc, 2 * float(m.opt.timestep))
        stiffness, damping = 1.0 / (dmax**2 * tc**2 * zeta**2), 2.0 / (dmax * tc)
    else:
        stiffness, damping = -solref[0] / dmax**2, -solref[1] / dmax
    return {
        "stiffness": stiffness,
        "damping": damping,
        "impedance": dmax,
        "impedance_min": min(max(solimp[0], 1e-4), 0.9999),
        "width": solimp[2],
        "friction": friction,
    }, found


def _pair_law(m: mujoco.MjModel, g1: int, g2: int) -> tuple[Any, ...]:
    """(friction, condim, solref, solimp, margin) of the contact of geoms g1, g2."""
    p1, p2 = int(m.geom_priority[g1]), int(m.geom_priority[g2])
    if p1 != p2:
        g = g1 if p1 > p2 else g2
        return (
            float(m.geom_friction[g, 0]),
            int(m.geom_condim[g]),
            tuple(map(float, m.geom_solref[g])),
            tuple(map(float, m.geom_solimp[g])),
            float(max(m.geom_margin[g1], m.geom_margin[g2])),
        )
    s1, s2 = float(m.geom_solmix[g1]), float(m.geom_solmix[g2])
    mix = (
        0.5
        if s1 < 1e-15 and s2 < 1e-15
        else (1.0 if s2 < 1e-15 else (0.0 if s1 < 1e-15 else s1 / (s1 + s2)))
    )
    r1, r2 = m.geom_solref[g1], m.geom_solref[g2]
    if r1[0] > 0 and r2[0] > 0:
        solref = tuple(float(mix * a + (1 - mix) * b) for a, b in zip(r1, r2, strict=True))
    else:
        solref = tuple(float(min(a, b)) for a, b in zip(r1, r2, strict=True))
    solimp = tuple(
        float(mix * a + (1 - mix) * b)
        for a, b in zip(m.geom_solimp[g1], m.geom_solimp[g2], strict=True)
    )
    return (
        float(max(m.geom_friction[g1, 0], m.geom_friction[g2, 0])),
        int(max(m.geom_condim[g1], m.geom_condim[g2])),
        solref,
        solimp,
        float(max(m.geom_margin[g1], m.geom_margin[g2])),
    )
