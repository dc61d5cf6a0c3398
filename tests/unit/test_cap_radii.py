"""End caps of different sizes: each cap's contact radius read from the robot file,
stepped as MuJoCo steps it, and identified from the robot at rest.

The plant is the icosahedron written as MJCF with a sphere of its own radius at each
end cap (:data:`RADII`), dropped onto a floor; free-joint damping lets it come to rest
(its sphere caps would otherwise roll on forever).
"""

from __future__ import annotations

import re
from dataclasses import replace

import mujoco
import numpy as np
import pytest
import torch
from test_mjcf_lab import mj_rod_state

from identification.data.end_caps import measured_rod_states
from identification.trajectory.cap_radius_fit import fit_cap_radii
from identification.trajectory.windows import rollout_caps
from tensegrity_env.assemblies import icosahedron, node_positions
from tensegrity_env.effects.ground_contact import GroundContact
from tensegrity_env.engine import Engine, State
from tensegrity_env.envs.physics import NativeStepper
from tensegrity_env.mjcf import from_mjcf, to_mjcf
from tensegrity_env.mjcf.writer import SimOptions
from tensegrity_env.model import Model
from tensegrity_env.topology import Topology

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: each rod's (end 0, end 1) sphere radius [m]
RADII = ((0.02, 0.03), (0.035, 0.025), (0.045, 0.02), (0.03, 0.04), (0.025, 0.05), (0.04, 0.035))
#: the one contact radius a file without the spheres would give every cap [m]
ONE_RADIUS = 0.03
#: motion capture's sample interval [s] (MuJoCo steps 1 ms)
DT = 0.01


def plant():
    """The icosahedron with :data:`RADII` sphere end caps, 8 cm above a floor, read back
    from the MJCF written for it (free-joint damping 3 on every rod)."""
    a = icosahedron(stiffness=200.0, damping=5.0, mass=1.0, seed=3)
    rods = tuple(replace(r, cap_radius=RADII[i]) for i, r in enumerate(a.topology.rods))
    topo = replace(a.topology, rods=rods)
    lift = 0.08 - node_positions(topo, a.pose_p, a.pose_q)[:, 2].min()
    xml = to_mjcf(
        topo,
        a.params,
        SimOptions(ground=True, control=False),
        a.pose_p + np.array([0.0, 0.0, lift]),
        a.pose_q,
    )
    xml = re.sub(
        r'<freejoint name="([^"]+)"\s*/>', r'<joint type="free" name="\1" damping="3"/>', xml
    )
    return from_mjcf("<icosahedron>", xml=xml)


def settled(asm, seconds: float) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """MuJoCo's prism dropped onto its floor and left for ``seconds``."""
    m = asm.model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    for _ in range(round(seconds / m.opt.timestep)):
        mujoco.mj_step(m, d)
    return m, d


def caps_of(asm, d: mujoco.MjData) -> np.ndarray:
    """The end caps (2R, 3) [m] of MuJoCo's state."""
    st = mj_rod_state(asm, d)
    engine = Engine(asm.topology)
    return engine.kinematics(st).x[0, : 2 * asm.topology.n_rods].numpy()


def one_radius(topology: Topology) -> Topology:
    """``topology`` as a file with one contact radius for every cap would give it."""
    rods = tuple(replace(r, radius=ONE_RADIUS, cap_radius=None) for r in topology.rods)
    return replace(topology, rods=rods)


def test_each_end_caps_radius_is_read_from_its_sphere() -> None:
    asm = plant()
    assert np.array_equal(asm.topology.cap_radii, np.array(RADII))
    assert Topology.from_json(asm.topology.to_json()).same_as(asm.topology)
    contact = asm.declared_effects()[0]
    assert isinstance(contact, GroundContact)
    assert np.array_equal(contact.radius.numpy(), np.array(RADII))
    # a document of the robot file's radii is unchanged by them; fitted ones are written
    assert "cap_radius" not in contact.to_dict()["params"]
    moved = contact.with_values(cap_radius=contact.radius + 0.001)
    assert np.allclose(moved.to_dict()["params"]["cap_radius"], np.array(RADII) + 0.001)


def test_fitted_radii_and_their_errors_survive_a_params_file(tmp_path) -> None:
    asm = plant()
    contact = asm.declared_effects()[0]
    se = np.full((6, 2), np.inf)  # a cap the data does not see
    se[0, 0] = 1e-4
    fitted = contact.with_values(cap_radius=contact.radius + 0.002)
    fitted.uncertainty["cap_radius"] = se
    Model(asm.topology, asm.params, [fitted]).save(tmp_path / "params.json")
    again = Model.read(tmp_path / "params.json").effects[0]
    assert np.array_equal(again.radius.numpy(), fitted.radius.numpy())
    assert np.array_equal(np.asarray(again.uncertainty["cap_radius"], float), se)


