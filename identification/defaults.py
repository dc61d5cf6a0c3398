"""Defaults and names the command line shows, importable without torch, MuJoCo or SciPy.

``--help`` reads them from here, so that it prints in a fraction of a second; the
modules that use them import them from here too. :data:`SCALE_NAMES` mirrors a
registry built from heavy classes; ``tests/unit/test_cli_help.py`` checks that the two
agree.
"""

from __future__ import annotations

from typing import Any

#: default windows of the floor fit of the declared model and contact (each window's
#: initial state is fitted through every contact, which costs in proportion). More pin
#: the declared model better, and also let it take up an undeclared effect: on the
#: measured benchmark's floor cells (seed 0) 24 windows put the control's spring damping
#: within 7.6 % (max) where 8 left 14 %, but the declared fit on 24 windows absorbed the
#: force-field cell's field, which was then missed (named with 8)
FLOOR_WINDOWS = 8
#: windows of the training split for the final refit of the selected model on the floor:
#: once selection is done, more windows only sharpen the parameters (spring damping
#: above all), with nothing left for the declared fit to absorb. The spread of the
#: fitted damping shrinks as the inverse square root of the windows kept. 96 windows of
#: 0.25 s are every sample of the benchmark's 8 training trajectories of 3 s: on its
#: floor cells with seed 1 (the seed the defaults were set on; ``python
#: benchmarks/bench_measured.py --settings floor --seed0 1``) they put the spring damping
#: within 8.7 % (max over 24 springs; control), 7.3 % (linear drag) and 11.2 %
#: (quadratic drag) where 48 windows and 20 iterations gave 11.7, 11.4 and 14.8 %.
#: Above one group's worth the windows run in the ``--jobs`` workers
#: (:mod:`identification.trajectory.forked`)
FINAL_FLOOR_WINDOWS = 96
#: most Levenberg-Marquardt iterations of the final refit: on those cells the refit on
#: 74-96 windows converged in 30-49 iterations, where 20 ran out on every cell
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
