"""Motion-capture takes of a cable-driven robot: end caps with logged cable commands.

Split from ``test_mocap_import.py`` so that the identification through the engine
(cable commands are stepped in PyTorch) runs in a file of its own.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from identification.data.dataset import read_dataset
from identification.data.mocap.c3d_files import write_c3d
from identification.data.mocap.commands import write_commands
from identification.simulation.mocap_takes import record_take, simulate_caps

ROBOT = Path(__file__).resolve().parents[2] / "tensegrity_env" / "assets" / "icosahedron_rolling.xml"


def cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tensegrity_sr.cli", *map(str, args)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip


def test_logged_cable_commands_drive_the_robot_along_its_imported_end_caps(tmp_path: Path) -> None:
    """Cable commands logged at 40 Hz beside a 120 Hz take: held onto the frames, fed
    back into MuJoCo from the same start they reproduce the take's end caps exactly; a
    hold one frame late, or no commands, does not."""
    import re

    xml = re.sub(r'<geom name="floor"[^>]*/>', "", (ROBOT.parent / "lab_prism_force_actuators.xml").read_text())
    xml = xml.replace(' dyntype="filter" dynprm="0.03"', "")  # force actuators, no lag
    rng = np.random.default_rng(9)
    log_t = np.arange(40) / 40.0
    log_u = rng.uniform(-1.0, 1.0, (40, 3))
    _, caps, names = simulate_caps(xml, 120.0, 0.9, np.random.default_rng(3),
                                      commands=(log_t, log_u))  # fmt: skip
    write_c3d(tmp_path / "take.c3d", caps, names, 120.0, units="m")
    write_commands(tmp_path / "take_commands.csv", log_t, log_u, ["a0", "a1", "a2"])
    (tmp_path / "robot.xml").write_text(xml)
    r = cli("import-mocap", tmp_path / "take.c3d", "--robot", tmp_path / "robot.xml",
            "--commands", tmp_path / "take_commands.csv", "--split", "1,0,0", "-o", tmp_path / "d.h5")  # fmt: skip
    assert r.returncode == 0, r.stderr
    held = read_dataset(tmp_path / "d.h5").split("train").cable_control[0]  # (T, 3)
    np.testing.assert_array_equal(held[::3], log_u[: len(held[::3])])
    frames = np.arange(len(held)) / 120.0
    _, again, _ = simulate_caps(xml, 120.0, 0.9, np.random.default_rng(3), commands=(frames, held))
    assert np.abs(again - caps).max() < 1e-9
    late = np.concatenate([held[:1] * 0, held[:-1]])
    _, off, _ = simulate_caps(xml, 120.0, 0.9, np.random.default_rng(3), commands=(frames, late))
    _, none, _ = simulate_caps(xml, 120.0, 0.9, np.random.default_rng(3))
    assert np.abs(off - caps).max() > 1e-2 and np.abs(none - caps).max() > 1e-2



def _identified_from_takes(tmp_path: Path, takes: int):
    """The icosahedron with three tendon actuators (gains -40, -55, -70 N per unit):
    ``takes`` takes of 0.6 s at 120 Hz with 1 mm marker noise, commands logged at 20 Hz
    (seed 11: the first takes of a longer series are the same),
    ``import-mocap --commands`` then ``identify`` on the end caps. The identified
    params, the true ones and identify's output."""
    import json

    from tensegrity_env.mjcf import from_mjcf

    xml = (ROBOT.parent / "icosahedron_cables.xml").read_text()
    (tmp_path / "robot.xml").write_text(xml)
    rng = np.random.default_rng(11)
    files, logs = [], []
    for k in range(takes):
        log_t = np.arange(0, 0.6, 0.05)
        log_u = rng.uniform(-0.5, 0.5, (len(log_t), 3))
        time, caps, names = simulate_caps(xml, 120.0, 0.6, rng, commands=(log_t, log_u))
        take = record_take(time, caps, names, rng, noise=1e-3)
        files.append(write_c3d(tmp_path / f"take{k}.c3d", take.points, take.names, 120.0))
        logs += ["--commands", str(write_commands(tmp_path / f"u{k}.csv", log_t, log_u, ["a0", "a1", "a2"]))]
    r = cli("import-mocap", *files, "--robot", tmp_path / "robot.xml", *logs, "-o", tmp_path / "d.h5")
    assert r.returncode == 0, r.stderr
    truth = from_mjcf(tmp_path / "robot.xml").params
    anchor = f"mass[rod0]={float(truth.mass[0])!r}"
    r = cli("identify", tmp_path / "d.h5", "--anchor", anchor, "-o", tmp_path / "p.json")
    assert r.returncode == 0, r.stderr
    return json.loads((tmp_path / "p.json").read_text())["params"], truth, r.stdout


def test_cable_gains_are_identified_from_three_takes(tmp_path: Path) -> None:
    """The fast form of the six-take test below (the steps with cable commands run in
    PyTorch): from the first three of its takes, ``identify`` recovers the three cable
    gains within 2 % (measured: 0.02-0.63 %) and the masses within 4 % (measured: 1.9 %;
    six takes pin them within 1 %)."""
    got, truth, out = _identified_from_takes(tmp_path, 3)
    np.testing.assert_allclose(got["cable_gain"], truth.cable_gain.numpy(), rtol=0.02)
    np.testing.assert_allclose(got["mass"], truth.mass.numpy(), rtol=0.04)
    assert "cable_gain[spring5]" in out


@pytest.mark.slow
def test_cable_gains_are_identified_from_imported_end_caps_and_command_logs(tmp_path: Path) -> None:
    """The measured path of a cable-driven robot: six takes; ``identify`` on the end
    caps recovers the gains within 2 % and the masses within 1 %."""
    got, truth, out = _identified_from_takes(tmp_path, 6)
    np.testing.assert_allclose(got["cable_gain"], truth.cable_gain.numpy(), rtol=0.02)
    np.testing.assert_allclose(got["mass"], truth.mass.numpy(), rtol=0.01)
    assert "cable_gain[spring5]" in out
