"""Motor position targets: an action as each winch's target rest length.

The generic robot environments take motor speed commands by default: action ``u`` in
[-1, 1] winds a cable's rest length ``l0`` at ``u * v_max``. With ``motor_targets=True``
an action component ``a`` in [-1, 1] is instead a target rest length within that
winch's range,

    target = l_min + (a + 1) / 2 * (l_max - l_min)        (a = -1: shortest, +1: longest)

and the env's own motor controller turns it into the speed command the motors take for
the coming control step (``dt`` = ``frame_skip`` physics steps), from the rest length
the motor's encoder reads now:

    u = clip((target - l0) / (v_max * dt), -1, 1)

the command that would reach the target within one control step at full speed where the
motor allows, and winds at full speed toward it where it is farther. A held target is
approached and then held (``u`` falls with the distance left; the first-order motor lag
may carry the rest length up to a few millimetres past it, corrected the next steps).
The motors (engine, C kernel, MuJoCo twin) still take speed commands, so an identified
env and its twin run the same motors, and the rewards' control cost is that of ``u``.

The controller's constants are the robot file's declared winch values (``v_max``,
``l_min``, ``l_max``: ``winch:<tendon>`` numerics), as the robot's own firmware knows
them, the same numbers in an identified env and in its twin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from tensegrity_env.params import Params


def check_flag(value: object, name: str = "motor_targets") -> bool:
    """``value`` as a bool; ValueError unless it is one (True/False, 0/1)."""
    if isinstance(value, bool | np.bool_) or value in (0, 1):
        return bool(value)
    raise ValueError(f"{name} is True or False, got {value!r}")


@dataclass(frozen=True)
class MotorTargets:
    """The motor controller of ``motor_targets=True`` (module doc).

    Attributes:
        l_min, l_max: each winch's rest-length range, (W,) [m].
        v_max: each winch's top winding speed, (W,) [m/s].
        control_dt: one control step [s].
    """

    l_min: np.ndarray
    l_max: np.ndarray
    v_max: np.ndarray
    control_dt: float

    @classmethod
    def of(cls, params: Params, control_dt: float) -> MotorTargets:
        """The controller for a robot file's declared winches (``MjcfAssembly.params``)."""

        def arr(t: torch.Tensor) -> np.ndarray:
            return np.asarray(t.detach().cpu().numpy(), dtype=np.float64).copy()

        return cls(arr(params.winch_min), arr(params.winch_max), arr(params.winch_speed),
                   float(control_dt))  # fmt: skip

    def targets(self, actions: np.ndarray) -> np.ndarray:
        """Target rest lengths (..., W) [m] of actions (..., W) in [-1, 1]."""
        a = np.minimum(np.maximum(actions, -1.0), 1.0)
        result: np.ndarray = self.l_min + 0.5 * (a + 1.0) * (self.l_max - self.l_min)
        return result

    def commands(self, actions: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """The motors' speed commands (..., W) in [-1, 1] for actions (..., W) in [-1, 1]
        and the winches' rest lengths now, ``rest`` (..., W) [m]."""
        u = (self.targets(actions) - rest) / (self.v_max * self.control_dt)
        result: np.ndarray = np.minimum(np.maximum(u, -1.0), 1.0)
        return result
