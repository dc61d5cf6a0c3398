"""The residual loop: find what the model misses, name the effect, add it, refit.

:class:`EffectDiscovery` runs the effect library (:mod:`~identification.discovery.library`)
with one of two scorers: :class:`OneStepScorer` (one-step regressions on rod states)
or :class:`MultiStepScorer` (multi-step prediction of measured end caps); one judge
(:mod:`~identification.discovery.judge`), one result (:class:`DiscoveryResult`), one
report writer (:func:`write_report`, :func:`write_params`).
"""

from identification.discovery.library import LIBRARY, FitSettings
from identification.discovery.loop import DiscoveryResult, EffectDiscovery
from identification.discovery.multi_step import MultiStepScorer
from identification.discovery.one_step import OneStepScorer
from identification.discovery.report import write_params, write_report
from identification.discovery.scorer import LoopScorer, Scorer
from identification.trajectory.end_cap_data import TrajectorySettings
from identification.trajectory.fitted_model import FittedModel

__all__ = [
    "LIBRARY",
    "DiscoveryResult",
    "EffectDiscovery",
    "FitSettings",
    "FittedModel",
    "LoopScorer",
    "MultiStepScorer",
    "OneStepScorer",
    "Scorer",
    "TrajectorySettings",
    "write_params",
    "write_report",
]
