"""Defaults and names the command line shows, importable without torch or MuJoCo.

``--help`` reads them from here, so that it prints in a fraction of a second; the
modules that use them import them from here too. Where a name list mirrors a registry
built from heavy classes (:data:`ASSEMBLY_NAMES`, :data:`EFFECT_NAMES`),
``tests/unit/test_cli_help.py`` checks that the two agree.
"""

from __future__ import annotations

#: default physics step [s]: MuJoCo's usual timestep; the longest step the engine takes
PHYSICS_DT = 1e-3

#: the built-in assemblies, the keys of :data:`tensegrity_env.assemblies.ASSEMBLIES`
ASSEMBLY_NAMES: tuple[str, ...] = ("icosahedron", "element")

#: the candidate effects, the keys of :data:`tensegrity_env.effects.EFFECTS` in its order
EFFECT_NAMES: tuple[str, ...] = (
    "ground_contact",
    "slack_springs",
    "linear_drag",
    "quadratic_drag",
    "force_field",
    "cubic_stiffness",
    "rest_length_offset",
    "control_lag",
    "spring_friction",
)

#: every refusable feature and why the model cannot honour it (the ``--ignore`` names)
FEATURES: dict[str, str] = {
    "integrator": "the engine integrates with MuJoCo's semi-implicit Euler only",
    "rod-collisions": "rod-rod contact is not part of the spring-rod model",
    "end-cap-shape": "a cylinder end meets a floor along its rim; contact is modelled for"
    " spherical ends (spheres, capsules)",
    "contact-pairs": "explicit <contact><pair> contacts are not modelled",
    "condim": "floor contact is modelled with sliding friction only (condim 3)",
    "cone": "floor friction is modelled as MuJoCo's pyramidal cone",
    "contact-solver": "the contact model assumes MuJoCo's default impratio, margin, gap and "
    "solimp midpoint/power, and no noslip or global contact override",
    "equality": "equality constraints are not modelled",
    "tendon-limits": "tendon length limits are not modelled",
    "tendon-friction": "tendon friction loss and armature are not modelled",
    "nonlinear-springs": "springs are linear (stiffness/damping polynomials, yield or dead "
    "bands other than tension-only are not modelled)",
    "joint-dynamics": "free-joint armature, friction loss and springs are not modelled, nor "
    "damping other than one value on every rod whose body frame is at its centre of mass",
    "actuators": "control inputs are world-frame site forces and cable (tendon) actuators"
    " with a fixed gain, no bias, no force or activation limits and at most a first-order"
    " filter (dyntype none or filter, actearly false)",
    "fluid": "fluid drag (density, viscosity, wind, fluid shapes) is not modelled",
    "gravcomp": "gravity compensation is not modelled",
    "disabled-physics": "disabling springs, dampers, actuation or constraints is not modelled",
}
