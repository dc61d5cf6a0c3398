"""Time spans on the command line: every window, horizon, filter span and step is in seconds.

``0.1``, ``0.1s`` and ``100ms`` all mean 0.1 s; a bare number is seconds. Spans are
turned into sample counts only against a dataset's sample interval
(:func:`samples_of`), so the same option means the same time at 60 Hz and at 1 kHz.
"""

from __future__ import annotations

import argparse
import math
import re

_DURATION = re.compile(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(s|ms)?\s*")


def seconds(text: str) -> float:
    """An argparse ``type``: ``"0.1"``, ``"0.1s"`` or ``"100ms"`` -> 0.1 [s] (>= 0, finite)."""
    m = _DURATION.fullmatch(str(text))
    if m is None:
        raise argparse.ArgumentTypeError(
            f"'{text}' is not a duration: give seconds, e.g. 0.1s, 0.1 or 100ms"
        )
    value = float(m.group(1)) * (1e-3 if m.group(2) == "ms" else 1.0)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"'{text}' is not a finite duration")
    return value


def samples_of(span: float, dt: float, minimum: int = 1) -> int:
    """Sample intervals in ``span`` [s] at sample interval ``dt`` [s], at least ``minimum``."""
    return max(minimum, round(span / dt))


def describe(span: float, dt: float) -> str:
    """``"0.1 s (12 samples at 120 Hz)"``: a span as given and as the data sees it."""
    return f"{span:g} s ({samples_of(span, dt)} samples at {1 / dt:g} Hz)"
