"""The paper's baselines, trained and evaluated on the same splits as our engine.

* :class:`Interaction` — the improved Interaction Network (two MLPs, state change out);
* :class:`InteractionInt` — the same with the integration module (accelerations out);
* :class:`KoopmanInt` — a linear (Koopman) operator on lifted spring-frame observables
  predicting accelerations, then the integration module.

Every model has ``fit(dataset, split, val_split) -> self``, ``predict(state) -> State``
(one step, float64 states) and ``history_`` (the training curve); rollouts feed
predictions back (:mod:`identification.baselines.evaluate`).
"""

from identification.baselines.common import ConstantVelocity, EnginePredictor, Predictor
from identification.baselines.interaction import Interaction
from identification.baselines.interaction_int import InteractionInt
from identification.baselines.koopman import KoopmanConfig, KoopmanInt
from identification.baselines.training import TrainConfig

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
