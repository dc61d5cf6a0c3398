"""MuJoCo ground truth: write an assembly as MJCF (:mod:`.writer`), and read any MJCF of the
same form back (:mod:`.reader`, rods' end caps: :mod:`.end_caps`).

The convention (DESIGN.md) that any MJCF must follow to be read:

* a **rod** is a body with one free joint and (at least) two sites, its end caps:
  the points motion capture tracks and the floor touches. With more sites, the end
  caps are the two at the rod's ends along its long axis (the principal axis of least
  inertia; of sites equally far out, the one nearest the axis), or the sites named
  in ``end_caps``;
* a **spring** is a spatial tendon through exactly two sites, each a site on a rod (an
  end cap, or any other site: an attachment point) or a site on the world body (a
  fixed anchor), with ``stiffness``, ``damping`` and ``springlength``;
* optional **control**: ``general`` actuators with a site transmission on a rod site
  (the arm ``r_u``) and a ``refsite`` on the world body (so the force direction is fixed
  in the world); the actuator gain is the control gain ``h`` and belongs to the ground
  truth only;
* optional **winches**: a custom numeric ``winch:<tendon>`` with ``v_max l_min l_max
  [tau]`` makes that spring a winch cable whose rest length its motor winds
  (:mod:`.winches`).

Rods are written with an explicit ``<inertial>`` (principal axes = body axes), so
``M`` and ``I`` are exactly the parameters. Reading takes each rod's mass, centre of
mass, principal frame and inertia from the compiled model (``body_mass``,
``body_ipos``, ``body_iquat``, ``body_inertia``: an ``<inertial>`` element or the
union of the body's geoms), whatever the body frame; the body frame's origin is kept
(``Rod.frame_origin``) because MuJoCo's free joint integrates that point. Rod-rod collisions are off by default
(``contype``/``conaffinity`` bits); with a ground plane, end caps collide with it.
"""

from tensegrity_env.mjcf.reader import MjcfAssembly, from_mjcf, inertial_quat
from tensegrity_env.mjcf.writer import AXES, SimOptions, build_model, to_mjcf

__all__ = [
    "AXES",
    "MjcfAssembly",
    "SimOptions",
    "build_model",
    "from_mjcf",
    "inertial_quat",
    "to_mjcf",
]
