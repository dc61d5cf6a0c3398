"""NTRT YAML robot models read into rods, cables and nominal parameters."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tensegrity_env.effects import GroundContact, SlackSprings
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model
from tensegrity_env.ntrt import from_ntrt
from tensegrity_env.rotations import TO_Z_UP, axis_angle_to_quat, np_quat_to_matrix

#: NTRT's documented 3-prism, in decimetres, y up, with an extension on one rod and a
#: motor-driven cable
PRISM = """
builders:
  rod:
    class: tgRodInfo
    parameters: {density: 0.5, radius: 0.1, friction: 0.8}
  ext:
    class: tgRodInfo
    parameters: {density: 0.001, radius: 0.05}
  string:
    class: tgBasicActuatorInfo
    parameters: {stiffness: 100, damping: 3, pretension: 50}
  activated_cable:
    class: tgBasicActuatorInfo
    parameters: {stiffness: 2000, damping: 1, pretension: 0}
nodes:
  bottom1: [-5, 0, 0]
  bottom2: [5, 0, 0]
  bottom3: [0, 0, 8.66]
  top1: [-5, 5, 0]
  top2: [5, 5, 0]
  top3: [0, 5, 8.66]
  tip ext1: [-5.894427, -0.447214, 0]
pair_groups:
  rod:
    - [bottom1, top2]
    - [bottom2, top3]
    - [bottom3, top1]
  ext:
    - [bottom1, ext1]
  string:
    - [bottom1, bottom2]
    - [bottom2, bottom3]
    - [bottom1, bottom3]
    - [top1, top2]
    - [top2, top3]
    - [top1, top3]
    - [bottom1, top1]
    - [bottom2, top2]
  activated_cable c1:
    - [bottom3, top3]
"""

PARENT = """
substructures:
  prism:
    path: ./prism.yaml
    rotation: {axis: [0, 1, 0], angle: 90}
    translation: [0, 2, 0]
builders:
  string:
    class: tgBasicActuatorInfo
    parameters: {stiffness: 150, damping: 3, pretension: 50}
