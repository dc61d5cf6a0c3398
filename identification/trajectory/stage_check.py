"""Is a stage's result usable? The noise level of the data, and the checks against it.

A fit through the engine can diverge (a rollout that leaves the data by metres) or
come out non-finite; nothing may be judged against such a model. The yardstick is the
measurement noise, estimated from the end caps themselves (:func:`noise_level`): a
stage whose end-cap RMS is not finite or exceeds :data:`DIVERGED` noise levels (and
:data:`DIVERGED_M`) has failed, and says so in one line (:class:`StageError`).
"""

from __future__ import annotations

import math

import numpy as np

from identification.data.quality import third_difference_noise
from tensegrity_env.io_utils import StageError

#: a fit whose end-cap RMS exceeds this many noise levels has diverged ...
DIVERGED = 100.0
#: ... and this much [m] (clean data: a model missing an effect is off by millimetres)
DIVERGED_M = 0.01


def noise_level(nodes: np.ndarray) -> float:
    """Measurement noise std [m] of end-cap trajectories ``nodes`` (N, T+1, C, 3); 0 where
    no end cap is seen in four consecutive samples.

    A robust scale of the third differences along time
    (:func:`~identification.data.quality.third_difference_noise`): white noise of std σ
    gives third differences of std ``sqrt(20) σ``, while smooth motion sampled at tens of
    hertz or faster gives third differences far below a millimetre (impacts are rare
    samples and do not move the median).
    """
    x = np.asarray(nodes, dtype=float)
    if x.ndim != 4 or x.shape[1] < 4:
        return 0.0
    noise = third_difference_noise(np.diff(x, n=3, axis=1))
    return 0.0 if math.isnan(noise) else noise


def diverged_limit(noise: float) -> float:
    """End-cap RMS [m] above which a fit has diverged, for data of noise std ``noise``."""
    return max(DIVERGED * noise, DIVERGED_M)


def fit_diverged(rms: float, noise: float) -> bool:
    """Whether an end-cap RMS [m] is non-finite or beyond :func:`diverged_limit`."""
    return not math.isfinite(rms) or rms > diverged_limit(noise)


def check_stage(stage: str, rms: float, noise: float, advice: str) -> None:
    """Raise :class:`StageError` naming ``stage`` if its end-cap RMS [m] has diverged."""
    if fit_diverged(rms, noise):
        cause = (
            "the end-cap RMS is not finite"
            if not math.isfinite(rms)
            else f"end-cap RMS {rms * 1e3:.4g} mm against a noise level of {noise * 1e3:.3g} mm "
            f"(limit {diverged_limit(noise) * 1e3:.3g} mm): the model diverged"
        )
        raise StageError(stage, cause, advice)
