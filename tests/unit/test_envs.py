"""The environments: native step = engine, Gymnasium/SB3 checks, batch = N singles, task, rendering."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.logger import Logger

import tensegrity_env  # registers the envs
from tensegrity_env.assemblies import element
from tensegrity_env.effects import GroundContact
from tensegrity_env.engine import Engine, State
from tensegrity_env.envs import (
    IcosahedronMJEnv,
    IcosahedronSREnv,
    IcosahedronSRVectorEnv,
    RenderingUnavailable,
    SB3VecEnv,
    write_video,
)
from tensegrity_env.envs.physics import (
    KernelMismatch,
    NativeStepper,
    TorchStepper,
    make_stepper,
    pack_states,
)
from tensegrity_env.envs.sr_env import DEFAULT_PARAMS, load_env_model
from tensegrity_env.envs.twin import face_down_pose, twin_assembly, twin_mjcf
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model
from tensegrity_env.native.pack import NotNative
from tensegrity_env.params import load_params_document
from tensegrity_env.rotations import np_quat_mul, np_quat_to_matrix

RNG = np.random.default_rng(0)


# ---------------------------------------------------------------------- the native step
def _states_near_floor(n: int, rng: np.random.Generator) -> State:
    """Face-down icosahedra 2 mm into the floor, with random velocities."""
    a = twin_assembly()
    p, q = face_down_pose(a.topology, a.pose_p, a.pose_q, clearance=-2e-3)
    return State.from_numpy(
        p + rng.normal(0, 3e-3, (n, 6, 3)),
        rng.normal(0, 0.3, (n, 6, 3)),
        np.broadcast_to(q, (n, 6, 4)).copy(),
        rng.normal(0, 0.5, (n, 6, 3)),
    )


def _engine_steps(topology, params, effects, state, control, steps):  # type: ignore[no-untyped-def]
    engine = Engine(topology, 1e-3, effects)
    with torch.no_grad():
        for _ in range(steps):
            state = engine.step(state, params, control)
    return pack_states(state)


@pytest.mark.parametrize(("batch", "friction"), [(3, 1.0), (11, 0.6)])
def test_native_step_matches_engine_with_ground_contact(batch: int, friction: float) -> None:
    """One block padded, and a full block plus a remainder: the engine's numbers to round-off."""
    a = twin_assembly()
    effects = [GroundContact(a.topology, friction=friction, stiffness=2000.0, impedance=0.93)]
    state = _states_near_floor(batch, RNG)
    u = RNG.normal(0, 1, (batch, 6, 3))
    ref = _engine_steps(a.topology, a.params, effects, state, torch.as_tensor(u), 100)
    x = pack_states(state)
    NativeStepper(a.topology, a.params, effects, 1e-3, 50)(x, u)
    NativeStepper(a.topology, a.params, effects, 1e-3, 50)(x, u)
    assert np.abs(x - ref).max() < 1e-10
    assert np.isfinite(x).all() and (x[..., 2] > 0).all()


def test_native_step_rod_with_both_caps_on_the_floor() -> None:
    """The coupled two-cap contact problem and world anchors (the one-rod element, lowered)."""
    e = element()
    effects = [GroundContact(e.topology, friction=0.8)]
    p = e.pose_p + np.array([0.0, 0.0, e.topology.rods[0].radius - 2e-3])
    n = 2
    state = State.from_numpy(
        np.broadcast_to(p, (n, 1, 3)).copy(),
        RNG.normal(0, 0.2, (n, 1, 3)),
        np.broadcast_to(e.pose_q, (n, 1, 4)).copy(),
        RNG.normal(0, 0.5, (n, 1, 3)),
    )
    u = RNG.normal(0, 1, (n, 1, 3))
    ref = _engine_steps(e.topology, e.params, effects, state, torch.as_tensor(u), 40)
    x = pack_states(state)
    NativeStepper(e.topology, e.params, effects, 1e-3, 40)(x, u)
    assert np.abs(x - ref).max() < 1e-10


