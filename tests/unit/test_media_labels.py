"""Side-by-side videos say which half is the identified model and which is MuJoCo, and
consoles and reports call a diverged rollout "diverged" alike."""

from __future__ import annotations

from pathlib import Path

import imageio.v2 as imageio
import numpy as np

from identification.experiments.long_horizon import checkpoint_table
from identification.report.tables import error_text
from tensegrity_env.envs import IcosahedronMJEnv, IcosahedronSREnv
from tensegrity_env.envs.rendering import (
    env_label,
    label_frame,
    record_side_by_side,
    side_by_side,
)


def bright(region: np.ndarray) -> int:
    """Pixels that are near white (label text)."""
    return int((region.min(axis=-1) > 200).sum())


def test_a_label_is_drawn_in_the_top_left_corner_only() -> None:
    frame = np.full((300, 400, 3), 90, np.uint8)
    out = label_frame(frame, "MuJoCo (IcosahedronMJ-v0)")
    assert out.shape == frame.shape and out.dtype == np.uint8
    changed = np.any(out != frame, axis=-1)
    rows, cols = np.nonzero(changed)
    assert rows.max() < 300 // 6 and cols.max() < 400 * 0.9  # a band at the top left
    assert bright(out[: rows.max() + 1]) > 50  # white text on the dark band
    assert np.array_equal(frame, np.full((300, 400, 3), 90, np.uint8))  # input untouched


def test_side_by_side_labels_each_half_with_its_own_text() -> None:
    blank = np.full((120, 160, 3), 90, np.uint8)
    both = side_by_side(blank, blank, "identified model", "MuJoCo")
    assert both.shape == (120, 320, 3)
    left, right = both[:, :160], both[:, 160:]
    assert not np.array_equal(left, right)  # different words
    assert np.array_equal(left, label_frame(blank, "identified model"))


def test_side_by_side_video_of_the_two_envs_is_labelled(tmp_path: Path) -> None:
    kw = {"render_mode": "rgb_array", "width": 160, "height": 120}
    sr, mj = IcosahedronSREnv(**kw), IcosahedronMJEnv(**kw)
    assert env_label(sr) == "identified model (IcosahedronSR-v0)"
    assert env_label(mj) == "MuJoCo (IcosahedronMJ-v0)"
    path = record_side_by_side(sr, mj, tmp_path / "clip.gif", max_steps=2)
    first = np.asarray(imageio.mimread(path))[0][..., :3]
    assert first.shape == (120, 320, 3)
    sr.reset(seed=0)
    plain = sr.render()
    band = slice(0, 120 // 6)
    assert bright(first[band, :160]) > bright(plain[band]) + 20
    assert bright(first[band, 160:]) > bright(plain[band]) + 20
    assert [p.name for p in tmp_path.iterdir()] == ["clip.gif"]  # written atomically
    sr.close()
    mj.close()


def test_diverged_is_the_word_everywhere() -> None:
    assert error_text(float("nan")) == error_text(float("inf")) == "diverged"
    assert error_text(1.234e-3, ".3e") == "1.234e-03 m"
    assert error_text(2e-3, ".4f", "mm", 1e3) == "2.0000 mm"
    curves = {"ok": {"position": np.full(101, 1e-3), "orientation": np.full(101, 0.01)},
              "blew up": {"position": np.full(101, np.nan), "orientation": np.full(101, np.nan)}}  # fmt: skip
    table = checkpoint_table(curves, 1e-3)
    assert "| ok | 1 mm / 0.573° |" in table and "| blew up | diverged |" in table
    assert "nan" not in table
