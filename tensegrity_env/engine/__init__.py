"""Differentiable spring-rod engine (PyTorch): forces -> accelerations -> integration."""

from tensegrity_env.engine.effects import Effect, EffectBase
from tensegrity_env.engine.state import State
from tensegrity_env.engine.step import Engine

__all__ = ["Effect", "EffectBase", "Engine", "State"]