"""

DM = 0.1  # metres per decimetre


@pytest.fixture()
def files(tmp_path: Path) -> tuple[Path, Path]:
    (tmp_path / "prism.yaml").write_text(PRISM)
    (tmp_path / "robot.yaml").write_text(PARENT)
    return tmp_path / "prism.yaml", tmp_path / "robot.yaml"


def nodes_dm() -> dict[str, np.ndarray]:
    return {"bottom1": np.array([-5.0, 0, 0]), "bottom2": np.array([5.0, 0, 0]),
            "bottom3": np.array([0, 0, 8.66]), "top1": np.array([-5.0, 5, 0]),
            "top2": np.array([5.0, 5, 0]), "top3": np.array([0, 5, 8.66]),
            "ext1": np.array([-5.894427, -0.447214, 0])}  # fmt: skip


def test_rods_cables_and_nominal_parameters_in_si(files: tuple[Path, Path]) -> None:
    robot = from_ntrt(files[0])
    topo, p = robot.topology, robot.params.numpy()
    assert topo.n_rods == 3 and topo.n_springs == 9 and topo.cable_actuators == (8,)
    n = nodes_dm()
    ends = [("bottom1", "top2"), ("bottom2", "top3"), ("bottom3", "top1")]
    lengths = np.array([np.linalg.norm(n[b] - n[a]) for a, b in ends]) * DM  # [m]
    rod_mass = 0.5e3 * np.pi * (0.1 * DM) ** 2 * lengths  # kg/dm^3 -> kg/m^3, dm -> m
    ext_len = np.linalg.norm(n["ext1"] - n["bottom1"]) * DM
    ext_mass = 1.0 * np.pi * (0.05 * DM) ** 2 * ext_len
    np.testing.assert_allclose(p["mass"], rod_mass + np.array([ext_mass, 0, 0]), rtol=1e-12)
    # a plain rod: a solid cylinder's principal inertia
    r, m, length = 0.1 * DM, rod_mass[1], lengths[1]
    np.testing.assert_allclose(p["inertia"][1], [m * r**2 / 2, *[m * (3 * r**2 + length**2) / 12] * 2], rtol=1e-9)
    assert topo.rods[1].axial_gyration == pytest.approx(r**2 / 2, rel=1e-9)  # the moment fits hold
    # the extension (collinear, on bottom1's side) moves the centre of mass and adds inertia
    assert p["inertia"][0][1] > p["inertia"][1][1]
    # end caps are the heaviest rod's nodes, the extension tip is not one of them
    assert [rod.length for rod in topo.rods] == pytest.approx(lengths, rel=1e-12)
    # cables: rest length = built length - pretension / stiffness (both in NTRT units)
    edge = 10.0 * DM
    np.testing.assert_allclose(p["rest_length"][0], edge - 50 / 100 * DM, rtol=1e-12)
    np.testing.assert_allclose(p["stiffness"], [100.0] * 8 + [2000.0])
    np.testing.assert_allclose(p["damping"], [3.0] * 8 + [1.0])
    np.testing.assert_allclose(p["rest_length"][8], 5.0 * DM, rtol=1e-12)  # no pretension
    np.testing.assert_allclose(p["gravity"], [0.0, 0.0, -9.81])
    # rest pose: y-up model turned z-up, in metres
    caps = robot.rest_caps
    np.testing.assert_allclose(caps[0], TO_Z_UP["y"] @ n["bottom1"] * DM, atol=1e-12)
    np.testing.assert_allclose(caps[1], TO_Z_UP["y"] @ n["top2"] * DM, atol=1e-12)
    assert caps[:, 2].min() == pytest.approx(0.0) and caps[:, 2].max() == pytest.approx(0.5)


def test_a_substructure_is_rotated_about_its_centroid_then_translated(files: tuple[Path, Path]) -> None:
    robot = from_ntrt(files[1])
    n = nodes_dm()
    pts = np.array([n[k] for k in ("bottom1", "bottom2", "bottom3", "top1", "top2", "top3", "ext1")])
    rot = np_quat_to_matrix(axis_angle_to_quat(np.array([0.0, 1, 0]), np.pi / 2))
    placed = (pts - pts.mean(0)) @ rot.T + pts.mean(0) + [0, 2, 0]
    np.testing.assert_allclose(robot.rest_caps[0], TO_Z_UP["y"] @ placed[0] * DM, atol=1e-12)
    np.testing.assert_allclose(robot.rest_caps[4], TO_Z_UP["y"] @ placed[2] * DM, atol=1e-12)  # bottom3
    # the parent's builder replaces the child's of the same key
    np.testing.assert_allclose(robot.params.numpy()["stiffness"], [150.0] * 8 + [2000.0])


def test_declared_model_has_a_floor_and_tension_only_cables(files: tuple[Path, Path]) -> None:
    model = Model.read(files[1])
    assert model.violation() == ""
    kinds = {type(e) for e in model.effects}
    assert kinds == {GroundContact, SlackSprings}
    slack = next(e for e in model.effects if isinstance(e, SlackSprings))
    assert sorted(slack.values["springs"].tolist()) == list(range(9))
    contact = next(e for e in model.effects if isinstance(e, GroundContact))
    assert float(contact.values["friction"]) == pytest.approx(0.8)


@pytest.mark.parametrize(
    "edit, message",
    [
        (("    - [bottom3, top1]\n", "    - [bottom3, nowhere]\n"), "no node 'nowhere'"),
        (("class: tgRodInfo\n    parameters: {density: 0.5, radius: 0.1, friction: 0.8}",
          "class: tgBoxInfo\n    parameters: {density: 0.5}"), "class 'tgBoxInfo' is not read"),
        (("{stiffness: 100, damping: 3, pretension: 50}", "{stiffness: 100, damping: 3, pretension: 5000}"),
         "rest length"),
        (("  bottom2: [5, 0, 0]", "  bottom2: [5, zero, 0]"), "is not three"),
    ],
)  # fmt: skip
def test_bad_models_are_one_line_errors_naming_the_file(tmp_path: Path, edit: tuple[str, str], message: str) -> None:
    bad = PRISM.replace(*edit)
    assert bad != PRISM
    (tmp_path / "bad.yaml").write_text(bad)
    with pytest.raises(InputError) as e:
        from_ntrt(tmp_path / "bad.yaml")
    text = str(e.value)
    assert "bad.yaml" in text and message in text and "\n" not in text


def test_the_rest_pose_is_rebuilt_from_each_rods_principal_frame(files: tuple[Path, Path]) -> None:
    """End caps placed by each rod's rest pose (centre of mass, principal frame as a
    unit quaternion) land on the model's nodes: the frames are rotations, not
    reflections, and the offsets are consistent with them."""
    from tensegrity_env.assemblies import node_positions

    robot = from_ntrt(files[1])
    np.testing.assert_allclose(np.linalg.norm(robot.rest_q, axis=-1), 1.0, atol=1e-12)
    nodes = node_positions(robot.topology, robot.rest_p, robot.rest_q)
    np.testing.assert_allclose(nodes[: 2 * robot.topology.n_rods], robot.rest_caps, atol=1e-12)


def test_a_sphere_on_an_end_cap_is_that_caps_contact_radius(tmp_path: Path) -> None:
    from tensegrity_env.ntrt import EXAMPLE_PRISM

    text = EXAMPLE_PRISM.replace(
        "nodes:\n  bottom1:", "  ball: {class: tgSphereInfo, parameters: {density: 0.1, radius: 0.3}}\nnodes:\n  bottom1 ball:"
    ).replace("[bottom1, top2]", "[ball, top2]").replace("[bottom1, bottom2]", "[ball, bottom2]")
    text = text.replace("[bottom1, bottom3]", "[ball, bottom3]").replace("[bottom1, top1]", "[ball, top1]")
    path = tmp_path / "prism.yaml"
    path.write_text(text)
    topo = from_ntrt(path).topology
    # 0.3 dm sphere at one end of the first rod; every other cap keeps the rod's 0.1 dm
    radii = np.full((3, 2), 0.01)
    radii[0, 0] = 0.03
    assert np.allclose(topo.cap_radii, radii, rtol=1e-12)
    contact = Model.read(path).effects[0]
    assert isinstance(contact, GroundContact)
    assert np.allclose(contact.radius.numpy(), radii, rtol=1e-12)
