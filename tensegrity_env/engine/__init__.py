"""Differentiable spring-rod engine (PyTorch): forces -> accelerations -> integration.

Names are imported on first use: the effects build on the engine's stages
(:mod:`~tensegrity_env.engine.forces`, :mod:`~tensegrity_env.engine.kinematics`, ...)
and the step (:mod:`~tensegrity_env.engine.step`) composes the effects, so importing a
stage must not import the step.
"""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "PHYSICS_DT": "tensegrity_env.engine.step",
        "Effect": "tensegrity_env.engine.effects",
        "EffectBase": "tensegrity_env.engine.effects",
        "Engine": "tensegrity_env.engine.step",
        "State": "tensegrity_env.engine.state",
        "substeps_for": "tensegrity_env.engine.step",
    },
)
