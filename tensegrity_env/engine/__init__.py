"""Differentiable spring-rod engine (PyTorch): forces -> accelerations -> integration."""

from tensegrity_env.engine.effects import Effect, EffectBase
from tensegrity_env.engine.state import State
from tensegrity_env.engine.step import PHYSICS_DT, Engine, substeps_for

__all__ = ["PHYSICS_DT", "Effect", "EffectBase", "Engine", "State", "substeps_for"]
