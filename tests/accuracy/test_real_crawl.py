"""The real 3-bar crawl (``../shared/real/bekris_3bar`` beside the checkout; skipped when
absent): converted by ``benchmarks/bekris_crawl.py``, imported with its command log at
its own uneven sample times, flagged by ``inspect``, its winding identified."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from bekris_crawl import convert

from identification.data.dataset import read_dataset
from tensegrity_sr.cli import main

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "real" / "bekris_3bar"
pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason=f"no real recordings at {REAL} (evaluation data "
                                "kept beside the checkout, not in it)")  # fmt: skip


def test_the_crawl_keeps_its_times_and_its_winding_is_identified(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    files = convert(REAL, tmp_path)
    h5 = tmp_path / "crawl.h5"
    assert main(["import-mocap", str(files.caps), "--robot", str(files.robot), "--units", "m",
                 "--commands", str(files.commands), "--split", "0.7,0.3,0", "-o", str(h5)]) == 0  # fmt: skip
    data = read_dataset(h5)
    times = np.concatenate([data.split(s).time[0] for s in ("train", "val")])
    steps = np.diff(data.split("val").time[0])
    assert len(times) == 366 and abs(steps.max() - 1.006) < 1e-3  # every record, the 1 s gap kept
    assert data.split("train").has_winch_commands
    capsys.readouterr()
    assert main(["inspect", str(h5)]) == 0
    out = capsys.readouterr().out
    short = re.search(r"time stamps: (\d+) steps too short to be capture times", out)
    assert short is not None and int(short.group(1)) >= 84  # the README's 84 steps under 5 ms
    assert re.search(r"time stamps: \d+ gaps", out)
    ident = tmp_path / "identified.json"
    assert main(["identify", str(h5), "--params", str(files.robot), "-o", str(ident)]) == 0
    doc = json.loads(ident.read_text())
    prov = doc["provenance"]
    # the fitted winding follows the measured cable lengths closer than the lab's values
    assert prov["cable_length_rms_m"] < 0.75 * prov["declared_cable_length_rms_m"]
    assert 0.0 < doc["params"]["winch_speed"][0] < 0.2
