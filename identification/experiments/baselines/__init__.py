"""The paper's baselines, trained and evaluated on the same splits as our engine.

* :class:`Interaction` — the improved Interaction Network (two MLPs, state change out);
* :class:`InteractionInt` — the same with the integration module (accelerations out);
* :class:`KoopmanInt` — a linear (Koopman) operator on lifted spring-frame observables
  predicting accelerations, then the integration module.

Every model has ``fit(dataset, split, val_split) -> self``, ``predict(state) -> State``
(one step, float64 states) and ``history_`` (the training curve); rollouts feed
predictions back (:mod:`identification.experiments.baselines.evaluate`).
"""

from identification.experiments.baselines.common import ConstantVelocity, EnginePredictor, Predictor
from identification.experiments.baselines.interaction import Interaction
from identification.experiments.baselines.interaction_int import InteractionInt
from identification.experiments.baselines.koopman import KoopmanConfig, KoopmanInt
from identification.experiments.baselines.training import TrainConfig

__all__ = [
    "ConstantVelocity",
    "EnginePredictor",
    "Interaction",
    "InteractionInt",
    "KoopmanConfig",
    "KoopmanInt",
    "Predictor",
    "TrainConfig",
]