def test_native_contact_lanes_do_not_mix() -> None:
    """Rods lying flat (both end caps down: the 8-edge problem) beside tilted rods (one
    cap down: 4 edges) in one SIMD block: each assembly steps as it does alone, bit for
    bit, and as the engine does to round-off."""
    e = element()
    n = 8
    rng = np.random.default_rng(11)
    p = np.broadcast_to(e.pose_p, (n, 1, 3)).copy()
    p[..., 2] += e.topology.rods[0].radius - 2e-3
    tilt = np.where(np.arange(n) % 2 == 0, 0.0, rng.uniform(0.006, 0.01, n))  # even: flat
    turn = np.stack([np.cos(tilt / 2), 0 * tilt, np.sin(tilt / 2), 0 * tilt], -1)[:, None]
    q = np_quat_mul(turn, np.broadcast_to(e.pose_q, (n, 1, 4)))
    state = State.from_numpy(p, rng.normal(0, 0.2, (n, 1, 3)), q, rng.normal(0, 0.5, (n, 1, 3)))
    effects = [GroundContact(e.topology, friction=0.8)]
    ends = np.einsum("brij,rkj->brki", np_quat_to_matrix(q), e.topology.end_offsets)[..., 2]
    down = (p[..., 2:3] + ends - e.topology.rods[0].radius < 0).sum(-1)[:, 0]
    assert set(down.tolist()) == {1, 2}  # both kinds of rods in the block
    u = rng.normal(0, 1, (n, 1, 3))
    stepper = NativeStepper(e.topology, e.params, effects, 1e-3, 20)
    together = pack_states(state)
    stepper(together, u)
    for b in range(n):
        alone = np.ascontiguousarray(pack_states(state)[b : b + 1])
        stepper(alone, u[b : b + 1])
        assert np.array_equal(alone, together[b : b + 1])
    ref = _engine_steps(e.topology, e.params, effects, state, torch.as_tensor(u), 20)
    assert np.abs(together - ref).max() < 1e-10


def test_native_and_torch_backends_agree_through_the_env() -> None:
    native = IcosahedronSREnv(frame_skip=10)
    torch_env = IcosahedronSREnv(frame_skip=10, backend="torch")
    assert isinstance(native.sim.stepper, NativeStepper)
    assert isinstance(torch_env.sim.stepper, TorchStepper)
    native.reset(seed=3)
    torch_env.reset(options={"state": native.state, "goal": native.goal})
    for _ in range(2):
        a = RNG.uniform(-1, 1, 18).astype(np.float32)
        o1, r1, *_ = native.step(a)
        o2, r2, *_ = torch_env.step(a)
    np.testing.assert_allclose(native.state, torch_env.state, atol=1e-10)
    np.testing.assert_allclose(o1, o2, atol=1e-5)
    assert abs(r1 - r2) < 1e-6


def test_kernel_self_check_catches_a_different_law() -> None:
    """A contact law the kernel does not implement is caught: a subclass of the ground
    contact is not packed, and the self-check against the engine catches the law."""
    a = twin_assembly()

    class Stiffer(GroundContact):
        def wrench(self, state, kin, params, applied=None):  # type: ignore[no-untyped-def]
            force, torque = super().wrench(state, kin, params, applied)
            return 1.01 * force, 1.01 * torque

    with pytest.raises(NotNative, match="no native form"):
        NativeStepper(a.topology, a.params, [Stiffer(a.topology)], 1e-3, 50)
    native = NativeStepper(a.topology, a.params, [GroundContact(a.topology)], 1e-3, 50)
    with pytest.raises(KernelMismatch):
        native.verify(a.params, [Stiffer(a.topology)])
    with pytest.warns(UserWarning, match="PyTorch engine"):
        stepper = make_stepper(a.topology, a.params, [Stiffer(a.topology)], 1e-3, 50)
    assert isinstance(stepper, TorchStepper)


# ---------------------------------------------------------------------- Gymnasium and SB3
@pytest.mark.parametrize("env_id", ["tensegrity_env:IcosahedronSR-v0", "IcosahedronMJ-v0"])
def test_env_checkers_pass(env_id: str) -> None:
    env = gym.make(env_id)
    check_env(env.unwrapped)
    sb3_check_env(env.unwrapped)
    env.close()


