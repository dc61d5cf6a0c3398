"""What a ground-truth dataset is generated from: :class:`GenerateSpec` (its presets
and :class:`InitialConditions`), read by :mod:`identification.simulation.truth` and
:mod:`identification.simulation.generate`."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from identification.data.dataset import SPLITS
from identification.defaults import PRESETS
from tensegrity_env import assemblies
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf_checks import check_ignore_names


@dataclass(frozen=True)
class InitialConditions:
    """How initial states are randomized around the nominal pose.

    Attributes:
        rotate: apply a uniformly random rigid rotation to the whole structure
            (ignored for assemblies tied to world anchors).
        position_std: per-rod position perturbation, std per axis [m].
        rotation_std: per-rod rotation perturbation about a random axis, std [rad].
        speed: range of each rod's linear speed, random direction [m/s].
        tumble: range of each rod's angular speed perpendicular to its axis [rad/s].
        spin: maximum spin about each rod's own axis, uniform in ``[-spin, spin]`` [rad/s].
        lift: with a floor, range of the lowest rod surface's initial height [m].
    """

    rotate: bool = True
    position_std: float = 0.02
    rotation_std: float = 0.05
    speed: tuple[float, float] = (0.3, 1.0)
    tumble: tuple[float, float] = (1.0, 3.0)
    spin: float = 2.0
    lift: tuple[float, float] = (0.02, 0.3)


@dataclass(frozen=True)
class GenerateSpec:
    """What to generate. Build from a preset with :meth:`preset`.

    Attributes:
        assembly: built-in assembly, ``"icosahedron"`` or ``"element"``.
        mjcf: a user MJCF file instead of a built-in assembly (see
            :func:`tensegrity_env.mjcf.from_mjcf` for the conventions it must follow).
        n_train, n_val, n_test: trajectories per split (val/test may be 0: omitted).
        steps: transitions per trajectory T (T + 1 samples).
        seed: seed of every random draw.
        ground: add a floor at z = 0 and lift the structure above it.
        control_std: std of the random control commands f_u per rod and axis
            [command units]; 0 gives no control.
        control_hold: how long each random command is held [s].
        preset: the preset name recorded in the file (``"custom"`` if none).
        initial: initial-condition randomization.
        threads: MuJoCo rollout threads (None: all CPU cores).
        chunk: trajectories per rollout call (None: automatic).
        ignore: MJCF features the model leaves out that the user accepts anyway
            (names of :data:`tensegrity_env.defaults.FEATURES`; warned about).
        end_caps: the end-cap sites of ``mjcf``, two per rod (empty: by convention).
    """

    assembly: str = "icosahedron"
    mjcf: str | None = None
    n_train: int = 16
    n_val: int = 4
    n_test: int = 4
    steps: int = 300
    seed: int = 0
    ground: bool = False
    control_std: float = 0.0
    control_hold: float = 0.05
    preset: str = "custom"
    initial: InitialConditions = field(default_factory=InitialConditions)
    threads: int | None = None
    chunk: int | None = None
    ignore: tuple[str, ...] = ()
    end_caps: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "ignore", tuple(self.ignore))
        object.__setattr__(self, "end_caps", tuple(self.end_caps))
        if self.end_caps and self.mjcf is None:
            raise InputError("--end-caps: names sites of an MJCF file; pass --mjcf")
        check_ignore_names(self.ignore)
        if self.mjcf is None and self.assembly not in assemblies.ASSEMBLIES:
            raise InputError(
                f"--assembly: unknown assembly '{self.assembly}' "
                f"(choose from {sorted(assemblies.ASSEMBLIES)})"
            )
        if self.n_train < 1:
            raise InputError(f"--n-train: need at least 1 training trajectory, got {self.n_train}")
        for name in ("n_val", "n_test"):
            if getattr(self, name) < 0:
                raise InputError(f"--{name.replace('_', '-')}: must be >= 0")
        if self.steps < 1:
            raise InputError(f"--steps: need at least 1 step, got {self.steps}")
        if not np.isfinite(self.control_std) or self.control_std < 0:
            raise InputError(f"--control-std: must be >= 0, got {self.control_std}")
        if not self.control_hold > 0:
            raise InputError(f"control_hold: must be positive, got {self.control_hold}")
        if self.threads is not None and self.threads < 1:
            raise InputError(f"--threads: must be >= 1, got {self.threads}")
        if self.seed < 0:
            raise InputError(f"--seed: must be >= 0, got {self.seed}")

    @classmethod
    def from_preset(cls, name: str, **overrides: Any) -> GenerateSpec:
        """The preset ``name`` with ``overrides`` (None values are ignored)."""
        if name not in PRESETS:
            raise InputError(f"--preset: unknown preset '{name}' (choose from {sorted(PRESETS)})")
        kw: dict[str, Any] = {**PRESETS[name], "preset": name}
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**kw)

    @property
    def counts(self) -> dict[str, int]:
        """Trajectories per non-empty split."""
        n = {"train": self.n_train, "val": self.n_val, "test": self.n_test}
        return {s: n[s] for s in SPLITS if n[s] > 0}

    @property
    def source_name(self) -> str:
        return str(self.mjcf) if self.mjcf is not None else self.assembly

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d.pop("threads")  # how fast, not what: keep files identical across machines
        d.pop("chunk")
        return d
