"""Rendering through MuJoCo's renderer, for the identified env and the twin alike.

Rod states (from the engine or from MuJoCo) are written into an ``MjData`` of a
MuJoCo model of the same assembly (:func:`tensegrity_env.mujoco_state.rod_state_to_mj`),
positions are propagated (``mj_fwdPosition``: bodies, sites, tendons) and the scene
is drawn with a goal marker on the floor. ``rgb_array`` uses an offscreen context:
headless Linux needs ``MUJOCO_GL=egl`` (or ``osmesa``) **before** ``mujoco`` is first
imported (``import tensegrity_env`` sets ``egl`` when there is no display and the
variable is unset). Where no OpenGL context can be made, rendering raises
:class:`RenderingUnavailable` with one line saying so.

:func:`write_video` writes frames to MP4 (imageio-ffmpeg) or GIF;
:func:`record_episode` and :func:`record_side_by_side` roll an env (or the
identified env and its twin from the same state under the same actions) into one.
Side-by-side frames (:func:`side_by_side`) carry each half's name drawn into the
image (:func:`label_frame`): an env's ``label`` attribute, e.g. "identified model
(IcosahedronSR-v0)" and "MuJoCo (IcosahedronMJ-v0)".
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import imageio.v2 as imageio
import mujoco
import numpy as np

from tensegrity_env.io_utils import atomic_path
from tensegrity_env.mjcf import MjcfAssembly
from tensegrity_env.mujoco_state import rod_state_to_mj

#: camera: looks at the midpoint of the structure and its goal from CAMERA_DISTANCE [m]
#: plus CAMERA_ZOOM times their separation, so that both stay in view
CAMERA_DISTANCE = 2.5
CAMERA_ZOOM = 1.1
CAMERA_ELEVATION = -35.0  # deg
CAMERA_AZIMUTH = 135.0  # deg
GOAL_RGBA = (0.15, 0.8, 0.25, 0.7)


def has_display() -> bool:
    """Whether a window can be opened (always assumed off Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class RenderingUnavailable(RuntimeError):
    """MuJoCo's renderer cannot get an OpenGL context (or a window) here."""


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


class SceneRenderer:
    """Draws packed rod states (R, 13) of one assembly with a goal marker.

    Args:
        assembly: the MuJoCo model of the assembly (with its floor) and its maps.
        width, height: image size [px] (at most the model's offscreen buffer).
        goal_radius: radius of the goal marker [m].
        shadows: draw shadows and floor reflections (6x slower with software OpenGL,
            the usual headless case).
    """

    def __init__(
        self,
        assembly: MjcfAssembly,
        width: int = 640,
        height: int = 480,
        goal_radius: float = 0.3,
        shadows: bool = False,
    ) -> None:
        m = assembly.model
        if not (0 < width <= m.vis.global_.offwidth and 0 < height <= m.vis.global_.offheight):
            raise ValueError(
                f"render size {width}x{height} must be within the model's offscreen buffer "
                f"{m.vis.global_.offwidth}x{m.vis.global_.offheight}"
            )
        self.assembly, self.model = assembly, m
        self.data = mujoco.MjData(m)
        self.width, self.height, self.goal_radius = int(width), int(height), float(goal_radius)
        self.shadows = bool(shadows)
        self._renderer: mujoco.Renderer | None = None
        self._viewer: Any = None
        self._warned = False
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.camera.distance = CAMERA_DISTANCE
        self.camera.elevation = CAMERA_ELEVATION
        self.camera.azimuth = CAMERA_AZIMUTH

    # ------------------------------------------------------------------ scene
    def set_state(self, x: np.ndarray) -> None:
        """Pose the model from packed rod states (R, 13)."""
        qpos, qvel = rod_state_to_mj(self.assembly, x[:, 0:3], x[:, 3:6], x[:, 6:10], x[:, 10:13])
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        mujoco.mj_fwdPosition(self.model, self.data)

    def _aim(self, x: np.ndarray, goal: np.ndarray) -> None:
        centre = x[:, 0:3].mean(axis=0)
        self.camera.lookat[:] = (0.5 * (centre[0] + goal[0]), 0.5 * (centre[1] + goal[1]), 0.3)
        gap = float(np.hypot(goal[0] - centre[0], goal[1] - centre[1]))
        self.camera.distance = CAMERA_DISTANCE + CAMERA_ZOOM * gap

    def _add_goal(self, scene: mujoco.MjvScene, goal: np.ndarray) -> None:
        if scene.ngeom >= scene.maxgeom:
            return
        mujoco.mjv_initGeom(
            scene.geoms[scene.ngeom],
            mujoco.mjtGeom.mjGEOM_CYLINDER,
            np.array([self.goal_radius, 0.002, 0.0]),
            np.array([goal[0], goal[1], 0.002]),
            np.eye(3).ravel(),
            np.array(GOAL_RGBA, dtype=np.float32),
        )
        scene.ngeom += 1

    # ------------------------------------------------------------------ modes
    def rgb_array(self, x: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """An RGB image (height, width, 3) uint8 of the assembly in state ``x``."""
        if self._renderer is None:
            try:
                self._renderer = mujoco.Renderer(self.model, self.height, self.width)
            except Exception as e:  # MuJoCo raises several types for a missing GL context
                gl = os.environ.get("MUJOCO_GL", "unset")
                raise RenderingUnavailable(
                    f"MuJoCo's renderer has no OpenGL context ({_first_line(e)}); MuJoCo picks "
                    f"its GL backend when first imported (MUJOCO_GL is now {gl!r}): headless, "
                    "set MUJOCO_GL=egl or osmesa before anything imports mujoco"
                ) from None
            for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION):
                self._renderer.scene.flags[flag] = self.shadows
        self.set_state(x)
        self._aim(x, goal)
        self._renderer.update_scene(self.data, camera=self.camera)
        self._add_goal(self._renderer.scene, goal)
        result: np.ndarray = self._renderer.render().copy()
        return result

    def human(self, x: np.ndarray, goal: np.ndarray) -> None:
        """Show the state in MuJoCo's interactive viewer.

        Without a display (Linux, no ``DISPLAY``/``WAYLAND_DISPLAY``) this warns once
        and shows nothing, rather than letting GLFW end the process.
        """
        if self._viewer is None:
            if not has_display():
                if not self._warned:
                    gym.logger.warn("render_mode='human' needs a display; nothing is shown")
                    self._warned = True
                return
            try:
                import mujoco.viewer

                self._viewer = mujoco.viewer.launch_passive(self.model, self.data)
            except Exception as e:
                raise RenderingUnavailable(
                    f"MuJoCo's viewer cannot open a window ({_first_line(e)}); "
                    "use render_mode='rgb_array' headless"
                ) from None
        with self._viewer.lock():
            self.set_state(x)
            self._aim(x, goal)
            self._viewer.cam.lookat[:] = self.camera.lookat
            self._viewer.user_scn.ngeom = 0
            self._add_goal(self._viewer.user_scn, goal)
        self._viewer.sync()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None


# ---------------------------------------------------------------------- labels
def env_label(env: Any) -> str:
    """What a video calls ``env``: its ``label`` (e.g. "MuJoCo (IcosahedronMJ-v0)"),
    else its registered id, else its class name."""
    base = getattr(env, "unwrapped", env)
    label = getattr(base, "label", None)
    if label:
        return str(label)
    spec = getattr(env, "spec", None)
    return spec.id if spec is not None else type(base).__name__


def label_frame(frame: np.ndarray, text: str) -> np.ndarray:
    """A copy of ``frame`` (H, W, 3) uint8 with ``text`` in white on a dark band, top left.

    The font height is about 1/18 of the frame height (at least 10 px).
    """
    from PIL import Image, ImageDraw, ImageFont

    image = Image.fromarray(np.ascontiguousarray(frame[..., :3], dtype=np.uint8))
    draw = ImageDraw.Draw(image)
    try:
        font: Any = ImageFont.load_default(size=max(10, frame.shape[0] // 18))
    except (TypeError, OSError):  # Pillow without FreeType: its fixed bitmap font
        font = ImageFont.load_default()
    pad = max(3, frame.shape[0] // 80)
    left, top, right, bottom = draw.textbbox((2 * pad, 2 * pad), text, font=font)
    draw.rectangle((left - pad, top - pad, right + pad, bottom + pad), fill=(20, 20, 20))
    draw.text((2 * pad, 2 * pad), text, fill=(255, 255, 255), font=font)
    return np.asarray(image)


def side_by_side(
    left: np.ndarray, right: np.ndarray, left_label: str, right_label: str
) -> np.ndarray:
    """Two frames (H, W, 3) side by side (H, 2W, 3), each labelled with what it shows."""
    return np.concatenate([label_frame(left, left_label), label_frame(right, right_label)], axis=1)


# ---------------------------------------------------------------------- videos
def write_video(frames: Sequence[np.ndarray], path: str | Path, fps: float = 20.0) -> Path:
    """Write RGB frames (H, W, 3) uint8 to ``path``: ``.mp4`` (H.264) or ``.gif`` (atomically)."""
    out = Path(path)
    if not frames:
        raise ValueError("no frames to write")
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"{out}: video must end in .mp4 or .gif")
    with atomic_path(out, keep_extension=True) as tmp:
        if suffix == ".gif":
            imageio.mimsave(tmp, list(frames), duration=1000.0 / fps, loop=0)
        else:
            imageio.mimsave(tmp, list(frames), fps=fps, macro_block_size=1)
    return out


Policy = Callable[[np.ndarray], np.ndarray]


def record_episode(
    env: Any,
    path: str | Path,
    policy: Policy | None = None,
    seed: int | None = 0,
    max_steps: int = 200,
) -> Path:
    """Roll ``env`` (``render_mode='rgb_array'``) under ``policy`` (random if None) to a video."""
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    frames = [env.render()]
    for _ in range(max_steps):
        action = env.action_space.sample() if policy is None else policy(obs)
        obs, _, terminated, truncated, _ = env.step(action)
        frames.append(env.render())
        if terminated or truncated:
            break
    return write_video(frames, path, fps=env.metadata.get("render_fps", 20))


def record_side_by_side(
    left: Any,
    right: Any,
    path: str | Path,
    policy: Policy | None = None,
    seed: int = 0,
    max_steps: int = 200,
) -> Path:
    """Both envs from ``left``'s seeded initial state under the same actions, side by side.

    ``policy`` sees ``left``'s observations (random actions if None). Typically the
    identified env on the left and its MuJoCo twin on the right; each half is
    labelled with :func:`env_label`.
    """
    left.reset(seed=seed)
    start = left.unwrapped.start_options()
    obs, _ = left.reset(options=start)
    right.reset(options=start)
    rng = np.random.default_rng(seed)
    names = env_label(left), env_label(right)
    frames = [side_by_side(left.render(), right.render(), *names)]
    for _ in range(max_steps):
        action = (
            rng.uniform(-1, 1, left.action_space.shape).astype(np.float32)
            if policy is None
            else policy(obs)
        )
        obs, _, t1, u1, _ = left.step(action)
        _, _, t2, u2, _ = right.step(action)
        frames.append(side_by_side(left.render(), right.render(), *names))
        if t1 or u1 or t2 or u2:
            break
    return write_video(frames, path, fps=left.metadata.get("render_fps", 20))
