"""MuJoCo's GL backend on a machine without a display: chosen only where its library is."""

from __future__ import annotations

from tensegrity_env.headless import default_mujoco_gl, headless_gl_backend


def test_a_backend_is_chosen_only_where_its_library_is_found() -> None:
    assert headless_gl_backend(lambda name: f"lib{name}.so.1") == "egl"
    assert headless_gl_backend(lambda name: "libOSMesa.so" if name == "OSMesa" else None) == "osmesa"
    # no libEGL and no OSMesa: MUJOCO_GL stays unset (egl there made `import mujoco` fail)
    assert headless_gl_backend(lambda name: None) is None


def _default(environ: dict[str, str], platform: str = "linux", found: bool = True) -> dict[str, str]:
    env = dict(environ)
    default_mujoco_gl(env, platform, lambda name: f"lib{name}.so" if found else None)
    return env


def test_mujoco_gl_is_set_only_headless_on_linux_and_where_a_backend_is_found() -> None:
    assert _default({}) == {"MUJOCO_GL": "egl"}
    assert _default({}, found=False) == {}  # no libEGL: unset, mujoco still imports
    assert _default({"DISPLAY": ":0"}) == {"DISPLAY": ":0"}
    assert _default({"WAYLAND_DISPLAY": "wayland-0"}) == {"WAYLAND_DISPLAY": "wayland-0"}
    assert _default({}, platform="darwin") == {}
    assert _default({"MUJOCO_GL": "osmesa"}) == {"MUJOCO_GL": "osmesa"}  # the user's choice
