"""The scale anchors a user gives (``--anchor mass[rod0]=1.95``): their form and domain.

A linear regression of spring-rod dynamics identifies its parameters up to one common
scale; an anchor is one known value (a weighed rod's mass) that fixes it. This module
reads and checks the user's anchors; the estimators
(:class:`~identification.linear.regression.SpringRodIdentifier`) hold them.
"""

from __future__ import annotations

import math
import re

from tensegrity_env.io_utils import InputError

_NAME = re.compile(r"^([a-z_]+)(\[[^\]]+\])?$")


#: the physical domain of an anchored value, per parameter group: (strictly positive, unit)
ANCHOR_DOMAIN: dict[str, tuple[bool, str]] = {
    "mass": (True, "kg"),
    "inertia": (True, "kg*m^2"),
    "stiffness": (True, "N/m"),
    "stiffness_rest": (True, "N"),
    "damping": (False, "N*s/m"),
    "rest_length": (False, "m"),
    "control_gain": (True, "N per command unit"),
    "cable_gain": (False, "N per command unit"),
}
#: groups whose values may take either sign (a cable actuator's gain: pull or push)
SIGNED_GROUPS = frozenset({"cable_gain"})


def check_anchor(name: str, value: float) -> None:
    """Raise :class:`InputError` unless ``value`` is finite and in the physical domain of
    ``name``'s group (mass, inertia, stiffness, K·l0, h > 0; damping, rest length >= 0)."""
    m = _NAME.match(name.strip())
    group = m.group(1) if m else name
    positive, unit = ANCHOR_DOMAIN.get(group, (False, ""))
    if not math.isfinite(value):
        raise InputError(f"--anchor {name}={value!r}: the value must be a finite number")
    if group not in SIGNED_GROUPS and (value < 0 or (positive and value == 0)):
        sign = "> 0" if positive else ">= 0"
        raise InputError(f"--anchor {name}={value!r}: a {group} must be {sign} [{unit}]")


def parse_anchor(text: str) -> tuple[str, float]:
    """Parse ``NAME=VALUE`` (e.g. ``mass[rod0]=1.95``): a finite value in the physical
    domain of the parameter (:func:`check_anchor`)."""
    name, sep, value = text.partition("=")
    if not sep or not _NAME.match(name.strip()):
        raise InputError(f"--anchor '{text}' must look like mass[rod0]=1.95")
    try:
        number = float(value)
    except ValueError:
        raise InputError(f"--anchor '{text}': '{value}' is not a number") from None
    check_anchor(name.strip(), number)
    return name.strip(), number
