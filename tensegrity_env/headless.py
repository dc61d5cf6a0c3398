"""MuJoCo's GL backend on a Linux machine without a display.

MuJoCo picks its GL backend when it is first imported, from ``MUJOCO_GL``. Headless,
rendering needs ``egl`` (or ``osmesa``); but with ``MUJOCO_GL=egl`` on a machine
without libEGL, ``import mujoco`` itself fails (PyOpenGL raises an ``AttributeError``
that MuJoCo does not catch), so a backend is only chosen where its library is found.
"""

from __future__ import annotations

import ctypes.util
from collections.abc import Callable

#: backends tried in order, with the shared library each needs
BACKENDS = (("egl", "EGL"), ("osmesa", "OSMesa"))


def headless_gl_backend(
    find_library: Callable[[str], str | None] = ctypes.util.find_library,
) -> str | None:
    """The first of :data:`BACKENDS` whose library ``find_library`` finds, else None
    (leave ``MUJOCO_GL`` unset: MuJoCo imports without a renderer)."""
    for backend, library in BACKENDS:
        if find_library(library):
            return backend
    return None