def test_both_envs_share_spaces_and_observation() -> None:
    sr, mj = gym.make("IcosahedronSR-v0"), gym.make("IcosahedronMJ-v0")
    assert sr.action_space == mj.action_space
    assert (
        sr.observation_space
        == mj.observation_space
        == gym.spaces.Box(-np.inf, np.inf, (75,), np.float32)
    )
    o_sr, _ = sr.reset(seed=1)
    state, goal = sr.unwrapped.state, sr.unwrapped.goal
    o_mj, _ = mj.reset(options={"state": state, "goal": goal})
    np.testing.assert_allclose(o_sr, o_mj, atol=1e-6)
    # with no control the identified model follows the twin closely for a second
    for _ in range(20):
        sr.step(np.zeros(18, np.float32))
        mj.step(np.zeros(18, np.float32))
    gap = np.linalg.norm(sr.unwrapped.state[:, :3].mean(0) - mj.unwrapped.state[:, :3].mean(0))
    assert gap < 1e-3


def test_seeded_resets_are_deterministic() -> None:
    env = gym.make("IcosahedronSR-v0")
    o1, _ = env.reset(seed=7)
    o2, _ = env.reset(seed=7)
    o3, _ = env.reset(seed=8)
    np.testing.assert_array_equal(o1, o2)
    assert not np.allclose(o1, o3)
    a = np.full(18, 0.5, np.float32)
    env.reset(seed=7)
    s1 = env.step(a)[0]
    env.reset(seed=7)
    np.testing.assert_array_equal(s1, env.step(a)[0])


# ---------------------------------------------------------------------- the task
def test_goal_reached_terminates_and_time_limit_truncates() -> None:
    env = gym.make("IcosahedronSR-v0", max_episode_steps=3)
    env.reset(seed=0)
    centre = env.unwrapped.state[:, :2].mean(axis=0)
    env.reset(seed=0, options={"goal": centre})
    _, reward, terminated, truncated, info = env.step(np.zeros(18, np.float32))
    assert terminated and not truncated and info["is_success"]
    assert info["reward_goal"] == env.unwrapped.task.goal_bonus
    assert reward == pytest.approx(
        info["reward_progress"] + info["reward_control"] + info["reward_goal"]
    )
    env.reset(seed=0)
    flags = [env.step(np.zeros(18, np.float32))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]


def test_commands_are_bounded_below_the_weight() -> None:
    env = IcosahedronSREnv()
    u = env.task.commands(RNG.uniform(-5, 5, (100, 18)), 6)
    assert np.linalg.norm(u, axis=-1).max() <= env.task.max_command + 1e-12
    params = env.sim.params
    push = 6 * float(params.control_gain) * env.task.max_command
    weight = float(params.mass.sum()) * 9.81
    assert push < 0.3 * weight


def test_structure_stands_and_rolls_forward_when_pushed() -> None:
    env = IcosahedronSREnv()
    env.reset(seed=0)
    start = env.state[:, :3].mean(axis=0)
    assert 0.2 < start[2] < 0.4  # standing, not collapsed
    for _ in range(20):
        env.step(np.zeros(18, np.float32))
    assert np.linalg.norm(env.state[:, :3].mean(axis=0) - start) < 0.02  # at rest
    push = np.tile([1.0, 0.0, 0.0], 6).astype(np.float32)
    for _ in range(100):  # 5 s of the largest push along +x
        _, _, terminated, _, _ = env.step(push)
        assert not terminated
    moved = env.state[:, :3].mean(axis=0) - start
    assert moved[0] > 1.0 and env.state[:, 2].mean() > 0.2


# ---------------------------------------------------------------------- batching
@pytest.mark.parametrize("num_envs", [3, 10])
def test_vector_env_equals_single_envs(num_envs: int) -> None:
    """Same seeds and actions, through several autoresets (episodes of 4 steps)."""
    venv = gym.make_vec(
        "IcosahedronSR-v0", num_envs=num_envs, vectorization_mode="vector_entry_point",
        max_episode_steps=4,
    )  # fmt: skip
    assert isinstance(venv.unwrapped, IcosahedronSRVectorEnv)
    singles = [gym.make("IcosahedronSR-v0", max_episode_steps=4) for _ in range(num_envs)]
    obs, _ = venv.reset(seed=10)
    ref = np.stack([e.reset(seed=10 + i)[0] for i, e in enumerate(singles)])
    np.testing.assert_array_equal(obs, ref)
    for _ in range(9):
        actions = RNG.uniform(-1, 1, (num_envs, 18)).astype(np.float32)
        obs, rew, term, trunc, info = venv.step(actions)
        for i, env in enumerate(singles):
            o, r, te, tr, inf = env.step(actions[i])
            assert (te, tr) == (term[i], trunc[i])
            assert r == rew[i] and inf["reward_progress"] == info["reward_progress"][i]
            if te or tr:
                np.testing.assert_array_equal(info["final_obs"][i], o)
                o, _ = env.reset()
            np.testing.assert_array_equal(obs[i], o)


