"""A trained policy on disk: the SB3 zip, its VecNormalize statistics and its run record.

Three files share a stem::

    model.zip                  SB3 model (policy weights, optimizer, settings)
    model_vecnormalize.pkl     VecNormalize statistics (absent if not normalized)
    model.json                 run record: algo, env id, seed, timesteps, wall time,
                               hyperparameters, the command that trained it

:func:`save_policy` writes each atomically; :func:`load_policy` reads them back as a
:class:`LoadedPolicy`, a plain ``obs -> action`` function whose normalization is
frozen (``training=False``, ``norm_reward=False``), so evaluating never moves the
statistics.
"""

from __future__ import annotations

import json
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from policies.goal_frame import to_goal_frame, to_world_actions
from tensegrity_env.io_utils import InputError, atomic_path, atomic_write_text

#: algorithms by the name used on the command line and in run records
ALGOS: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "sac": SAC}


def stats_path(model_path: str | Path) -> Path:
    """``<stem>_vecnormalize.pkl`` beside ``<stem>.zip``."""
    p = Path(model_path)
    return p.with_name(f"{p.stem}_vecnormalize.pkl")


def record_path(model_path: str | Path) -> Path:
    """``<stem>.json`` beside ``<stem>.zip``."""
    return Path(model_path).with_suffix(".json")


def save_policy(
    model: BaseAlgorithm, vecnorm: VecNormalize | None, path: str | Path, record: dict[str, Any]
) -> Path:
    """Write the model zip, its statistics (if any) and its run record atomically."""
    path = Path(path)
    if vecnorm is not None:
        with atomic_path(stats_path(path)) as tmp:
            vecnorm.save(str(tmp))
    elif stats_path(path).exists():
        stats_path(path).unlink()
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        model.save(f)
    atomic_write_text(record_path(path), json.dumps(record, indent=2) + "\n")
    return path


def read_record(model_path: str | Path) -> dict[str, Any]:
    """The run record beside a model zip ({} if there is none)."""
    p = record_path(model_path)
    if not p.exists():
        return {}
    try:
        return dict(json.loads(p.read_text()))
    except (OSError, ValueError) as e:
        raise InputError(f"{p}: not a readable run record ({type(e).__name__})") from None


def load_vecnormalize(path: str | Path) -> VecNormalize:
    """Statistics saved by :func:`save_policy`, without an env attached."""
    try:
        with open(path, "rb") as f:
            obj = pickle.load(f)
    except OSError as e:
        raise InputError(f"{path}: cannot read normalization statistics ({e.strerror})") from None
    except Exception as e:  # a truncated or foreign pickle raises many types
        raise InputError(
            f"{path}: corrupted normalization statistics ({type(e).__name__})"
        ) from None
    if not isinstance(obj, VecNormalize):
        raise InputError(f"{path}: not VecNormalize statistics")
    return obj


def pretrained_path(algo: str, env_id: str = "IcosahedronSR-v0") -> Path:
    """The policy shipped in the installed package (``policies/pretrained``) for ``algo``.

    Found through :mod:`importlib.resources`, so it works from a wheel install as
    from the source tree. Raises :class:`InputError` if none is shipped.
    """
    from importlib import resources

    folder = resources.files("policies") / "pretrained"
    res = folder / f"{algo}_{env_id}.zip"
    if not res.is_file():
        shipped = sorted(p.name for p in folder.iterdir() if p.name.endswith(".zip"))
        raise InputError(
            f"no shipped {algo} policy for {env_id} (shipped: {', '.join(shipped) or 'none'})"
        )
    return Path(str(res))


def resolve_model_path(path: str | Path) -> Path:
    """A model zip from a zip path or a training folder (``<folder>/model.zip``)."""
    p = Path(path)
    if p.is_dir():
        p = p / "model.zip"
    if not p.exists():
        raise InputError(f"{p}: no such policy file")
    return p


@dataclass
class LoadedPolicy:
    """A trained policy as a deterministic function of raw observations.

    Attributes:
        model: the SB3 algorithm (on the CPU).
        vecnorm: its frozen observation statistics, None if trained without them.
        path: the model zip.
        record: the run record ({} if none was saved).
        goal_frame: the network acts in the goal frame (:mod:`policies.goal_frame`):
            observations are turned into it and actions back into the world frame.
        goal_frame_caps: None for the rolling task's layout; the robot's end caps for a
            generic robot's goal task (:func:`~policies.goal_frame.to_goal_frame`).
    """

    model: BaseAlgorithm
    vecnorm: VecNormalize | None
    path: Path
    record: dict[str, Any] = field(default_factory=dict)
    goal_frame: bool = False
    goal_frame_caps: int | None = None

    def __post_init__(self) -> None:
        if self.vecnorm is not None:
            self.vecnorm.training = False  # frozen: evaluation never updates the statistics
            self.vecnorm.norm_reward = False

    @property
    def algo(self) -> str:
        return next(k for k, v in ALGOS.items() if isinstance(self.model, v))

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        """Observations as the network saw them in training (float32, same shape)."""
        if self.vecnorm is None:
            return np.asarray(obs, dtype=np.float32)
        return np.asarray(self.vecnorm.normalize_obs(np.asarray(obs)), dtype=np.float32)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic action(s) for observation(s) (75,) or (B, 75): (18,) or (B, 18)."""
        caps = self.goal_frame_caps
        seen = to_goal_frame(obs, caps) if self.goal_frame else obs
        action, _ = self.model.predict(self.normalize(seen), deterministic=True)
        if self.goal_frame:
            action = to_world_actions(np.asarray(action), np.asarray(obs), caps)
        return np.asarray(action, dtype=np.float32)


def load_model(path: Path, algo: str | None = None) -> BaseAlgorithm:
    """An SB3 model zip; the algorithm from ``algo`` or tried in turn."""
    candidates = [ALGOS[algo]] if algo in ALGOS else list(ALGOS.values())
    error: Exception | None = None
    for cls in candidates:
        try:
            return cls.load(path, device="cpu")
        except Exception as e:  # SB3 raises many types for a foreign or damaged zip
            error = e
    raise InputError(
        f"{path}: not a Stable-Baselines3 PPO/SAC model ({type(error).__name__})"
    ) from None


def load_policy(path: str | Path) -> LoadedPolicy:
    """The policy in ``path`` (a model zip or a training folder) with its statistics.

    Raises :class:`InputError` naming the file if it is missing or damaged.
    """
    p = resolve_model_path(path)
    record = read_record(p)
    model = load_model(p, record.get("algo"))
    s = stats_path(p)
    vecnorm = load_vecnormalize(s) if s.exists() else None
    if record.get("vecnormalize") and vecnorm is None:
        raise InputError(f"{s}: missing (the run record says the policy was normalized)")
    if vecnorm is not None and vecnorm.observation_space.shape != model.observation_space.shape:
        raise InputError(f"{s}: statistics do not match {p}'s observation space")
    caps = record.get("goal_frame_caps")
    return LoadedPolicy(
        model, vecnorm, p, record, bool(record.get("goal_frame", False)),
        None if caps is None else int(caps),
    )  # fmt: skip
