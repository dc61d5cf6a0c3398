"""Is a stage's result usable? The noise level of the data, and the checks against it.

A fit through the engine can diverge (a rollout that leaves the data by metres) or
come out non-finite; nothing may be judged against such a model. The yardstick is the
measurement noise, estimated from the end caps themselves (:func:`noise_level`, from
the spread of each rigid rod's measured length where the caps come in rod pairs): a
stage whose end-cap RMS is not finite or exceeds :data:`DIVERGED` noise levels (and
:data:`DIVERGED_M`) has failed, and says so in one line (:class:`StageError`).

A fit can also reach the noise with parameters the data does not determine: with the
springs driven to almost nothing, the rods move independently and the masses other
than the anchored one no longer enter the dynamics (ground contact is per kilogram), so
they drift by any factor at the same end-cap RMS. Its standard errors say so:
:func:`check_determined` fails a stage in which an identified mass, inertia, stiffness
or rest length has a standard error of :data:`UNDETERMINED` times its value or more;
one from :data:`POORLY_DETERMINED` times up is written with a warning
(:func:`undetermined` with that limit).
"""

from __future__ import annotations

import math

import numpy as np

from identification.data.quality import MAD_TO_STD, third_difference_noise
from identification.linear.regression import ParameterRow
from tensegrity_env.io_utils import StageError

#: a fit whose end-cap RMS exceeds this many noise levels has diverged ...
DIVERGED = 100.0
#: ... and this much [m] (clean data: a model missing an effect is off by millimetres)
DIVERGED_M = 0.01


#: the fewest rod-length samples (both end caps seen) :func:`noise_level` reads the
#: noise from; with fewer it takes the third differences
LEAST_LENGTHS = 50


def noise_level(nodes: np.ndarray, rods: bool = False) -> float:
    """Measurement noise std [m] of end-cap trajectories ``nodes`` (N, T+1, C, 3); 0 where
    no end cap is seen in four consecutive samples.

    ``rods``: the end caps come in rod pairs (caps ``2r`` and ``2r + 1`` on rigid rod
    ``r``, as a dataset's topology orders them). The noise is then read from the spread
    of each rod's measured length ``|x_1 - x_0|`` about its median (per trajectory and
    rod): ``1.4826 MAD / √2``, since isotropic noise of std σ on both caps moves the
    length by std ``√2 σ``. No motion enters a rigid rod's length, at any sample rate or
    through impacts; the third differences below read motion as noise where the
    samples are sparse for it (a fast tumble at 60 Hz reads as several times its noise;
    measured in docs/decisions.md).

    Otherwise (or with fewer than :data:`LEAST_LENGTHS` lengths) a robust scale of the third differences along time
    (:func:`~identification.data.quality.third_difference_noise`): white noise of std σ
    gives third differences of std ``sqrt(20) σ``, while smooth motion sampled at tens of
    hertz or faster gives third differences far below a millimetre (impacts are rare
    samples and do not move the median).
    """
    x = np.asarray(nodes, dtype=float)
    if rods and x.ndim == 4 and x.shape[2] % 2 == 0:
        length = np.linalg.norm(x[:, :, 1::2] - x[:, :, 0::2], axis=-1)  # (N, T+1, R)
        seen = np.isfinite(length).any(axis=1, keepdims=True)  # a rod never seen has no median
        median = np.nanmedian(np.where(seen, length, 0.0), axis=1, keepdims=True)
        dev = np.where(seen, length - median, np.nan)
        dev = dev[np.isfinite(dev)]
        if dev.size >= LEAST_LENGTHS:
            return MAD_TO_STD * float(np.median(np.abs(dev))) / np.sqrt(2.0)
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


#: an identified parameter whose standard error reaches this multiple of its value is
#: not determined by the data (zero and twice the value fit alike); good family fits stay
#: below 0.1, the wrong ones written at the noise reach 1e2-1e4 (docs/decisions.md)
UNDETERMINED = 1.0
#: ... and one whose standard error reaches this multiple is written with a warning (every
#: drawn plant's fit off by more than 10 % reaches it, those within 3 % stay below 0.11,
#: docs/decisions.md)
POORLY_DETERMINED = 0.1
#: the groups :func:`check_determined` reads: the ones a written model is trusted for
#: (a spring's damping is excluded: a small damping is legitimately barely seen)
DETERMINED_GROUPS = ("mass", "inertia", "stiffness", "rest_length")
#: a model is refused only where the data leaves a mass undetermined (the model's scale
#: is then arbitrary); inertias and springs a take barely excites get the warning (a real
#: jump take leaves two inertias and nine stiffnesses at 1.1-9 times their error)
REFUSING_GROUPS = ("mass",)


def undetermined(rows: list[ParameterRow], limit: float = UNDETERMINED) -> list[tuple[str, float]]:
    """The identified (or ratio) rows of :data:`DETERMINED_GROUPS` whose standard error
    is ``limit`` times their value or more (infinite: a direction the data does not see),
    as ``(name, stderr / |value|)``, the largest ratio first. Anchored, frozen and
    not-identifiable rows and rows without a standard error (NaN) are not judged."""
    out = []
    for r in rows:
        if r.status not in ("identified", "ratio") or r.group not in DETERMINED_GROUPS:
            continue
        if math.isnan(r.stderr):
            continue
        ratio = abs(r.stderr) / abs(r.value) if r.value != 0 else math.inf
        if not ratio < limit:
            out.append((r.name, ratio))
    return sorted(out, key=lambda x: -x[1])


def check_determined(stage: str, rows: list[ParameterRow], advice: str) -> None:
    """Raise :class:`StageError` naming ``stage`` and the worst parameter when a mass row
    of ``rows`` (:data:`REFUSING_GROUPS`) is :func:`undetermined` by the data: a model
    that fits the end caps with such values is not written. Undetermined inertias,
    stiffnesses and rest lengths alone are left to the warning (:data:`POORLY_DETERMINED`)."""
    bad = undetermined(rows)
    if any(r.group in REFUSING_GROUPS for r in rows if r.name in dict(bad)):
        name, ratio = bad[0]
        more = f" (and {len(bad) - 1} more parameters)" if len(bad) > 1 else ""
        raise StageError(stage, f"{name} has a standard error {ratio:.3g} times its value"
                         f"{more}: the data does not determine it (not written)", advice)  # fmt: skip
