"""Fixtures shared by tests/unit and tests/accuracy.

``mujoco_data`` generates MuJoCo datasets once and keeps them on disk, keyed by the
generator's arguments and a fingerprint of the code that generates them (the sources of
``tensegrity_env`` and ``identification/simulation``, and MuJoCo's version): a second
test asking for the same data, in this run or a later one, reads it back instead of
rolling it out again. The files live in pytest's cache folder (``.pytest_cache``), or in
a temporary folder when the cache is disabled (``-p no:cacheprovider``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pickle
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import torch
from hypothesis import HealthCheck, settings

# Headless rendering: MuJoCo picks its GL backend when first imported, and a test module may
# import mujoco before anything of ours: importing the package sets the default first
# (tensegrity_env.headless.default_mujoco_gl).
import tensegrity_env  # noqa: F401
from identification.data.dataset import Dataset, GroundTruth
from identification.simulation.generate import GenerateSpec, generate_dataset
from identification.simulation.planted import PlantedData, PlantSpec, planted_dataset

# Property-based tests: a few dozen examples locally (random, fast); `HYPOTHESIS_PROFILE=ci`
# derandomizes them so that CI runs the same examples every time.
settings.register_profile(
    "dev", max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile(
    "ci", max_examples=25, deadline=None, derandomize=True, database=None,
    suppress_health_check=[HealthCheck.too_slow],
)  # fmt: skip
settings.register_profile(
    "long", max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)  # a deeper search when changing a reader: HYPOTHESIS_PROFILE=long
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))

ROOT = Path(__file__).resolve().parents[1]
#: the code whose output is cached: a change to any of these files regenerates the data
GENERATOR_SOURCES = ("tensegrity_env", "identification/simulation", "identification/data")


def _fingerprint() -> str:
    """Hash of the generator's sources and MuJoCo's version."""
    import mujoco

    h = hashlib.sha256(mujoco.__version__.encode())
    for folder in GENERATOR_SOURCES:
        for path in sorted((ROOT / folder).rglob("*")):
            if path.suffix in {".py", ".c", ".xml", ".json"} and path.is_file():
                h.update(str(path.relative_to(ROOT)).encode())
                h.update(path.read_bytes())
    return h.hexdigest()[:16]


class MujocoData:
    """Generated datasets, cached in memory and on disk (see the module docstring).

    Args:
        folder: where the pickled datasets are kept.
    """

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.code = _fingerprint()
        self._memory: dict[str, Any] = {}
        for old in folder.glob("*.pkl"):  # data of an older generator: never read again
            if old.name.split("-")[1] != self.code:
                old.unlink(missing_ok=True)

    def _key(self, kind: str, spec: Any) -> str:
        h = hashlib.sha256(f"{kind}|{spec!r}".encode())
        mjcf = getattr(spec, "mjcf", None)
        if mjcf is not None:  # the same path may hold another model in another test
            h.update(Path(mjcf).read_bytes())
        return h.hexdigest()[:24]

    def _get(self, kind: str, spec: Any, make: Any) -> Any:
        key = self._key(kind, spec)
        if key in self._memory:
            return self._memory[key]
        path = self.folder / f"{kind}-{self.code}-{key}.pkl"
        if path.exists():
            value = pickle.loads(path.read_bytes())
        else:
            value = make(spec)
            fd, tmp = tempfile.mkstemp(dir=self.folder, suffix=".part")
            with os.fdopen(fd, "wb") as f:
                pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)  # never a half-written file under the final name
        self._memory[key] = value
        return value

    def generated(self, spec: GenerateSpec) -> tuple[Dataset, GroundTruth]:
        """``generate_dataset(spec)``, generated once."""
        if spec.threads is not None:  # the data does not depend on threads: one key
            spec = dataclasses.replace(spec, threads=None)
        return self._get("generated", spec, generate_dataset)

    def planted(self, spec: PlantSpec) -> PlantedData:
        """``planted_dataset(spec)``, generated once."""
        return self._get("planted", spec, planted_dataset)


def pytest_configure(config: pytest.Config) -> None:
    """One torch thread for every test: the problems are small, and on a busy machine a
    second thread made the engine tests ten times slower, not faster."""
    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def mujoco_data(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> MujocoData:
    """Session-wide cache of generated MuJoCo datasets (see :class:`MujocoData`)."""
    cache = getattr(request.config, "cache", None)
    folder = (
        cache.mkdir("mujoco-data") if cache is not None else tmp_path_factory.mktemp("mujoco-data")
    )
    return MujocoData(Path(folder))


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """Run a test on one torch thread (small float64 problems: threads only add overhead)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture
def one_line_error(capsys: pytest.CaptureFixture[str]) -> Callable[..., str]:
    """``one_line_error(*words)``: the captured stderr is exactly one ``error:`` line
    holding every word, with no traceback; returns that line."""

    def check(*words: str) -> str:
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), err
        assert "Traceback" not in err
        for w in words:
            assert w in lines[0], (w, lines[0])
        return lines[0]

    return check
