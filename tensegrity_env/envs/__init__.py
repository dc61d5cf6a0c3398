"""Gymnasium environments: the rolling icosahedron on the identified engine and in MuJoCo.

==========================  ====================================================
``IcosahedronSR-v0``        :class:`IcosahedronSREnv`: the identified engine
                            (params file; native C kernel or PyTorch engine)
``IcosahedronMJ-v0``        :class:`IcosahedronMJEnv`: the MuJoCo twin, ground truth
``TensegritySR-v0``         :class:`TensegritySREnv`: any winch-driven robot on its
                            identified model (native C kernel or PyTorch engine);
                            batched: :class:`TensegritySRVectorEnv`
``TensegrityMJ-v0``         :class:`TensegrityMJEnv`: that robot in MuJoCo (its twin);
                            batched: :class:`TensegrityMJVectorEnv` (``mujoco.rollout``)
``gym.make_vec(...)``       :class:`IcosahedronSRVectorEnv` /
                            :class:`IcosahedronMJVectorEnv`: N envs, one batched step
:class:`SB3VecEnv`          Stable-Baselines3 ``VecEnv`` adapter
==========================  ====================================================

Modules: :mod:`.task` (reset, actions, observation, reward: shared),
:mod:`.base` (the single-env base), :mod:`.sr_env`, :mod:`.mj_env`, :mod:`.vector`,
:mod:`.sb3`, :mod:`.physics` (steppers; the C kernel in :mod:`tensegrity_env.native`),
:mod:`.rendering` (MuJoCo renderer, videos), :mod:`.twin` (the ground truth);
for any robot: :mod:`.robot_task` (sensors, goal and shape tasks),
:mod:`.robot_physics` (its model and twin), :mod:`.robot_faces` (the other faces it
rests on: tipped starts), :mod:`.robot_rollout` (its twins through ``mujoco.rollout``),
:mod:`.robot_env`, :mod:`.robot_vector`.
"""

from tensegrity_env.envs.mj_env import IcosahedronMJEnv
from tensegrity_env.envs.rendering import (
    RenderingUnavailable,
    record_episode,
    record_side_by_side,
    write_video,
)
from tensegrity_env.envs.robot_env import TensegrityMJEnv, TensegritySREnv
from tensegrity_env.envs.robot_vector import TensegrityMJVectorEnv, TensegritySRVectorEnv
from tensegrity_env.envs.sr_env import DEFAULT_PARAMS, IcosahedronSREnv, load_env_model
from tensegrity_env.envs.task import RollingTask
from tensegrity_env.envs.vector import IcosahedronMJVectorEnv, IcosahedronSRVectorEnv


def __getattr__(name: str) -> object:
    if name == "SB3VecEnv":  # imported on use: Stable-Baselines3 is slow to import
        from tensegrity_env.envs.sb3 import SB3VecEnv

        return SB3VecEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DEFAULT_PARAMS",
    "IcosahedronMJEnv",
    "IcosahedronMJVectorEnv",
    "IcosahedronSREnv",
    "IcosahedronSRVectorEnv",
    "RenderingUnavailable",
    "RollingTask",
    "SB3VecEnv",
    "TensegrityMJEnv",
    "TensegrityMJVectorEnv",
    "TensegritySREnv",
    "TensegritySRVectorEnv",
    "load_env_model",
    "record_episode",
    "record_side_by_side",
    "write_video",
]