def test_sb3_adapter_terminal_observation_and_timelimit() -> None:
    venv = SB3VecEnv(IcosahedronSRVectorEnv(num_envs=4, max_episode_steps=3))
    venv.seed(0)
    obs = venv.reset()
    assert obs.shape == (4, 75)
    for _ in range(3):
        obs, rewards, dones, infos = venv.step(np.zeros((4, 18), np.float32))
    assert dones.all() and rewards.dtype == np.float32
    for info in infos:
        assert info["TimeLimit.truncated"] is True
        assert info["terminal_observation"].shape == (75,)
        assert not np.array_equal(info["terminal_observation"], obs[0])


def _approach_and_return(policy, seed: int, steps: int = 40) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Mean approach to the goal [m] and mean return of ``policy(obs) -> actions`` over
    16 episodes of ``steps`` steps that start from the states and goals of ``seed``."""
    venv = SB3VecEnv(IcosahedronSRVectorEnv(num_envs=16, max_episode_steps=steps))
    venv.seed(seed)
    obs = venv.reset()
    progress, total = np.zeros(16), np.zeros(16)
    for _ in range(steps):
        obs, reward, _, infos = venv.step(policy(obs))
        total += reward
        progress += [info["reward_progress"] for info in infos]
    control_dt = venv.venv.control_dt
    return float(progress.mean() * control_dt), float(total.mean())  # progress_weight 1: m/s


def test_sb3_trains_on_the_batched_env(one_torch_thread: None) -> None:
    """4096 PPO steps through the SB3 adapter already roll the structure toward the goal.

    On the same 16 held-out episodes the trained policy approaches the goal by more than
    the untrained one (same initial weights) and earns more than uniformly random
    actions: rewards, observations and episode ends reach the learner correctly.
    """
    from stable_baselines3 import PPO

    venv = SB3VecEnv(IcosahedronSRVectorEnv(num_envs=16, max_episode_steps=40))
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=128, n_epochs=4, learning_rate=1e-3,
                device="cpu", seed=0)  # fmt: skip
    model.set_logger(Logger(folder=None, output_formats=[]))  # no folder in /tmp

    def act(obs: np.ndarray) -> np.ndarray:
        return model.predict(obs, deterministic=True)[0]

    rng = np.random.default_rng(0)
    _, random_return = _approach_and_return(lambda o: rng.uniform(-1, 1, (len(o), 18)), seed=100)
    approach_before, return_before = _approach_and_return(act, seed=100)
    model.learn(total_timesteps=4096)
    approach_after, return_after = _approach_and_return(act, seed=100)
    assert approach_after > approach_before + 0.01  # at least 1 cm closer in 2 s
    assert return_after > return_before and return_after > random_return


# ---------------------------------------------------------------------- files
def test_params_path_loads_another_model(tmp_path: Path) -> None:
    a = twin_assembly()
    stiff = a.params.replace(stiffness=a.params.stiffness * 2)
    path = tmp_path / "stiff.json"
    Model(a.topology, stiff, [GroundContact(a.topology)]).save(path)
    env = IcosahedronSREnv(params_path=path)
    assert torch.allclose(env.sim.params.stiffness, stiff.stiffness)
    Model(a.topology, a.params).save(tmp_path / "no_contact.json")
    with pytest.raises(InputError, match="ground_contact"):
        IcosahedronSREnv(params_path=tmp_path / "no_contact.json")
    e = element()
    Model(e.topology, e.params).save(tmp_path / "element.json")
    with pytest.raises(InputError, match="icosahedron"):
        IcosahedronSREnv(params_path=tmp_path / "element.json")


def test_shipped_assets_are_identified_and_in_sync() -> None:
    twin = Path(tensegrity_env.__file__).parent / "assets" / "icosahedron_rolling.xml"
    assert twin.read_text() == twin_mjcf(ground=True)
    doc = load_params_document(DEFAULT_PARAMS)
    model = load_env_model(DEFAULT_PARAMS)
    assert model.effect_names == ["ground_contact"] and model.dt == 1e-3
    truth = twin_assembly().params
    errors = model.params.relative_error(truth)
    assert max(float(v.max()) for v in errors.values()) < 1e-6  # clean data: exact
    assert doc["provenance"]["environment_assets"]["quick"] is False


def test_write_video(tmp_path: Path) -> None:
    frames = [np.full((32, 48, 3), k * 20, np.uint8) for k in range(5)]
    for suffix in (".gif", ".mp4"):
        path = write_video(frames, tmp_path / f"clip{suffix}", fps=10)
        assert path.stat().st_size > 0
    with pytest.raises(ValueError):
        write_video(frames, tmp_path / "clip.avi")


# ---------------------------------------------------------------------- rendering
def _frame(env: gym.Env) -> np.ndarray:
    try:
        return env.render()  # type: ignore[return-value]
    except RenderingUnavailable as e:
        pytest.skip(f"no headless OpenGL here: {e}")


@pytest.mark.parametrize("cls", [IcosahedronSREnv, IcosahedronMJEnv])
def test_rendered_frame_shows_the_structure(cls: type) -> None:
    env = cls(render_mode="rgb_array", width=320, height=240)
    env.reset(seed=0)
    frame = _frame(env)
    assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8
    r, g, b = (frame[..., k].astype(int) for k in range(3))
    rods = (r > 120) & (r > g + 50) & (r > b + 50)  # the rods' rust red
    assert rods.sum() > 200, "no rod pixels in the frame"
    assert frame.std() > 10
    env.close()


# ---------------------------------------------------------------------- slow
@pytest.mark.slow
def test_asset_pipeline_regenerates_an_identified_model(tmp_path: Path) -> None:
    """generate -> identify -> generate on the floor -> diagnose, on small datasets (~1 min)."""
    from tensegrity_sr.make_default_params import main as make_assets

    assert make_assets(["--quick", "--out", str(tmp_path), "--work", str(tmp_path / "work")]) == 0
    params = tmp_path / "icosahedron_rolling_params.json"
    effects = load_env_model(params).effects
    contact = effects[0].values
    assert abs(float(contact["friction"]) - 1.0) < 0.05
    env = IcosahedronSREnv(params_path=params)
    env.reset(seed=0)
    assert 0.2 < env.state[:, 2].mean() < 0.45


def test_identified_env_tracks_the_twin() -> None:
    """Same start and random actions: the centres stay within 1 mm for a second.

    Contact is a constraint that reacts to control forces too (as in MuJoCo); when it
    saw only springs and gravity, the gap under random pushes was 3 mm (median) here.
    """
    sr, mj = IcosahedronSREnv(goal_distance=(50, 50)), IcosahedronMJEnv(goal_distance=(50, 50))
    gaps = []
    for seed in range(6):
        sr.reset(seed=seed)
        mj.reset(options={"state": sr.state, "goal": sr.goal})
        rng = np.random.default_rng(seed)
        for _ in range(20):
            a = rng.uniform(-1, 1, 18).astype(np.float32)
            sr.step(a)
            mj.step(a)
        gaps.append(np.linalg.norm(sr.state[:, :3].mean(0) - mj.state[:, :3].mean(0)))
    assert np.median(gaps) < 2e-4 and max(gaps) < 1e-3


def test_task_options_reach_every_env_and_typos_are_refused() -> None:
    """One definition of the task options (TaskOptions) serves the single and vector envs."""
    sr = gym.make("IcosahedronSR-v0", goal_radius=0.5, goal_distance=[3.0, 3.0])
    mj = gym.make("IcosahedronMJ-v0", goal_radius=0.5, goal_distance=[3.0, 3.0])
    venv = IcosahedronSRVectorEnv(num_envs=2, goal_radius=0.5, goal_distance=(3.0, 3.0))
    for env in (sr.unwrapped, mj.unwrapped, venv):
        assert env.task.goal_radius == 0.5 and env.task.goal_distance == (3.0, 3.0)
    sr.reset(seed=0)
    obs, _ = venv.reset(seed=0)
    # the goal starts 3 m from the centre: observation entries 73-74 are goal minus centre
    assert abs(float(np.linalg.norm(obs[0, 73:75])) - 3.0) < 0.05
    with pytest.raises(TypeError, match="goal_radus"):
        IcosahedronSREnv(goal_radus=0.5)  # type: ignore[call-arg]
    for env in (sr, mj, venv):
        env.close()
