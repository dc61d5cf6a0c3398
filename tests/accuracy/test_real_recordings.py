"""Real recordings (``../shared/real`` beside the checkout; skipped when absent): the ETH
jumping 6-bar's raw OptiTrack exports imported with its NTRT model, nothing else given."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from identification.data.dataset import read_dataset

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "real" / "eth_jumping_6bar"
pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason=f"no real recordings at {REAL} (evaluation data "
                                "kept beside the checkout, not in it)")  # fmt: skip
ROBOT = REAL / "robot_ntrt" / "isodrop3Aext.yaml"


def imported(take: str, out: Path) -> tuple[np.ndarray, np.ndarray, str]:
    r = subprocess.run([sys.executable, "-m", "tensegrity_sr.cli", "import-mocap", str(REAL / "raw" / take),
                        "--robot", str(ROBOT), "--split", "1,0,0", "--segments", "0-30", "--piece", "0",
                        "-o", str(out)],
                       capture_output=True, text=True, check=False)  # fmt: skip
    assert r.returncode == 0, r.stderr
    split = read_dataset(out).split("train")
    assert split.time is not None
    return split.nodes[0], split.time[0], r.stdout


@pytest.fixture(scope="module")
def drop(tmp_path_factory: pytest.TempPathFactory) -> tuple[np.ndarray, np.ndarray, str]:
    return imported("T2_drop_newnodes_.csv", tmp_path_factory.mktemp("drop") / "drop.h5")


def test_the_drop_is_labelled_set_upright_and_its_rods_keep_their_length(drop) -> None:  # type: ignore[no-untyped-def]
    caps, time, out = drop
    assert "up is y (free flight" in out
    # the person's stretch: the resting robot starts to move when touched, leaves the floor
    # held (about 7 s) and is let go (about 11.5 s, the impact 0.3 s later)
    found = re.search(r"external ([\d.]+)-([\d.]+) s \(off the floor and not falling freely "
                      r"([\d.]+)-([\d.]+) s\)", out)  # fmt: skip
    assert found is not None, out
    touched, released, lifted, let_go = map(float, found.groups())
    assert abs(lifted - 7.0) < 0.5 and abs(let_go - 11.5) < 0.5 and abs(released - 11.5) < 0.5
    assert 6.0 < touched <= lifted
    # labelled as tracked: one cap lies hidden under the robot after the drop (11 markers
    # from 13.8 s on); every other cap is tracked in most frames
    tracked = sorted(float(x) for x in re.findall(r"^  rod\d\.\d\s+([\d.]+) %", out, re.M))
    assert len(tracked) == 12 and np.mean(tracked) > 90.0 and tracked[1] > 83.0
    # the markers, millimetres beyond the model's end caps, placed onto them; heights from
    # the floor the resting robot shows
    beyond = re.search(r"markers sit ([\d.]+) to ([\d.]+) mm beyond the model's end caps along 6 rods", out)
    assert beyond is not None and 0.0 < float(beyond[1]) <= float(beyond[2]) < 10.0
    assert re.search(r"the floor lies at z = [\d.]+ mm", out)
    seen = np.isfinite(caps).all(-1)
    low = np.nanmin(np.where(seen, caps[..., 2], np.nan), axis=1)
    rest = (time < 6.5) | (time > 13.0)  # on the floor before the hands and after the drop
    assert abs(np.nanmedian(low[rest]) - 0.006) < 0.003  # the lowest caps one rod radius (6 mm) up
    assert np.nanmax(low) > 0.3  # lifted by a person before the drop
    apart = np.linalg.norm(caps[:, 0::2] - caps[:, 1::2], axis=-1)
    for r in range(apart.shape[1]):
        d = apart[:, r]
        near = [np.nanmedian(d[np.abs(time - time[f]) <= 0.5]) for f in np.flatnonzero(np.isfinite(d))[::10]]
        assert np.all(np.abs(d[np.isfinite(d)][::10] - near) <= 0.002 + 1e-9)
        assert abs(np.nanmedian(d) - 0.5) < 0.001  # the model's 0.5 m between its end caps


def test_the_jump_take_imports_with_its_repeated_frames_as_gaps(tmp_path: Path, drop) -> None:  # type: ignore[no-untyped-def]
    caps, time, out = imported("T5_3A_thirdcomp.csv", tmp_path / "jump.h5")
    assert "up is y" in out and "frames repeated the frame before" in out
    seen = np.isfinite(caps).all(-1)
    measured = np.isfinite(caps).any(-1).any(-1)  # frames that are not repeats
    # every 4th frame repeats the one before (72 % measured); in the jump a few frames
    # more see only markers whose rod's other one is hidden: their caps are not placed
    assert 0.66 < measured.mean() < 0.76
    late = time > 10.0  # after the jump and the landing
    assert seen[late].mean() > 0.55  # found again after the tracking was lost in the jump
    # the floor the compressed robot rests on, at the height the drop take found (one day's
    # recordings, one calibration)
    floors = [float(x) for x in re.findall(r"the floor lies at z = ([\d.]+) mm", out)]
    floors += [float(x) for x in re.findall(r"the floor lies at z = ([\d.]+) mm", drop[2])]
    assert len(floors) == 2 and abs(floors[0] - floors[1]) < 1.0