def test_engine_and_kernel_step_caps_of_different_radii_as_mujoco() -> None:
    asm = plant()
    m, d = settled(asm, 1.8)  # tipping over onto a face: caps on the floor, moving
    contact, drag = asm.declared_effects()
    engine = Engine(asm.topology, dt=m.opt.timestep, effects=[contact, drag])
    state = mj_rod_state(asm, d)
    touching = contact.clearance(state, engine.kinematics(state)) < 0
    assert int(touching.sum()) >= 2
    errors = []
    for _ in range(200):
        mujoco.mj_step(m, d)
        state = engine.step(state, asm.params)
        ref = mj_rod_state(asm, d)
        errors.append(
            max(
                float((getattr(state, k) - getattr(ref, k)).abs().max())
                for k in ("p", "v", "q", "omega")
            )
        )
    assert max(errors) <= 1e-9
    stepper = NativeStepper(asm.topology, asm.params, [contact, drag], m.opt.timestep, 2, threads=1)
    assert stepper.verify(asm.params, [contact, drag]) <= 1e-12


def test_contact_radii_are_identified_at_rest_and_the_rest_shape_follows() -> None:
    asm = plant()
    m, d = settled(asm, 10.0)
    rest = []
    for _ in range(round(1.0 / DT) + 1):  # one second at rest, sampled every DT
        rest.append(caps_of(asm, d))
        for _ in range(round(DT / m.opt.timestep)):
            mujoco.mj_step(m, d)
    rest = np.array(rest)
    # at rest, but for the slow creep MuJoCo's soft friction lets loaded caps make
    assert np.abs(rest - rest[0]).max() < 5e-3
    on_floor = rest[0, :, 2].reshape(-1, 2) - np.array(RADII) < 1e-3  # the caps it stands on
    assert on_floor.sum() >= 3
    topo = one_radius(asm.topology)
    contact, drag = asm.declared_effects()
    law = {k: v for k, v in contact.values.items() if k != "cap_radius"}
    nominal = GroundContact(topo, **law)
    drag = type(drag)(topo, **drag.values)
    engine = Engine(topo, dt=DT, substeps=round(DT / m.opt.timestep), native=True)
    found = fit_cap_radii(engine, asm.params, [drag, nominal], [rest])
    assert found is not None and found.kept
    r = found.contact.radius.numpy()
    se = found.contact.uncertainty["cap_radius"]
    # the caps it stands on are found within 0.1 mm (0.02 mm here), with finite standard errors; the
    # raised ones keep the file's radius, unseen
    assert np.array_equal(found.free, on_floor)
    assert np.abs(r - np.array(RADII))[on_floor].max() <= 1e-4, r
    assert np.isfinite(se[on_floor]).all() and np.isinf(se[~on_floor]).all()
    assert np.array_equal(r[~on_floor], np.full(int((~on_floor).sum()), ONE_RADIUS))
    # the rest shape: the model settles where MuJoCo's robot rests, as it does not with
    # one radius for every cap
    shape = {name: rest_error(engine.with_effects([drag, c]), asm.params, rest) for name, c in
             (("nominal", nominal), ("identified", found.contact))}  # fmt: skip
    assert shape["identified"] <= 2e-4, shape
    assert shape["nominal"] >= 10 * shape["identified"], shape


def rest_error(engine: Engine, params, rest: np.ndarray) -> float:
    """End-cap RMS [m] between the end caps ``engine`` holds, rolled out from the first
    measured resting state (velocities zero), and the measured ones ``rest`` (T, 2R, 3)
    at the end of the rest."""
    _, st = measured_rod_states(rest[None], engine.topology, DT, "gaussian", 0.01)
    p, q = torch.as_tensor(st["p"][:, 0]), torch.as_tensor(st["q"][:, 0])
    init = State(p, torch.zeros_like(p), q, torch.zeros_like(p))
    zeros = torch.zeros(1, rest.shape[0] - 1, engine.topology.n_rods, 3, dtype=torch.float64)
    with torch.no_grad():
        caps = rollout_caps(engine, params, init, zeros)
    return float(np.sqrt(((caps[0, -1].numpy() - rest[-1]) ** 2).sum(-1).mean()))
