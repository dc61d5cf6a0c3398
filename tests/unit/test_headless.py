"""MuJoCo's GL backend on a machine without a display: chosen only where its library is."""

from __future__ import annotations

import os
import subprocess
import sys

from tensegrity_env.headless import headless_gl_backend


def test_a_backend_is_chosen_only_where_its_library_is_found() -> None:
    assert headless_gl_backend(lambda name: f"lib{name}.so.1") == "egl"
    assert headless_gl_backend(lambda name: "libOSMesa.so" if name == "OSMesa" else None) == "osmesa"
    # no libEGL and no OSMesa: MUJOCO_GL stays unset (egl there made `import mujoco` fail)
    assert headless_gl_backend(lambda name: None) is None


def test_importing_the_package_headless_leaves_mujoco_importable() -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    code = ("import os, tensegrity_env, mujoco; "
            "from tensegrity_env.headless import headless_gl_backend; "
            "print(os.environ.get('MUJOCO_GL'), headless_gl_backend())")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()  # fmt: skip
    assert out[0] == str(out[1])
