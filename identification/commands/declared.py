"""The declared model a command starts from: one option name, ``--params``, in every
command, and one way to read it against the dataset."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from tensegrity_env.io_utils import InputError

if TYPE_CHECKING:  # imported where used: --help imports no torch, MuJoCo or SciPy
    from identification.data.dataset import Dataset
    from tensegrity_env.effects import GroundContact
    from tensegrity_env.effects.base import PhysicalEffect
    from tensegrity_env.model import Model
    from tensegrity_env.params import Params


def add_params_option(parser: argparse.ArgumentParser, help: str) -> None:
    """``--params FILE`` (a params.json or the robot's MJCF); ``--init``, its former name
    in ``identify``, is still read and not shown."""
    parser.add_argument("--params", type=Path, help=help)
    parser.add_argument("--init", type=Path, dest="params", help=argparse.SUPPRESS)


def declared_model(path: Path, dataset: Dataset, source: Path) -> Model:
    """The model in ``path`` (:meth:`~tensegrity_env.model.Model.read`), at the dataset's
    sample interval; raises :class:`InputError` if its topology is not the dataset's
    (``source``: the dataset's file, for the message)."""
    from tensegrity_env.model import Model

    model = Model.read(path, dt=dataset.dt)
    if not model.topology.same_as(dataset.topology):
        raise InputError(f"{path}: topology differs from {source}")
    return model


def declared_start(
    path: Path, dataset: Dataset, source: Path, anchors: dict[str, float]
) -> tuple[Params, GroundContact | None, list[PhysicalEffect]]:
    """Where a trajectory fit on end caps starts from the model in ``path``: its
    parameters, its floor contact (None: none) and its other effects (an NTRT model's
    tension-only springs), which a fit on the floor keeps as declared. Its first rod's
    mass fixes the scale unless ``anchors`` (updated in place) already does; a model with
    two floors is refused."""
    from tensegrity_env.effects import GroundContact

    model = declared_model(path, dataset, source)
    anchors.setdefault(f"mass[{model.topology.rods[0].name}]", float(model.params.mass[0]))
    # narrowing to the class: the floor fits run its contact law (search, touchdowns)
    floors = [e for e in model.effects if isinstance(e, GroundContact)]
    if len(floors) > 1:
        raise InputError(f"{path}: a trajectory fit starts from the declared model and at "
                         "most one ground_contact (remove the others from its 'effects')")  # fmt: skip
    others = [e for e in model.effects if all(e is not f for f in floors)]
    return model.params, floors[0] if floors else None, others


def no_other_effects(path: Path, others: list[PhysicalEffect], what: str) -> None:
    """Refuse in one line a declared model whose effects besides a floor (``others``)
    ``what`` (a fit that starts from the declared model and a floor only) cannot keep."""
    if others:
        raise InputError(f"{path}: {what} starts from the declared model and at most one "
                         f"ground_contact; it cannot keep its {', '.join(e.name for e in others)} "
                         "(remove them from its 'effects')")  # fmt: skip
