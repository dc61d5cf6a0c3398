"""Defaults and names the command line shows, importable without torch, MuJoCo or SciPy.

``--help`` reads them from here, so that it prints in a fraction of a second; the
modules that use them import them from here too. :data:`SCALE_NAMES` mirrors a
registry built from heavy classes; ``tests/unit/test_cli_help.py`` checks that the two
agree.
"""

from __future__ import annotations

from typing import Any

#: default windows of the floor fit of the declared model and contact: more pin it
#: better but let it take up an undeclared effect (measured in docs/decisions.md)
FLOOR_WINDOWS = 8
#: windows of the training split for the final refit of the selected model on the floor:
#: once selection is done, more windows only sharpen the parameters; 96 of 0.25 s are
#: every sample of the benchmark's 8 training trajectories of 3 s (measured in
#: docs/decisions.md). Above one group's worth they run in the ``--jobs`` workers
#: (:mod:`identification.trajectory.forked`)
FINAL_FLOOR_WINDOWS = 96
#: most Levenberg-Marquardt iterations of the final refit: enough for it to converge on
#: the benchmark's floor cells (docs/decisions.md)
FINAL_ITERATIONS = 60

#: longest window on the floor [s]: each one's initial state is fitted, and a window
#: spanning several impacts stalls that fit
FLOOR_WINDOW_S = 0.25

#: The paper's fractions of the training transitions.
DEFAULT_FRACTIONS: tuple[float, ...] = (1.0, 0.1, 0.01, 0.001, 0.0001)

#: Trajectory counts and length (transitions) of each preset.
PRESETS: dict[str, dict[str, Any]] = {
    "small": {"n_train": 16, "n_val": 4, "n_test": 4, "steps": 300},
    "paper": {"n_train": 1000, "n_val": 200, "n_test": 100, "steps": 736},
    # the paper's generalization data: 20,000-step trajectories under random directed
    # perturbation forces h * f_u at each rod's arm r_u
    "perturbed": {"n_train": 4, "n_val": 0, "n_test": 4, "steps": 20000, "control_std": 1.0},
}

#: plant -> strength name -> value (units in :data:`STRENGTH_UNITS`)
PLANTS: dict[str, dict[str, float]] = {
    "none": {"moderate": 0.0},
    "ground_contact": {"weak": 0.3, "moderate": 1.0, "strong": 2.0},
    "quadratic_drag": {"weak": 20.0, "moderate": 100.0, "strong": 500.0},
    "linear_drag": {"weak": 0.1, "moderate": 0.5, "strong": 2.0},
    "slack_springs": {"weak": 6, "moderate": 12, "strong": 24},
    "joint_damping": {"weak": 0.05, "moderate": 0.4, "strong": 1.0},
    "spring_friction": {"weak": 0.2, "moderate": 1.0, "strong": 3.0},
}
STRENGTH_UNITS = {
    "none": "",
    "ground_contact": "friction coefficient",
    "quadratic_drag": "fluid density [kg/m^3]",
    "linear_drag": "fluid viscosity [Pa*s]",
    "slack_springs": "cable springs",
    "joint_damping": "free-joint damping [N*s/m and N*m*s]",
    "spring_friction": "tendon friction loss [N]",
}

#: the sizes of the paper's experiments, the keys of
#: :data:`identification.experiments.paper.SCALES`
SCALE_NAMES: tuple[str, ...] = ("small", "full")
