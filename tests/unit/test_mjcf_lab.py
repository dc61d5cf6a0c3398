"""MJCF the way labs write it: composite rods, body frames away from the centre of mass.

The model is a 3-bar prism. Each rod is one body with a free joint built from five
geoms (a thin cylinder, two sphere end caps, two motor cylinders of different
masses, so the centre of mass is off the middle); every body frame sits at the world
origin, two of them rotated, about a metre from the rod's centre of mass.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from identification.linear.regression import SpringRodIdentifier
from identification.report.tables import group_errors
from identification.simulation.generate import GenerateSpec, generate_dataset
from tensegrity_env.effects.ground_contact import GroundContact
from tensegrity_env.effects.springs import SlackSprings
from tensegrity_env.engine import Engine, State
from tensegrity_env.envs.physics import NativeStepper
from tensegrity_env.io_utils import InputError
from tensegrity_env.mjcf import from_mjcf, to_mjcf
from tensegrity_env.mjcf_checks import IgnoredFeatureWarning
from tensegrity_env.mujoco_state import mj_to_rod_state
from tensegrity_env.rotations import np_quat_to_matrix
from tensegrity_env.topology import Topology
from tensegrity_sr.cli import main

CAP_RADIUS = 0.175  # sphere end caps [m]
ROD_RADIUS = 0.016  # the thin tube between them [m]
#: body orientations (w, x, y, z, normalised below): identity and two arbitrary rotations
BODY_QUATS = ((1.0, 0.0, 0.0, 0.0), (0.9, 0.2, -0.3, 0.25), (0.3, 0.8, 0.1, -0.5))


def _v(x: np.ndarray | list[float]) -> str:
    return " ".join(repr(float(a)) for a in np.ravel(x))


def prism_ends(length: float = 1.6, ring: float = 0.55, z0: float = 0.3) -> list[np.ndarray]:
    """World end-cap centres of a twisted 3-bar prism, each (2, 3) [m]."""
    out = []
    for i in range(3):
        a0 = 2 * np.pi * i / 3
        a1 = a0 + 5 * np.pi / 6
        b = np.array([ring * np.cos(a0), ring * np.sin(a0), z0])
        t = np.array([ring * np.cos(a1), ring * np.sin(a1), 0.0])
        t[2] = z0 + np.sqrt(length**2 - np.sum((t[:2] - b[:2]) ** 2))
        out.append(np.stack([b, t]))
    return out


def lab_mjcf(
    attach: str = "centre",
    floor: bool = False,
    friction: float = 0.9,
    extra: str = "",
    rest_fraction: float = 0.9,
    floor_attrs: str = "",
) -> str:
    """MJCF text of the lab-style 3-bar prism.

    Args:
        attach: where cables attach: ``"centre"`` (the end-cap centres), ``"surface"``
            (sites on the sphere surfaces, a cap radius from the centres) or ``"mid"``
            (the vertical cables end at a site 60 % along the neighbouring rod).
        floor: a plane at z = 0; every geom has sliding friction ``friction``.
        floor_attrs: more attributes of the floor geom (``solref``, ``condim``, ...).
        extra: MJCF appended inside ``<mujoco>`` (actuators, equality constraints, ...).
        rest_fraction: every cable's rest length as a fraction of its length in qpos0.
    """
    parts = ['<mujoco model="lab3bar">', '<option timestep="0.001" integrator="Euler"/>']
    if floor:
        parts.append(f'<default><geom friction="{friction} 0.005 0.0001"/></default>')
    parts.append("<worldbody>")
    if floor:
        parts.append(
            f'<geom name="floor" type="plane" size="0 0 1" contype="1" conaffinity="2"'
            f" {floor_attrs}/>"
        )
    for i, (b, t) in enumerate(prism_ends()):
        quat = np.asarray(BODY_QUATS[i]) / np.linalg.norm(BODY_QUATS[i])
        rot = np_quat_to_matrix(quat)

        def loc(x: np.ndarray, rot: np.ndarray = rot) -> str:
            return _v(rot.T @ x)  # world point -> body frame (body at the origin)

        axis = (t - b) / np.linalg.norm(t - b)
        side = np.cross(axis, [0.0, 0.0, 1.0])
        side /= np.linalg.norm(side)
        col = 'contype="2" conaffinity="1"'  # rods meet the floor, never each other
        parts += [
            f'<body name="r{i}" pos="0 0 0" quat="{_v(quat)}"><freejoint name="r{i}"/>',
            f'<geom name="r{i}_tube" type="cylinder" size="{ROD_RADIUS}" fromto="{loc(b)} {loc(t)}"'
            f' mass="0.6" {col}/>',
            f'<geom name="r{i}_cap0" type="sphere" size="{CAP_RADIUS}" pos="{loc(b)}"'
            f' mass="0.35" {col}/>',
            f'<geom name="r{i}_cap1" type="sphere" size="{CAP_RADIUS}" pos="{loc(t)}"'
            f' mass="0.3" {col}/>',
            f'<geom name="r{i}_motor0" type="cylinder" size="0.045"'
            f' fromto="{loc(b + 0.22 * axis)} {loc(b + 0.40 * axis)}" mass="0.5" {col}/>',
            f'<geom name="r{i}_motor1" type="cylinder" size="0.045"'
            f' fromto="{loc(t - 0.45 * axis)} {loc(t - 0.28 * axis)}" mass="0.42" {col}/>',
            f'<site name="r{i}_end0" pos="{loc(b)}"/>',
            f'<site name="r{i}_end1" pos="{loc(t)}"/>',
            f'<site name="r{i}_s0" pos="{loc(b + CAP_RADIUS * side)}"/>',
            f'<site name="r{i}_s1" pos="{loc(t - CAP_RADIUS * side)}"/>',
            f'<site name="r{i}_mid" pos="{loc(b + 0.6 * (t - b))}"/>',
            "</body>",
        ]
    parts.append("</worldbody>")
    a0, a1 = ("end0", "end1") if attach == "centre" else ("s0", "s1")
    cables = []
    for i in range(3):
        j = (i + 1) % 3
        cables += [
            (f"r{i}_{a0}", f"r{j}_{a0}"),
            (f"r{i}_{a1}", f"r{j}_{a1}"),
            (f"r{i}_{a0}", f"r{j}_mid" if attach == "mid" else f"r{j}_{a1}"),
        ]
    rng = np.random.default_rng(0)
    stiffness = 300.0 + 100.0 * rng.random(len(cables))
    damping = 2.0 + rng.random(len(cables))

    def tendons(rest: np.ndarray) -> str:
        return (
            "<tendon>"
            + "".join(
                f'<spatial name="c{k}" stiffness="{float(stiffness[k])!r}" damping="{float(damping[k])!r}"'
                f' springlength="{float(rest[k])!r}"><site site="{sa}"/><site site="{sb}"/></spatial>'
                for k, (sa, sb) in enumerate(cables)
            )
            + "</tendon>"
        )

    body = "\n".join(parts)
    probe = mujoco.MjModel.from_xml_string(f"{body}{tendons(np.ones(len(cables)))}</mujoco>")
    d = mujoco.MjData(probe)
    mujoco.mj_forward(probe, d)
    return f"{body}\n{tendons(rest_fraction * d.ten_length)}\n{extra}</mujoco>"


def mj_random_state(asm, seed: int) -> tuple[mujoco.MjModel, mujoco.MjData]:
    m = asm.model
    d = mujoco.MjData(m)
    d.qvel[:] = np.random.default_rng(seed).normal(size=m.nv)
    return m, d


def mj_rod_state(asm, d: mujoco.MjData) -> State:
    s = mj_to_rod_state(asm, d.qpos.copy(), d.qvel.copy())
    return State.from_numpy(*(s[k][None] for k in ("p", "v", "q", "omega")))


# ---------------------------------------------------------------------- rods as MuJoCo builds them
def test_rods_are_read_from_the_compiled_bodies() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf())
    m = asm.model
    for r, rod in enumerate(asm.topology.rods):
        b = asm.rod_bodies[r]
        assert float(asm.params.mass[r]) == pytest.approx(0.6 + 0.35 + 0.3 + 0.5 + 0.42, rel=1e-12)
        assert np.allclose(asm.params.inertia[r].numpy(), m.body_inertia[b], rtol=0, atol=0)
        # the contact radius is the sphere at the end-cap site, not the first geom (the tube)
        assert rod.radius == CAP_RADIUS
        # the body frame sits at the world origin, a metre away from the centre of mass
        assert np.linalg.norm(rod.frame_origin) == pytest.approx(np.linalg.norm(m.body_ipos[b]))
        assert np.linalg.norm(rod.frame_origin) > 0.8
        assert rod.length == pytest.approx(1.6, rel=1e-12)


def test_end_cap_radius_is_the_capsule_or_cylinder_ending_at_the_site() -> None:
    xml = lab_mjcf().replace('type="sphere" size="0.175"', 'type="sphere" size="0.01"')
    asm = from_mjcf("<lab>", xml=xml)
    # the motor cylinders do not end at an end cap; the tube does (and is larger than 0.01)
    assert [r.radius for r in asm.topology.rods] == [ROD_RADIUS] * 3


def test_engine_equals_mujoco_with_body_frames_off_the_centre_of_mass() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf())
    m, d = mj_random_state(asm, seed=1)
    engine = Engine(asm.topology, dt=m.opt.timestep)
    state = mj_rod_state(asm, d)
    errors = []
    for _ in range(1000):
        mujoco.mj_step(m, d)
        state = engine.step(state, asm.params)
        ref = mj_rod_state(asm, d)
        errors.append(
            max(float((getattr(state, k) - getattr(ref, k)).abs().max()) for k in "pvq")
            + float((state.omega - ref.omega).abs().max())
        )
    assert errors[0] <= 5e-15
    assert max(errors) <= 1e-11


def test_native_kernel_integrates_off_centre_body_frames_like_the_engine() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf())
    contact = GroundContact(asm.topology, friction=0.9)
    stepper = NativeStepper(asm.topology, asm.params, [contact], 1e-3, 2, threads=1)
    assert stepper.verify(asm.params, [contact]) <= 1e-13


def test_frame_origin_survives_json_and_mjcf_round_trips() -> None:
    asm = from_mjcf("<lab>", xml=lab_mjcf())
    topo = asm.topology
    assert Topology.from_json(topo.to_json()).same_as(topo)
    again = from_mjcf("<again>", xml=to_mjcf(topo, asm.params))
    assert np.allclose(again.topology.frame_origins, topo.frame_origins, atol=1e-12)
    assert np.allclose(again.topology.end_offsets, topo.end_offsets, atol=1e-12)
    # the written model steps the same as the lab's own file
    data = mj_random_state(asm, seed=2)[1]
    state = mj_rod_state(asm, data)
    engine = Engine(again.topology, dt=1e-3)
    assert (
        float(
            (engine.step(state, again.params).p - Engine(topo).step(state, asm.params).p)
            .abs()
            .max()
        )
        <= 1e-14
    )


@cache
def _lab_data(tmp: str, attach: str = "centre") -> tuple:
    path = Path(tmp) / f"lab_{attach}.xml"
    path.write_text(lab_mjcf(attach))
    spec = GenerateSpec(mjcf=str(path), n_train=4, n_val=0, n_test=1, steps=400, seed=3)
    return generate_dataset(spec)


def test_identify_recovers_every_parameter_with_off_centre_body_frames(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    ds, truth = _lab_data(str(tmp_path_factory.mktemp("lab")))
    est = SpringRodIdentifier(anchors={"mass[r0]": float(truth.params.mass[0])}).fit(ds)
    errors = group_errors(est.table_, truth.params)
    assert max(errors.values()) <= 1e-6, errors
    assert est.score(ds, "test")["one_step_position_error"] <= 1e-12
    # the native normal equations and the PyTorch design agree
    est_torch = SpringRodIdentifier(
        anchors={"mass[r0]": float(truth.params.mass[0])}, backend="torch"
    ).fit(ds)
    assert torch.allclose(est_torch.params_.stiffness, est.params_.stiffness, rtol=1e-9)


# ---------------------------------------------------------------------- what the file says
def test_floor_contact_is_read_from_the_file_and_reproduces_mujoco() -> None:
    xml = lab_mjcf(floor=True, friction=0.9, floor_attrs='solref="-5000 -50"')
    asm = from_mjcf("<lab>", xml=xml)
    dmax = 0.95  # MuJoCo's default solimp
    assert asm.options.ground and asm.options.friction == 0.9
    assert asm.contact["friction"] == 0.9
    assert asm.contact["stiffness"] == pytest.approx(5000 / dmax**2, rel=1e-12)
    assert asm.contact["damping"] == pytest.approx(50 / dmax, rel=1e-12)
    # lower the prism so its three bottom end caps sink 5 mm into the floor
    m, d = mj_random_state(asm, seed=5)
    d.qvel[:] *= 0.1
    for r in range(3):
        d.qpos[asm.rod_qpos[r] + 2] -= 0.3 - CAP_RADIUS + 0.005
    state = mj_rod_state(asm, d)
    mujoco.mj_step(m, d)
    contact = GroundContact(asm.topology, height=0.0, **asm.contact)
    with torch.no_grad():
        bare = Engine(asm.topology, 1e-3).step(state, asm.params)
        full = Engine(asm.topology, 1e-3, effects=[contact]).step(state, asm.params)
    ref = mj_rod_state(asm, d)
    assert float((bare.v - ref.v).abs().max()) > 1e-3  # the floor pushes
    assert float((full.v - ref.v).abs().max()) <= 1e-9  # MuJoCo's solver tolerance


def test_ground_truth_records_the_files_friction_and_contact(tmp_path: Path) -> None:
    path = tmp_path / "lab.xml"
    path.write_text(lab_mjcf(floor=True, friction=0.7, floor_attrs='solref="0.01 0.8"'))
    _, truth = generate_dataset(GenerateSpec(mjcf=str(path), n_train=1, n_val=0, n_test=0,
                                             steps=5))  # fmt: skip
    (contact,) = truth.effects
    assert contact["name"] == "ground_contact"
    assert contact["params"]["friction"] == 0.7
    # the rods keep solref 0.02 1: MuJoCo mixes the pair half and half (solmix 1 each)
    tc, zeta = 0.5 * (0.01 + 0.02), 0.5 * (0.8 + 1.0)
    assert contact["params"]["stiffness"] == pytest.approx(1 / (0.95**2 * tc**2 * zeta**2))
    assert contact["params"]["damping"] == pytest.approx(2 / (0.95 * tc))
    assert truth.sim["friction"] == 0.7


@pytest.mark.parametrize(
    ("feature", "change"),
    [
        ("condim", lambda x: lab_mjcf(floor=True, floor_attrs='condim="6"')),
        ("cone", lambda x: x.replace("<option ", '<option cone="elliptic" ')),
        ("rod-collisions", lambda x: x.replace('contype="2" conaffinity="1"',
                                                'contype="3" conaffinity="3"')),
        ("equality", lambda x: x.replace("</mujoco>",
                                         '<equality><weld body1="r0" body2="r1"/></equality>'
                                         "</mujoco>")),
        ("tendon-limits", lambda x: x.replace('<spatial name="c0"',
                                              '<spatial name="c0" range="0 2"')),
        ("integrator", lambda x: x.replace('integrator="Euler"', 'integrator="RK4"')),
        ("joint-dynamics", lambda x: x.replace('<freejoint name="r1"/>',
                                               '<joint name="r1" type="free" damping="0.1"/>')),
        ("actuators", lambda x: x.replace("</mujoco>",
                                          '<actuator><motor joint="r0" gear="0 0 1 0 0 0"/>'
                                          "</actuator></mujoco>")),
    ],
)  # fmt: skip
def test_unmodelled_features_are_refused_by_name_unless_ignored(feature: str, change) -> None:
    xml = change(lab_mjcf(floor=feature == "cone"))
    with pytest.raises(InputError, match=f"--ignore {feature}"):
        from_mjcf("<lab>", xml=xml)
    with pytest.warns(IgnoredFeatureWarning, match="ignoring"):
        asm = from_mjcf("<lab>", xml=xml, ignore=[feature])
    assert asm.topology.n_rods == 3


def test_dead_band_springs_are_tension_only_cables() -> None:
    xml = lab_mjcf()
    xml = xml.replace('springlength="', 'springlength="0 ', 2)  # c0 and c1 become cables
    asm = from_mjcf("<lab>", xml=xml)
    plain = from_mjcf("<lab>", xml=lab_mjcf())
    assert asm.slack_springs == (0, 1)
    assert torch.equal(asm.params.rest_length, plain.params.rest_length)
    # slack cables (shorter than rest) push nothing, as MuJoCo's dead band
    m, d = mj_random_state(asm, seed=6)
    state = mj_rod_state(asm, d)
    lengths = d.ten_length.copy()
    mujoco.mj_forward(m, d)
    assert np.all(d.ten_length[:2] < asm.params.rest_length.numpy()[:2] / 0.9 + 1)  # sanity
    mujoco.mj_step(m, d)
    cables = SlackSprings(asm.topology, springs=list(asm.slack_springs))
    with torch.no_grad():
        step = Engine(asm.topology, 1e-3, effects=[cables]).step(state, asm.params)
    assert float((step.v - mj_rod_state(asm, d).v).abs().max()) <= 1e-12
    assert lengths.shape == (9,)


def test_generate_refuses_with_one_line_and_accepts_with_ignore(tmp_path: Path, capsys) -> None:
    path = tmp_path / "lab.xml"
    path.write_text(lab_mjcf().replace("<option ", '<option density="1.2" '))
    out = tmp_path / "d.h5"
    assert main(["generate", "--mjcf", str(path), "--steps", "5", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "fluid" in err and "--ignore fluid" in err and "Traceback" not in err
    assert not out.exists()
    args = ["generate", "--mjcf", str(path), "--steps", "5", "--ignore", "fluid", "-o", str(out)]
    assert main([*args, "--no-progress"]) == 0
    assert "warning:" in capsys.readouterr().err and out.exists()
