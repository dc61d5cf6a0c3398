"""tensegrity_env: the spring-rod world (topology, MuJoCo ground truth, engine, environments).

Importing the package registers the Gymnasium environments ``IcosahedronSR-v0`` (the
identified engine) and ``IcosahedronMJ-v0`` (its MuJoCo twin), each with a natively
batched ``vector_entry_point``, and ``TensegritySR-v0`` / ``TensegrityMJ-v0`` (any
winch-driven robot, identified and in MuJoCo; see :mod:`tensegrity_env.envs`). On a Linux machine
without a display it also defaults ``MUJOCO_GL`` to ``egl`` (before MuJoCo is
imported) so that rendering works headless, or to ``osmesa`` where only that library
is found, and leaves it unset where neither is
(:func:`~tensegrity_env.headless.default_mujoco_gl`); set it yourself to override.

:class:`~tensegrity_env.model.Model` (topology, params, effects, dt; ``params.json``)
and the names in ``__all__`` are imported on first use, so that importing the package
stays fast.
"""

from tensegrity_env.headless import default_mujoco_gl
from tensegrity_env.lazy import lazy_exports

default_mujoco_gl()


def _register_envs() -> None:
    from gymnasium.envs.registration import register, registry

    for name, single, vector in (
        ("IcosahedronSR-v0", "sr_env:IcosahedronSREnv", "vector:IcosahedronSRVectorEnv"),
        ("IcosahedronMJ-v0", "mj_env:IcosahedronMJEnv", "vector:IcosahedronMJVectorEnv"),
        ("TensegritySR-v0", "robot_env:TensegritySREnv", "robot_vector:TensegritySRVectorEnv"),
        ("TensegrityMJ-v0", "robot_env:TensegrityMJEnv", "robot_vector:TensegrityMJVectorEnv"),
    ):
        if name not in registry:
            register(
                id=name,
                entry_point=f"tensegrity_env.envs.{single}",
                vector_entry_point=None if vector is None else f"tensegrity_env.envs.{vector}",
                max_episode_steps=300,
            )


_register_envs()


__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "Model": "tensegrity_env.model",
        "Topology": "tensegrity_env.topology",
        "Rod": "tensegrity_env.topology",
        "Spring": "tensegrity_env.topology",
        "Params": "tensegrity_env.params",
        "Engine": "tensegrity_env.engine",
        "State": "tensegrity_env.engine",
        "Assembly": "tensegrity_env.assemblies",
        "icosahedron": "tensegrity_env.assemblies",
        "element": "tensegrity_env.assemblies",
        "SimOptions": "tensegrity_env.mjcf",
        "from_mjcf": "tensegrity_env.mjcf",
        "to_mjcf": "tensegrity_env.mjcf",
    },
)
