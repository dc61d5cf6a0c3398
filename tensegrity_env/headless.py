"""MuJoCo's GL backend on a Linux machine without a display.

MuJoCo picks its GL backend when it is first imported, from ``MUJOCO_GL``. Headless,
rendering needs ``egl`` (or ``osmesa``); but with ``MUJOCO_GL=egl`` on a machine
without libEGL, ``import mujoco`` itself fails (PyOpenGL raises an ``AttributeError``
that MuJoCo does not catch), so a backend is only chosen where its library is found.
"""

from __future__ import annotations

import ctypes.util
import os
import sys
from collections.abc import Callable, MutableMapping

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


def default_mujoco_gl(
    environ: MutableMapping[str, str] = os.environ,
    platform: str = sys.platform,
    find_library: Callable[[str], str | None] = ctypes.util.find_library,
) -> None:
    """Set ``MUJOCO_GL`` in ``environ`` to :func:`headless_gl_backend` on a Linux machine
    without a display (no ``DISPLAY`` or ``WAYLAND_DISPLAY``), unless it is set already
    or no backend's library is found."""
    if not platform.startswith("linux") or "MUJOCO_GL" in environ:
        return
    if environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"):
        return
    backend = headless_gl_backend(find_library)
    if backend is not None:
        environ["MUJOCO_GL"] = backend
