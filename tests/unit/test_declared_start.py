"""Where a trajectory fit on end caps starts: an NTRT model with tension-only springs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from identification.commands.declared import declared_start, no_other_effects
from identification.data.dataset import Dataset, Split
from tensegrity_env.effects import GroundContact, SlackSprings
from tensegrity_env.io_utils import InputError
from tensegrity_env.ntrt import from_ntrt

PRISM = """
builders:
  rod: {class: tgRodInfo, parameters: {density: 0.5, radius: 0.1}}
  string: {class: tgBasicActuatorInfo, parameters: {stiffness: 100, damping: 3, pretension: 50}}
nodes:
  b1: [-5, 0, 0]
  b2: [5, 0, 0]
  b3: [0, 0, 8.66]
  t1: [-5, 5, 0]
  t2: [5, 5, 0]
  t3: [0, 5, 8.66]
pair_groups:
  rod: [[b1, t2], [b2, t3], [b3, t1]]
  string: [[b1, b2], [b2, b3], [b1, b3], [t1, t2], [t2, t3], [t1, t3], [b1, t1], [b2, t2], [b3, t3]]
"""


def test_an_ntrt_model_starts_the_fit_with_its_floor_rod_mass_and_slack_springs(tmp_path: Path) -> None:
    path = tmp_path / "prism.yaml"
    path.write_text(PRISM)
    robot = from_ntrt(path)
    caps = np.tile(robot.rest_caps, (1, 4, 1, 1))
    data = Dataset(robot.topology, 1 / 120, {"train": Split(nodes=caps, control=np.zeros((1, 3, 3, 3)))})
    anchors: dict[str, float] = {}
    params, contact, others = declared_start(path, data, tmp_path / "take.h5", anchors)
    assert isinstance(contact, GroundContact)
    (slack,) = others  # every NTRT cable is tension-only
    assert isinstance(slack, SlackSprings) and slack.values["springs"].tolist() == list(range(9))
    assert anchors == {f"mass[{robot.topology.rods[0].name}]": pytest.approx(float(robot.params.mass[0]))}
    np.testing.assert_allclose(params.stiffness.numpy(), robot.params.stiffness.numpy())
    with pytest.raises(InputError, match="cannot keep its slack_springs"):
        no_other_effects(path, others, "the trajectory fit off the floor")
