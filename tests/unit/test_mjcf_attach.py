"""Springs attached anywhere on a rod: the lab prism with cables on the sphere surfaces
(a cap radius from the end-cap centres) and at motor sites partway along the
neighbouring rod. The end caps stay the points motion capture tracks."""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from test_mjcf_lab import CAP_RADIUS, lab_mjcf, mj_random_state, mj_rod_state

from identification.data.dataset import read_dataset
from identification.data.end_caps import rod_states_from_nodes
from identification.linear.regression import SpringRodIdentifier
from identification.report.tables import group_errors
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.assemblies import node_positions
from tensegrity_env.effects.ground_contact import GroundContact
from tensegrity_env.effects.springs import SlackSprings
from tensegrity_env.engine import Engine
from tensegrity_env.envs.physics import NativeStepper
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import from_mjcf, to_mjcf
from tensegrity_env.topology import Topology
from tensegrity_sr.cli import main

ATTACH = ("surface", "mid")


@pytest.mark.parametrize("attach", ATTACH)
def test_sites_off_the_end_caps_are_attachment_points(attach: str) -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf(attach))
    topo = asm.topology
    assert topo.n_points == (6 if attach == "surface" else 9)
    for rod in topo.rods:  # the end caps are still the sphere centres
        assert rod.length == pytest.approx(1.6, rel=1e-12)
        assert rod.radius == CAP_RADIUS
    # every spring's length in qpos0 is MuJoCo's tendon length
    d = mujoco.MjData(asm.model)
    mujoco.mj_forward(asm.model, d)
    x = node_positions(topo, *(asm_pose(asm, d)))
    nodes = topo.spring_nodes
    lengths = np.linalg.norm(x[nodes[:, 1]] - x[nodes[:, 0]], axis=-1)
    assert np.allclose(lengths, d.ten_length, rtol=0, atol=1e-14)
    if attach == "surface":  # a cap radius from the end-cap centre
        caps = x[: 2 * topo.n_rods]
        points = x[2 * topo.n_rods :]
        gap = np.linalg.norm(points[:, None] - caps[None], axis=-1).min(axis=1)
        assert np.allclose(gap, CAP_RADIUS, atol=1e-12)


def asm_pose(asm, d: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    s = mj_rod_state(asm, d)
    return s.p[0].numpy(), s.q[0].numpy()


@pytest.mark.parametrize("attach", ATTACH)
def test_engine_equals_mujoco_with_springs_anywhere_on_the_rods(attach: str) -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf(attach))
    m, d = mj_random_state(asm, seed=11)
    engine = Engine(asm.topology, dt=m.opt.timestep)
    state = mj_rod_state(asm, d)
    errors = []
    for _ in range(1000):
        mujoco.mj_step(m, d)
        state = engine.step(state, asm.params)
        ref = mj_rod_state(asm, d)
        errors.append(
            max(float((getattr(state, k) - getattr(ref, k)).abs().max()) for k in ("p", "v", "q"))
            + float((state.omega - ref.omega).abs().max())
        )
    print(f"one step {errors[0]:.1e}, 1000 steps {max(errors):.1e}")
    assert errors[0] <= 1e-13
    assert max(errors) <= 1e-10  # round-off, grown over a second of chaotic motion


@pytest.mark.parametrize("attach", ATTACH)
def test_native_kernel_steps_attachment_points_like_the_engine(attach: str) -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf(attach))
    stepper = NativeStepper(asm.topology, asm.params, [], 1e-3, 2, threads=1)
    assert stepper.verify(asm.params, []) <= 1e-13


def test_attachment_points_survive_json_and_mjcf_round_trips() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf("mid"))
    topo = asm.topology
    assert Topology.from_json(topo.to_json()).same_as(topo)
    again = from_mjcf("<again>", xml=to_mjcf(topo, asm.params))
    assert again.topology.same_as(topo, atol=1e-12)
    state = mj_rod_state(asm, mj_random_state(asm, seed=12)[1])
    a = Engine(again.topology).step(state, again.params).v
    b = Engine(topo).step(state, asm.params).v
    assert float((a - b).abs().max()) <= 1e-12


def test_old_topology_json_without_attachments_is_read() -> None:
    topo = from_mjcf("<lab>", xml=lab_mjcf()).topology
    d = topo.to_dict()
    for r in d["rods"]:
        del r["attachments"]
    assert Topology.from_dict(d).same_as(topo)


def test_a_rod_without_two_end_caps_is_refused_with_the_reason() -> None:
    # a second site at r1's lower end-cap centre: which one is tracked?
    twin = lab_mjcf().replace(
        '<site name="r1_s0"', '<site name="r1_twin" pos="{}"/><site name="r1_s0"'
    )
    pos = twin.split('<site name="r1_end0" pos="')[1].split('"')[0]
    with pytest.raises(
        InputError, match=r"cannot tell which of sites 'r1_end0', 'r1_twin'.*motion"
    ):
        from_mjcf("<lab>", xml=twin.replace("{}", pos))
    # r1 keeps one site (the motor site), every cable of r1 ends there
    lines = [
        ln
        for ln in lab_mjcf().splitlines()
        if not ln.startswith(('<site name="r1_end', '<site name="r1_s'))
    ]
    one = (
        "\n".join(lines)
        .replace('site="r1_end0"', 'site="r1_mid"')
        .replace('site="r1_end1"', 'site="r1_mid"')
    )
    with pytest.raises(InputError, match=r"needs two end-cap sites .*motion capture tracks"):
        from_mjcf("<lab>", xml=one)


