"""The README's commands for a pip user: a built wheel, run from outside the checkout.

The wheel is built without its dependencies and unpacked into a folder that is put on
``PYTHONPATH`` of this interpreter (whose environment already has the dependencies), and
the commands run from a temporary working directory: they must find everything they
need (assets, the shipped policy, C sources) in the installed package, not the checkout.
"""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    tmp = tmp_path_factory.mktemp("wheel")
    r = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(tmp / "dist"), str(ROOT)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if r.returncode:
        pytest.skip(f"cannot build a wheel here: {r.stderr.strip().splitlines()[-1:]}")
    (wheel,) = (tmp / "dist").glob("tensegrity_sr-*.whl")
    with zipfile.ZipFile(wheel) as z:
        z.extractall(tmp / "site")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(PYTHONPATH=str(tmp / "site"), MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    (tmp / "work").mkdir()
    return {"env": env, "cwd": str(tmp / "work"), "site": str(tmp / "site")}  # type: ignore[dict-item]


def run(installed: dict, *argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tensegrity_sr.cli", *argv], cwd=installed["cwd"],
                          env=installed["env"], capture_output=True, text=True, check=False)  # fmt: skip


def test_the_package_is_imported_from_the_wheel_not_the_checkout(installed: dict) -> None:
    r = subprocess.run([sys.executable, "-c", "import tensegrity_env, identification; "
                        "print(tensegrity_env.__file__); print(identification.__file__)"],
                       cwd=installed["cwd"], env=installed["env"], capture_output=True, text=True,
                       check=True)  # fmt: skip
    assert all(line.startswith(installed["site"]) for line in r.stdout.split())


def test_readme_commands_work_outside_the_checkout(installed: dict) -> None:
    data = Path(installed["cwd"]) / "data.h5"
    assert run(installed, "generate", "--n-train", "2", "--n-val", "0", "--n-test", "1",
               "--steps", "50", "--no-progress", "-o", str(data)).returncode == 0  # fmt: skip
    assert run(installed, "inspect", str(data)).returncode == 0
    r = run(installed, "identify", str(data), "--anchor", "mass[rod0]=2.0", "-o", "params.json")
    assert r.returncode == 0, r.stderr
    r = run(installed, "transfer", "--pretrained", "ppo", "--episodes", "1", "-o", "transfer")
    assert r.returncode == 0, r.stderr
    assert "IcosahedronMJ-v0" in r.stdout
