"""Progress bars over the long fits a user waits on: the Levenberg-Marquardt
iterations of the floor rounds and of ``diagnose``'s final refit on the floor."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
from tqdm.auto import tqdm

from identification.trajectory.forked import in_worker


@contextmanager
def iteration_bar(desc: str, iterations: int) -> Iterator[Callable[[float], None]]:
    """A ``progress`` callback for :func:`~identification.trajectory.windowed_problem.fit`:
    one tick per iteration (at most ``iterations``), the end-cap RMS [mm] beside it.

    The bar shows on a terminal only (tqdm's default), is cleared when the fit ends (its
    result is logged), and never shows in a forked worker, whose siblings would write
    over it.
    """
    bar = tqdm(total=iterations, desc=desc, unit="iteration", leave=False,
               disable=True if in_worker() else None)  # fmt: skip

    def tick(mean_squared: float) -> None:
        bar.set_postfix_str(f"end-cap RMS {np.sqrt(mean_squared) * 1e3:.3f} mm", refresh=False)
        bar.update(1)

    try:
        yield tick
    finally:
        bar.close()