def test_end_caps_can_be_named() -> None:
    names = [f"r{i}_s{k}" for i in range(3) for k in range(2)]
    asm = from_mjcf("<lab>", xml=lab_mjcf("mid"), end_caps=names)
    # the surface sites are now the tracked points; the centres are unused sites
    assert asm.topology.n_points == 3
    with pytest.raises(InputError, match="does not exist"):
        from_mjcf("<lab>", xml=lab_mjcf(), end_caps=["nope"])


@cache
def _lab_data(tmp: str, attach: str) -> tuple:
    path = Path(tmp) / f"lab_{attach}.xml"
    path.write_text(lab_mjcf(attach))
    spec = GenerateSpec(mjcf=str(path), n_train=4, n_val=0, n_test=1, steps=400, seed=3)
    return generate_dataset(spec)


@pytest.mark.parametrize("attach", ATTACH)
def test_identify_recovers_every_parameter_with_springs_anywhere(
    attach: str, tmp_path_factory: pytest.TempPathFactory
) -> None:
    ds, truth = _lab_data(str(tmp_path_factory.mktemp("lab")), attach)
    assert ds.topology.n_points > 0
    anchor = {"mass[r0]": float(truth.params.mass[0])}
    est = SpringRodIdentifier(anchors=anchor).fit(ds)
    errors = group_errors(est.table_, truth.params)
    assert max(errors.values()) <= 1e-6, errors
    assert est.score(ds, "test")["one_step_position_error"] <= 1e-12
    est_torch = SpringRodIdentifier(anchors=anchor, backend="torch").fit(ds)
    assert torch.allclose(est_torch.params_.stiffness, est.params_.stiffness, rtol=1e-9)


def test_slack_cables_at_attachment_points_match_mujocos_dead_band() -> None:
    xml = lab_mjcf("surface").replace('springlength="', 'springlength="0 ', 3)
    asm = from_mjcf("<lab>", xml=xml)
    assert asm.slack_springs == (0, 1, 2)
    m, d = mj_random_state(asm, seed=13)
    state = mj_rod_state(asm, d)
    mujoco.mj_step(m, d)
    cables = SlackSprings(asm.topology, springs=list(asm.slack_springs))
    with torch.no_grad():
        step = Engine(asm.topology, 1e-3, effects=[cables]).step(state, asm.params)
    assert float((step.v - mj_rod_state(asm, d).v).abs().max()) <= 1e-12


def test_native_kernel_with_floor_contact_and_attachment_points() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf("mid"))
    contact = GroundContact(asm.topology, friction=0.9)
    stepper = NativeStepper(asm.topology, asm.params, [contact], 1e-3, 2, threads=1)
    assert stepper.verify(asm.params, [contact]) <= 1e-13


def test_end_caps_alone_cannot_place_points_off_the_rod_axis() -> None:
    surface = from_mjcf("<lab>", xml=lab_mjcf("surface")).topology
    assert len(surface.off_axis_points()) == 6
    nodes = np.zeros((2, 2 * surface.n_rods, 3))
    nodes[:, 1::2, 2] = 1.0
    with pytest.raises(InputError, match="twist"):
        rod_states_from_nodes(nodes, surface, 1e-3)
    # the motor sites lie on the rod axis: end caps place them; the surface sites do not
    mid = from_mjcf("<lab>", xml=lab_mjcf("mid")).topology
    assert [n.split("/")[1] for n in mid.off_axis_points()] == ["point0", "point1"] * 3


def test_generate_takes_the_end_caps_option(tmp_path: Path, capsys) -> None:
    path = tmp_path / "lab.xml"
    path.write_text(lab_mjcf("mid"))
    out = tmp_path / "d.h5"
    names = ",".join(f"r{i}_s{k}" for i in range(3) for k in range(2))
    args = ["generate", "--mjcf", str(path), "--steps", "5", "--no-progress", "-o", str(out)]
    assert main([*args, "--end-caps", names]) == 0
    # the surface sites are the tracked points: three motor sites remain attachment points
    assert read_dataset(out).topology.n_points == 3
    assert main([*args, "--force", "--end-caps", "r0_s0,nope"]) == 2
    err = capsys.readouterr().err
    assert "end-cap site 'nope' does not exist" in err and "Traceback" not in err


def test_end_caps_survive_coordinates_rounded_as_in_a_hand_written_file() -> None:
    """Surface sites a cap radius beside the end-cap centres, every coordinate rounded to
    5 decimals (axial positions then differ by ~1e-6 m): the centres stay the end caps."""
    exact = lab_mjcf("surface")
    rounded = re.sub(r"-?\d+\.\d{6,}", lambda m: f"{float(m.group()):.5f}", exact)
    assert rounded != exact
    a, b = from_mjcf("<exact>", xml=exact).topology, from_mjcf("<rounded>", xml=rounded).topology
    # a side site taken as an end cap would move it by the cap radius, 17.5 cm
    np.testing.assert_allclose(b.end_offsets, a.end_offsets, atol=1e-5)
    assert np.array_equal(b.spring_nodes, a.spring_nodes)
