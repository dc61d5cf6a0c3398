"""Identification from noisy measured end caps (motion capture).

Measured data holds end-cap positions only, ``nodes`` (N, T+1, 2R, 3) [m], with
Gaussian noise of ~1 mm. Finite differences of such positions destroy accelerations,
so identification runs in two stages:

1. **Smoothing + linear regression** (:func:`smoothed_regression`): a Savitzky-Golay
   filter gives end-cap positions, velocities and accelerations in continuous time;
   rod states and their rates follow from the rod geometry, and the paper's linear
   equations of motion (:func:`identification.design.rod_blocks`) are solved exactly.
   Fast, but biased by the noise left after smoothing and by the smoothing itself.
2. **Multi-step trajectory fit** (:func:`fit_windows`): the trajectories are cut into
   windows; each window's initial rod state and the physical parameters (log K, c,
   l0, M, I_perp, h; anchors fixed) are free, the differentiable engine rolls every
   window out (batched, float64) and Levenberg-Marquardt minimises the mean squared
   end-cap position error. That is maximum likelihood under Gaussian position noise.
   The window states are local unknowns, so each iteration solves the normal
   equations by a Schur complement on the parameters (bundle-adjustment structure).
   Jacobians come from forward differences through the engine, all directions
   rolled out as one batch (three times cheaper than forward-mode AD here); the
   reverse-mode gradient is available as a check. Windows grow from short (which
   forgive a rough start) to long (which carry far more information per sample).

What end caps cannot show: a rod whose end caps lie on one of its principal axes
can spin about that axis unseen. Its axial moment of inertia enters the motion only
through the (unknown) axial angular momentum ``I_axial * omega_axial``, so it is not
identifiable; simulation uses the solid-cylinder value ``M r^2 / 2`` of the fitted
mass and the per-window axial spin absorbs the rest. :attr:`TrajectoryIdentifier.notes_`
says so; the two perpendicular inertias are one parameter ``I_perp`` per rod. The
axial spins themselves barely show (and make Gauss-Newton converge slowly), so they
are freed only in a last stage, and only when a score test says the data can see
them (clean data, long windows); otherwise they stay 0.

Data needed (icosahedron, 1 kHz, 1 mm noise, initial speeds ~0.5 m/s and ~1.5 rad/s,
no control; the damping c is always the weakest group). Long windows matter far more
than the number of samples: at the truth, one 4 s trajectory gives a largest relative
standard error of c of 2.1 % with 0.5 s windows but 1.1 % with 2 s windows, and 1.2 s
of data cut into 0.1 s windows gives 23 %. Two 0.6 s trajectories give K, M, I_perp
within 1 % and c within ~4 %; four 2 s trajectories (8000 samples) give every K, c, M,
I_perp within 0.6 % (``tests/test_noisy.py``, the slow test). The dataset generator's
livelier small preset (16 trajectories of 0.3 s, speeds up to 1 m/s and 3 rad/s) gives
every K, c, M, I_perp within 1.4 % from 4800 samples. The reported standard
errors (:attr:`TrajectoryIdentifier.stderr_`) are honest (z-scores of rms ~1) and
shrink as one over the square root of the data.

Cost: every Levenberg-Marquardt iteration rolls out ``n_local + n_free + 1`` copies
(155 for the icosahedron) of all the data: ~1.2 s per 1000 samples on one core.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch
from scipy.signal import savgol_filter
from tqdm.auto import tqdm

from identification.dataset import Dataset, Split
from identification.design import ParameterLayout, accumulate_normal, rod_blocks, rod_slots
from identification.features import TransitionFeatures
from identification.solve import solve_constrained
from tensegrity_env.engine import Engine, State
from tensegrity_env.engine.forces import spring_frames
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.io_utils import InputError
from tensegrity_env.params import Params
from tensegrity_env.rotations import quat_mul, quat_to_matrix
from tensegrity_env.topology import Topology

DTYPE = torch.float64
#: the groups of the trajectory fit's log-parameter vector, in order
GROUPS = ("stiffness", "damping", "rest_length", "mass", "inertia_perp", "control_gain")
#: the trajectory fit keeps every parameter within a factor e^LOG_BOX (1e4) of its
#: stage-1 start, so that one the data barely sees cannot run off towards 0, where
#: its effect (and so its Jacobian column) drops below round-off and it never returns
LOG_BOX = float(np.log(1e4))


# ---------------------------------------------------------------------- measured data
def add_measurement_noise(dataset: Dataset, std: float = 1e-3, seed: int = 0) -> Dataset:
    """A copy with i.i.d. Gaussian noise of ``std`` [m] on every end-cap coordinate.

    Only ``nodes`` (noisy) and ``control`` are kept: rod states are dropped, as motion
    capture would not give them. Each split draws from its own seeded stream.
    """
    splits = {}
    for k, (name, split) in enumerate(sorted(dataset.splits.items())):
        rng = np.random.default_rng([seed, k])
        noisy = split.nodes + std * rng.standard_normal(split.nodes.shape)
        splits[name] = Split(nodes=noisy, control=split.control.copy())
    attrs = {**dataset.attrs, "measurement_noise_std": float(std)}
    return Dataset(dataset.topology, dataset.dt, splits, attrs=attrs, path=None)


# ---------------------------------------------------------------------- rod geometry
@dataclass(frozen=True)
class RodAxes:
    """End caps on a principal axis through the centre of mass, for every rod.

    Attributes:
        axis: index (0, 1, 2) of the principal axis holding rod r's end caps, (R,).
        frac: the COM as ``x_0 + frac * (x_1 - x_0)`` between the end caps, (R,).
        radius: rod radius for the assumed axial inertia ``M r^2 / 2`` [m], (R,).
    """

    axis: np.ndarray
    frac: np.ndarray
    radius: np.ndarray

    @classmethod
    def of(cls, topology: Topology) -> RodAxes:
        """Raise :class:`InputError` if some rod's end caps are not on a principal axis."""
        ends = topology.end_offsets  # (R, 2, 3)
        axis, frac = [], []
        for r, e in enumerate(ends):
            k = int(np.argmax(np.abs(e[1] - e[0])))
            off = np.delete(e, k, axis=1)
            scale = np.abs(e).max()
            if np.abs(off).max() > 1e-9 * scale or abs(e[1, k] - e[0, k]) < 1e-12:
                raise InputError(
                    f"rod '{topology.rods[r].name}': end caps are not on a principal axis through "
                    "the centre of mass; end-cap-only identification needs them there"
                )
            axis.append(k)
            frac.append(-e[0, k] / (e[1, k] - e[0, k]))
        radius = np.array([max(rod.radius, 1e-3) for rod in topology.rods])
        return cls(np.array(axis), np.array(frac), radius)


def quat_from_axis(u: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., R, 4) turning principal axis ``axis[r]`` onto unit ``u`` (..., R, 3).

    The rotation about ``u`` is unobservable from end caps; this picks the shortest arc.
    """
    a = np.eye(3)[axis]  # (R, 3)
    a = np.broadcast_to(a, u.shape)
    w = 1.0 + (a * u).sum(-1, keepdims=True)
    xyz = np.cross(a, u)
    flip = w[..., 0] < 1e-9  # u = -a: half turn about any axis perpendicular to a
    perp = np.eye(3)[(np.asarray(axis) + 1) % 3]
    perp = np.broadcast_to(perp, u.shape)
    q = np.concatenate([w, xyz], axis=-1)
    q = np.where(flip[..., None], np.concatenate([np.zeros_like(w), perp], axis=-1), q)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


@dataclass(frozen=True)
class SmoothedStates:
    """Rod kinematics from smoothed end caps, all (N, T+1, R, ·), world frame.

    Attributes:
        x, xd: end-cap positions [m] and velocities [m/s], (N, T+1, 2R, 3).
        p, v, a: COM position [m], velocity [m/s], acceleration [m/s^2].
        q: orientation (w, x, y, z) with the shortest-arc axial phase, (..., 4).
        omega, alpha: angular velocity [rad/s] and acceleration [rad/s^2] perpendicular
            to the rod (the axial part is unobservable and set to 0).
        window: the filter length used [samples].
    """

    x: np.ndarray
    xd: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    q: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    window: int

    @property
    def margin(self) -> int:
        """Samples at each end where the filter extrapolates."""
        return min(self.window // 2, (self.p.shape[1] - 1) // 2)


def smooth_rod_states(
    nodes: np.ndarray, dt: float, axes: RodAxes, window: int, polyorder: int = 3
) -> SmoothedStates:
    """Savitzky-Golay smoothing of end caps ``nodes`` (N, T+1, 2R, 3) and the rod states.

    ``window`` is the filter length in samples (odd; clipped to the trajectory). The
    perpendicular angular velocity and acceleration are ``u × u̇`` and ``u × ü`` of
    the rod direction ``u``.
    """
    T1 = nodes.shape[1]
    window = min(window, T1 if T1 % 2 else T1 - 1)
    window = max(window, polyorder + 2 + (polyorder % 2 == 0))
    kw = {"window_length": window, "polyorder": polyorder, "axis": 1, "delta": dt}
    x, xd, xdd = (savgol_filter(nodes, deriv=d, **kw) for d in range(3))
    N, _, n2, _ = nodes.shape
    shape = (N, T1, n2 // 2, 2, 3)
    x, xd, xdd = (y.reshape(shape) for y in (x, xd, xdd))
    lam = axes.frac[:, None]
    d, dd, ddd = (y[..., 1, :] - y[..., 0, :] for y in (x, xd, xdd))
    p, v, a = (y[..., 0, :] + lam * dy for y, dy in ((x, d), (xd, dd), (xdd, ddd)))
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    u = d / length
    omega = np.cross(u, dd / length)
    alpha = np.cross(u, ddd / length)
    return SmoothedStates(
        x=x.reshape(nodes.shape), xd=xd.reshape(nodes.shape), p=p, v=v, a=a,
        q=quat_from_axis(u, axes.axis), omega=omega, alpha=alpha, window=window,
    )  # fmt: skip


# ---------------------------------------------------------------------- stage 1
def smoothed_features(
    topology: Topology, s: SmoothedStates, control: np.ndarray
) -> TransitionFeatures:
    """:class:`TransitionFeatures` at every sample ``t < T`` away from the ends (``s.margin``).

    Continuous-time accelerations from the smoothing replace the transition's finite
    differences; ``control`` is (N, T, R, 3).
    """
    T = control.shape[1]
    t = slice(s.margin, max(s.margin + 1, min(T, s.p.shape[1] - s.margin)))

    def pick(arr: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(arr[:, t].reshape(-1, *arr.shape[2:]), dtype=DTYPE)

    p, q, omega, alpha, accel = map(pick, (s.p, s.q, s.omega, s.alpha, s.a))
    x_end, xd_end, u = map(pick, (s.x, s.xd, control))
    n, R = p.shape[:2]
    rot = quat_to_matrix(q)
    anchors = torch.as_tensor(topology.anchor_positions, dtype=DTYPE).expand(n, -1, -1)
    kin = Kinematics(
        rot=rot,
        arms=x_end.reshape(n, R, 2, 3) - p.unsqueeze(2),
        x=torch.cat([x_end, anchors], dim=1),
        xd=torch.cat([xd_end, torch.zeros_like(anchors)], dim=1),
    )
    nodes = torch.as_tensor(topology.spring_nodes, dtype=torch.long)
    arm_u = torch.einsum("nrij,rj->nri", rot, torch.as_tensor(topology.control_arms, dtype=DTYPE))
    return TransitionFeatures(
        accel=accel,
        alpha_local=torch.einsum("nrji,nrj->nri", rot, alpha),
        omega_local=torch.einsum("nrji,nrj->nri", rot, omega),
        rot=rot,
        arms=kin.arms,
        springs=spring_frames(kin, nodes[:, 0], nodes[:, 1]),
        control=u,
        control_arm=arm_u,
    )


def smoothed_regression(
    topology: Topology,
    smooth: SmoothedStates,
    control: np.ndarray,
    anchors: Mapping[str, float] | None = None,
    gravity: Sequence[float] = (0.0, 0.0, -9.81),
) -> dict[str, np.ndarray]:
    """Stage 1: linear regression on smoothed end caps (see :func:`smooth_rod_states`).

    Returns natural-unit values: ``stiffness``, ``damping``, ``rest_length`` (S,),
    ``mass``, ``inertia_perp`` (R,) and ``control_gain`` (1,); NaN where the regression
    cannot tell. Samples near the ends, where the filter extrapolates, are not used.
    Anchors (see :func:`parse_anchors`) fix the scale; without one it is ``mass`` of the
    first rod = 1.
    """
    topo = topology
    axes = RodAxes.of(topo)
    layout = ParameterLayout.build(topo)
    slots = rod_slots(layout)
    feat = smoothed_features(topo, smooth, control)
    P = layout.n_params
    normal = torch.zeros(P + 1, P + 1, dtype=DTYPE)
    accumulate_normal(rod_blocks(feat, slots, torch.tensor(gravity, dtype=DTYPE)), slots, P, normal)
    fixed = {}
    rods, springs = [r.name for r in topo.rods], [s.name for s in topo.springs]
    for (group, i), value in parse_anchors(topo, anchors or {}).items():
        names = {
            "mass": [f"mass[{rods[i]}]"],
            "stiffness": [f"stiffness[{springs[i]}]"],
            "damping": [f"damping[{springs[i]}]"],
            "control_gain": ["control_gain"],
            "inertia_perp": [
                f"inertia[{rods[i]},{'xyz'[k]}]" for k in range(3) if k != axes.axis[i]
            ],
        }.get(group, [])  # rest lengths do not set the scale
        for name in names:
            fixed[layout.lookup(name)] = float(value)
    if not any(v != 0 for v in fixed.values()):
        fixed = {layout.index("mass", 0): 1.0}
    sol = solve_constrained(normal[:-1, :-1], fixed, feat.n * topo.n_rods * 6)
    th = {
        g: [] for g in ("mass", "inertia", "stiffness", "stiffness_rest", "damping", "control_gain")
    }
    for value, group in zip(sol.theta, layout.groups, strict=True):
        th[group].append(value)
    inertia = np.array(th["inertia"]).reshape(-1, 3)
    perp = np.isfinite(inertia) & (np.eye(3)[axes.axis] == 0)  # the two perpendicular axes
    count = perp.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return {
            "stiffness": np.array(th["stiffness"]),
            "damping": np.array(th["damping"]),
            "rest_length": np.array(th["stiffness_rest"]) / np.array(th["stiffness"]),
            "mass": np.array(th["mass"]),
            "inertia_perp": np.where(count > 0, np.where(perp, inertia, 0).sum(1) / count, np.nan),
            "control_gain": np.array(th["control_gain"]),
        }


def _odd(x: float) -> int:
    n = max(round(x), 5)
    return n if n % 2 else n + 1


# ---------------------------------------------------------------------- parameters
def parse_anchors(topology: Topology, anchors: Mapping[str, float]) -> dict[tuple[str, int], float]:
    """``{"mass[rod0]": 1.95}`` -> ``{("mass", 0): 1.95}``.

    Names: ``mass[ROD]``, ``inertia_perp[ROD]`` (or ``inertia[ROD,x]`` for a perpendicular
    axis), ``stiffness[SPRING]``, ``damping[SPRING]``, ``rest_length[SPRING]``,
    ``control_gain``. Values must be positive. Raises :class:`InputError`.
    """
    rods = {r.name: i for i, r in enumerate(topology.rods)}
    springs = {s.name: i for i, s in enumerate(topology.springs)}
    out: dict[tuple[str, int], float] = {}
    for name, value in anchors.items():
        group, _, rest = name.partition("[")
        element = rest.rstrip("]").split(",")[0]
        key: tuple[str, int] | None = None
        if name == "control_gain":
            key = ("control_gain", 0)
        elif group in ("mass", "inertia_perp", "inertia") and element in rods:
            key = ("inertia_perp" if group == "inertia" else group, rods[element])
        elif group in ("stiffness", "damping", "rest_length") and element in springs:
            key = (group, springs[element])
        if key is None:
            raise InputError(
                f"unknown anchor '{name}'; use mass[{topology.rods[0].name}], "
                f"stiffness[{topology.springs[0].name}], inertia_perp[ROD], control_gain, ..."
            )
        if (
            group == "inertia"
            and rest.rstrip("]").split(",")[-1] == "xyz"[RodAxes.of(topology).axis[key[1]]]
        ):
            raise InputError(
                f"anchor '{name}': the axial inertia is not identifiable from end caps"
            )
        if not float(value) > 0:
            raise InputError(f"anchor '{name}' must be positive, got {value}")
        out[key] = float(value)
    return out


@dataclass(frozen=True)
class ParamVector:
    """The trajectory fit's log-parameters: ``log [K, c, l0, M, I_perp, h]`` (n_full,).

    ``free`` marks the fitted entries; the others stay at ``start``. Inertia is
    ``I_perp`` on both perpendicular axes and the assumed ``M r^2 / 2`` on the axis.
    """

    topology: Topology
    axes: RodAxes
    start: torch.Tensor
    free: torch.Tensor
    gravity: torch.Tensor

    @property
    def sizes(self) -> dict[str, int]:
        S, R = self.topology.n_springs, self.topology.n_rods
        return dict(zip(GROUPS, (S, S, S, R, R, 1), strict=True))

    def offset(self, group: str) -> int:
        return sum(list(self.sizes.values())[: GROUPS.index(group)])

    @property
    def n_free(self) -> int:
        return int(self.free.sum())

    def selector(self) -> torch.Tensor:
        """(n_full, n_free) 0/1 matrix placing free values into the full vector."""
        idx = torch.nonzero(self.free)[:, 0]
        sel = torch.zeros(len(self.free), len(idx), dtype=DTYPE)
        sel[idx, torch.arange(len(idx))] = 1.0
        return sel

    def full(self, theta: torch.Tensor) -> torch.Tensor:
        """Full log vector (..., n_full) from the free values ``theta`` (..., n_free)."""
        return torch.where(self.free, 0.0, self.start) + theta @ self.selector().T

    def params(self, log_full: torch.Tensor) -> Params:
        """Engine parameters from a full log vector (n_full,) (differentiable).

        A batch of vectors (B, n_full) gives per-batch parameters, (B, ·), which the
        engine broadcasts against states of batch B (used to fold tangents).
        """
        val = torch.exp(log_full)
        g = {k: val[..., self.offset(k) : self.offset(k) + n] for k, n in self.sizes.items()}
        axial = torch.as_tensor(np.eye(3)[self.axes.axis], dtype=DTYPE)  # (R, 3)
        r2 = torch.as_tensor(self.axes.radius**2 / 2, dtype=DTYPE)
        inertia = (
            g["inertia_perp"].unsqueeze(-1) * (1 - axial) + (g["mass"] * r2).unsqueeze(-1) * axial
        )
        gain = g["control_gain"][..., 0]
        return Params(
            stiffness=g["stiffness"], damping=g["damping"], rest_length=g["rest_length"],
            mass=g["mass"], inertia=inertia, gravity=self.gravity,
            control_gain=gain if log_full.dim() == 1 else gain[:, None, None],
        )  # fmt: skip

    def names(self) -> list[str]:
        """Name of every entry of the full vector, e.g. ``stiffness[spring3]``."""
        rods = [r.name for r in self.topology.rods]
        springs = [s.name for s in self.topology.springs]
        labels = {"mass": rods, "inertia_perp": rods, "control_gain": None}
        out = []
        for group in GROUPS:
            els = labels.get(group, springs)
            out += [group] if els is None else [f"{group}[{e}]" for e in els]
        return out


# ---------------------------------------------------------------------- windows
STATE_KEYS = ("p", "v", "q", "omega")


@dataclass(frozen=True)
class Windows:
    """Trajectory windows of ``W`` steps, batched over ``B``.

    Attributes:
        obs: measured end caps, (B, W+1, 2R, 3) [m].
        control: commands during each step, (B, W, R, 3), or None (no control).
        state: current estimate of each window's initial rod state, (B, R, ·).
        traj, start: trajectory index and first sample of each window, (B,).
    """

    obs: torch.Tensor
    control: torch.Tensor | None
    state: State
    traj: np.ndarray
    start: np.ndarray

    @property
    def size(self) -> int:
        return int(self.obs.shape[0])

    @property
    def steps(self) -> int:
        return int(self.obs.shape[1]) - 1

    def take(self, idx: slice | np.ndarray) -> Windows:
        t = torch.as_tensor(np.arange(self.size)[idx])
        ctrl = None if self.control is None else self.control[t]
        return Windows(self.obs[t], ctrl, self.state.index(t), self.traj[t], self.start[t])


def cut_windows(
    nodes: np.ndarray, control: np.ndarray, grid: dict[str, np.ndarray], window: int
) -> Windows:
    """Non-overlapping windows of about ``window`` steps over every trajectory.

    ``nodes`` (N, T+1, 2R, 3), ``control`` (N, T, R, 3); initial states are read from
    ``grid``, rod states at every sample (N, T+1, R, ·) (the smoothing, or a previous
    fit). The length is adjusted so that ``T // window`` windows tile each trajectory
    (fewer than that many steps are left over at its end).
    """
    N, T1 = nodes.shape[:2]
    W = (T1 - 1) // max(1, (T1 - 1) // window)
    starts = np.arange(0, T1 - W, W)
    traj, start = np.repeat(np.arange(N), len(starts)), np.tile(starts, N)
    span = start[:, None] + np.arange(W + 1)
    obs = torch.as_tensor(nodes[traj[:, None], span], dtype=DTYPE)
    ctrl = control[traj[:, None], span[:, :-1]]
    state = State.from_numpy(*(grid[k][traj, start] for k in STATE_KEYS))
    ctrl_t = torch.as_tensor(ctrl, dtype=DTYPE) if np.any(ctrl != 0) else None
    return Windows(obs, ctrl_t, state, traj, start)


@torch.no_grad()
def fill_grid(
    engine: Engine, params: Params, windows: Windows, grid: dict[str, np.ndarray]
) -> None:
    """Write the rollout of every fitted window into ``grid`` (N, T+1, R, ·), in place."""
    roll = engine.rollout(windows.state, params, windows.steps, windows.control)
    span = windows.start[:, None] + np.arange(windows.steps + 1)
    for k, arr in roll.numpy().items():
        grid[k][windows.traj[:, None], span] = arr


def local_basis(axes: RodAxes, spin: bool = True) -> torch.Tensor:
    """Tangents of each window's initial state, (n_local, R, 12).

    Per rod: ``δp, δv`` (world), ``δθ`` (rotation vector), ``δω`` (both in the rod frame).
    The rotation about the axis holding the end caps is left out: it moves nothing.
    ``spin=False`` also leaves out the angular velocity about that axis (rod frame):
    it acts only through the tiny gyroscopic term ``I_axial ω_axial``, so short windows
    cannot tell it from noise.
    """
    R = len(axes.axis)
    rows = []
    for r in range(R):
        for j in range(12):
            if 6 <= j < 9 and j - 6 == axes.axis[r]:
                continue
            if j - 9 == axes.axis[r] and not spin:
                continue
            e = torch.zeros(R, 12, dtype=DTYPE)
            e[r, j] = 1.0
            rows.append(e)
    return torch.stack(rows)


def perturb(state: State, d: torch.Tensor) -> State:
    """``state ⊕ d`` for per-rod perturbations ``d`` (B, R, 12) (see :func:`local_basis`)."""
    dq = torch.cat([torch.ones_like(d[..., :1]), 0.5 * d[..., 6:9]], dim=-1)
    q = quat_mul(state.q, dq)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    d_omega = torch.einsum("brij,brj->bri", quat_to_matrix(state.q), d[..., 9:12])
    return State(state.p + d[..., 0:3], state.v + d[..., 3:6], q, state.omega + d_omega)


def end_caps(engine: Engine, p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """End-cap positions of rod poses ``p`` (..., R, 3), ``q`` (..., R, 4) -> (..., 2R, 3)."""
    arms = torch.einsum("...rij,rkj->...rki", quat_to_matrix(q), engine.end_offsets)
    return (p.unsqueeze(-2) + arms).flatten(-3, -2)


def window_residual(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor
) -> Callable[[torch.Tensor, torch.Tensor], torch.Tensor]:
    """``f(z, theta)``: engine end caps minus measured, (B, W+1, 2R, 3) [m].

    ``z`` (B, n_local) perturbs each window's initial state along ``basis``;
    ``theta`` (n_free,) are the free log-parameters.
    """

    def f(z: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
        state = perturb(win.state, torch.einsum("bl,lrj->brj", z, basis))
        roll = engine.rollout(state, vec.params(vec.full(theta)), win.steps, win.control)
        return end_caps(engine, roll.p, roll.q) - win.obs

    return f


# ---------------------------------------------------------------------- stage 2
@dataclass(frozen=True)
class NormalEquations:
    """Gauss-Newton normal equations with per-window (local) and parameter (global) blocks.

    Attributes:
        H_ll: (B, n_l, n_l); H_lg: (B, n_l, n_g); g_l: (B, n_l);
        H_gg: (n_g, n_g); g_g: (n_g,); sse: sum of squared residuals [m^2]; m: residuals.
    """

    H_ll: torch.Tensor
    H_lg: torch.Tensor
    g_l: torch.Tensor
    H_gg: torch.Tensor
    g_g: torch.Tensor
    sse: float
    m: int


def linearize(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor, theta: torch.Tensor,
    chunk: int, step: float = 1e-7, exact_gradient: bool = False,
) -> NormalEquations:  # fmt: skip
    """Gauss-Newton normal equations of all windows at ``theta`` and the current states.

    ``J`` comes from forward differences of step ``step`` along every local coordinate
    and every free log-parameter (:func:`gauss_newton_fd`). Its ~1e-7 relative error
    barely moves the optimum (the shift is ~1e-7 of a standard error; none on clean
    data, where the residual vanishes). ``exact_gradient`` replaces ``Jᵀr`` by the
    exact gradient (reverse mode through the engine), about twice the cost.
    """
    H_ll, H_lg, g_l = [], [], []
    n_g = len(theta)
    H_gg = torch.zeros(n_g, n_g, dtype=DTYPE)
    g_g = torch.zeros(n_g, dtype=DTYPE)
    sse, m = 0.0, 0
    for start in range(0, win.size, chunk):
        part = win.take(slice(start, start + chunk))
        ll, lg, gg, gl, gt, part_sse = gauss_newton_fd(engine, vec, part, basis, theta, step)
        if exact_gradient:
            z = torch.zeros(part.size, basis.shape[0], dtype=DTYPE, requires_grad=True)
            th = theta.clone().requires_grad_(True)
            r = window_residual(engine, vec, part, basis)(z, th)
            gl, gt = torch.autograd.grad(0.5 * (r * r).sum(), (z, th))
        H_ll.append(ll)
        H_lg.append(lg)
        g_l.append(gl)
        H_gg += gg
        g_g += gt
        sse += part_sse
        m += part.obs.numel()
    return NormalEquations(torch.cat(H_ll), torch.cat(H_lg), torch.cat(g_l), H_gg, g_g, sse, m)


@torch.no_grad()
def gauss_newton_fd(
    engine: Engine,
    vec: ParamVector,
    win: Windows,
    basis: torch.Tensor,
    theta: torch.Tensor,
    step: float,
    block: int = 25,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, float]:
    """``JᵀJ`` and ``Jᵀr`` by forward differences, and the sum of squares ``rᵀr`` [m^2].

    Returns ``H_ll`` (B, n_l, n_l), ``H_lg`` (B, n_l, n_g), ``H_gg`` (n_g, n_g), ``g_l``
    (B, n_l), ``g_g`` (n_g,) and ``rᵀr``. The windows and one perturbed copy per
    coordinate (``n_t = n_l + n_g``) are stepped as one batch of ``(n_t + 1) B`` (the
    parameters get a batch dimension); the products are accumulated every ``block``
    steps, so memory does not grow with the window length.
    """
    n_l, n_g, b = basis.shape[0], len(theta), win.size
    n_t = n_l + n_g
    eye = step * torch.eye(n_t, dtype=DTYPE).repeat_interleave(b, dim=0)
    z = torch.cat([torch.zeros(b, n_l, dtype=DTYPE), eye[:, :n_l]])
    th = torch.cat([theta.expand(b, n_g), theta + eye[:, n_l:]])
    state = State(*(x.repeat(n_t + 1, *([1] * (x.dim() - 1))) for x in win.state.tensors()))
    state = perturb(state, torch.einsum("bl,lrj->brj", z, basis))
    params = vec.params(vec.full(th))
    ctrl = None if win.control is None else win.control.repeat(n_t + 1, 1, 1, 1)
    H_ll = torch.zeros(b, n_l, n_l, dtype=DTYPE)
    H_lg = torch.zeros(b, n_l, n_g, dtype=DTYPE)
    H_gg = torch.zeros(n_g, n_g, dtype=DTYPE)
    g_l = torch.zeros(b, n_l, dtype=DTYPE)
    g_g = torch.zeros(n_g, dtype=DTYPE)
    sse, t0 = 0.0, 0
    caps = [end_caps(engine, state.p, state.q)]
    for t in range(win.steps):
        state = engine.step(state, params, None if ctrl is None else ctrl[:, t])
        caps.append(end_caps(engine, state.p, state.q))
        if len(caps) == block or t == win.steps - 1:
            x = torch.stack(caps, dim=1).reshape(n_t + 1, b, len(caps), -1)
            r = (x[0] - win.obs[:, t0 : t0 + len(caps)].flatten(2)).flatten(1)  # (b, m)
            J = (x[1:] - x[:1]).flatten(2) / step  # (n_t, b, m)
            Jl, Jg = J[:n_l], J[n_l:]
            H_ll += torch.einsum("ibm,jbm->bij", Jl, Jl)
            H_lg += torch.einsum("ibm,jbm->bij", Jl, Jg)
            H_gg += torch.einsum("ibm,jbm->ij", Jg, Jg)
            g_l += torch.einsum("ibm,bm->bi", Jl, r)
            g_g += torch.einsum("ibm,bm->i", Jg, r)
            sse += float((r * r).sum())
            t0, caps = t0 + len(caps), []
    return H_ll, H_lg, H_gg, g_l, g_g, sse


def _damped(H: torch.Tensor, lam: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``H + lam D + ε`` and the Marquardt scaling ``D = diag(H)``.

    ``ε = 1e-14 max(D)`` keeps directions the data does not see at all solvable.
    """
    d = torch.diagonal(H, dim1=-2, dim2=-1).clamp_min(0)
    floor = 1e-14 * d.amax(-1, keepdim=True).clamp_min(1e-300)
    return H + torch.diag_embed(lam * d + floor), d


def schur_step(
    ne: NormalEquations, lam: float
) -> tuple[torch.Tensor, torch.Tensor, float, torch.Tensor]:
    """Solve ``(H + lam D) δ = -g`` by eliminating the window states.

    Returns δz (B, n_l), δθ (n_g,), the predicted decrease of the sum of squares
    ``δᵀ(lam D δ - g)`` [m^2] and the reduced matrix ``S = A_gg - Σ H_gl A_ll⁻¹ H_lg``.
    """
    n_g = ne.H_gg.shape[0]
    (A_ll, D_l), (A_gg, D_g) = _damped(ne.H_ll, lam), _damped(ne.H_gg, lam)
    Y = torch.linalg.solve(A_ll, torch.cat([ne.H_lg, ne.g_l.unsqueeze(-1)], dim=-1))
    S = A_gg - torch.einsum("bli,blj->ij", ne.H_lg, Y[..., :n_g])
    b = -ne.g_g + torch.einsum("bli,bl->i", ne.H_lg, Y[..., n_g])
    S = 0.5 * (S + S.T)
    d_theta = torch.linalg.solve(S, b)
    d_z = -(Y[..., n_g] + torch.einsum("blj,j->bl", Y[..., :n_g], d_theta))
    pred = lam * ((D_l * d_z**2).sum() + (D_g * d_theta**2).sum())
    pred -= (ne.g_l * d_z).sum() + (ne.g_g * d_theta).sum()
    return d_z, d_theta, float(pred), S


@torch.no_grad()
def window_sse(
    engine: Engine, vec: ParamVector, win: Windows, basis: torch.Tensor, theta: torch.Tensor,
    chunk: int,
) -> float:  # fmt: skip
    """Sum of squared end-cap errors of all windows [m^2]."""
    total = 0.0
    for start in range(0, win.size, chunk):
        part = win.take(slice(start, start + chunk))
        z0 = torch.zeros(part.size, basis.shape[0], dtype=DTYPE)
        total += float((window_residual(engine, vec, part, basis)(z0, theta) ** 2).sum())
    return total


@dataclass(frozen=True)
class WindowFit:
    """Result of :func:`fit_windows`.

    Attributes:
        theta: fitted free log-parameters, (n_free,).
        windows: the windows with fitted initial states.
        history: mean squared end-cap error [m^2] at the start and after each iteration.
        stderr: standard error of each free log-parameter (= relative standard error of
            the parameter) from the Gauss-Newton covariance ``σ² S⁻¹``, (n_free,).
        score: the chi-square decrease the first Gauss-Newton step promised.
        converged: the stopping rule was met (not just ``max_iter``).
    """

    theta: torch.Tensor
    windows: Windows
    history: list[float]
    stderr: np.ndarray
    score: float
    converged: bool


def fit_windows(
    engine: Engine,
    vec: ParamVector,
    windows: Windows,
    theta: torch.Tensor,
    max_iter: int = 20,
    tol: float = 0.1,
    progress: Callable[[float], None] | None = None,
    exact_gradient: bool = False,
    spin: bool = True,
    gate: float | None = None,
) -> WindowFit:
    """Stage 2: Levenberg-Marquardt on window initial states and free log-parameters.

    Minimises the mean squared end-cap position error of all windows rolled out by
    ``engine`` (Nielsen's damping update, faster when the model is good). Stops when
    the full Gauss-Newton step would lower the chi-square ``sse / σ̂²`` by less than
    ``tol`` (the Newton decrement: 0.1 leaves every parameter well within a fraction
    of its standard error), when the RMS error reaches round-off (clean data), or
    after ``max_iter`` iterations (one Jacobian each). With ``gate``, nothing is done
    when the first step promises less than ``gate`` (a score test: the new unknowns
    cannot be told from noise). ``progress`` is called with the mean squared error
    after each iteration; ``exact_gradient``: see :func:`linearize`; ``spin``: see
    :func:`local_basis`.
    """
    basis = local_basis(vec.axes, spin)
    chunk = max(1, 6000 // (basis.shape[0] + len(theta) + 1))  # batch of the FD Jacobian
    ne = linearize(engine, vec, windows, basis, theta, chunk, exact_gradient=exact_gradient)
    dof = max(ne.m - len(theta) - windows.size * basis.shape[0], 1)
    history = [ne.sse / ne.m]
    exact = (1e-12 * max(1.0, float(windows.obs.abs().max()))) ** 2  # round-off [m^2]
    _, _, newton, S = schur_step(ne, 0.0)
    score = newton / max(ne.sse / dof, 1e-300)
    lo, hi = vec.start[vec.free] - LOG_BOX, vec.start[vec.free] + LOG_BOX
    done = score < tol or history[-1] < exact or (gate is not None and score < gate)
    lam, nu, converged = 1e-7, 2.0, done
    for _ in range(max_iter if not done else 0):
        while True:
            d_z, d_theta, pred, _ = schur_step(ne, lam)
            d_theta = (theta + d_theta).clamp(lo, hi) - theta
            d_state = torch.einsum("bl,lrj->brj", d_z, basis)
            trial = replace(windows, state=perturb(windows.state, d_state))
            sse = window_sse(engine, vec, trial, basis, theta + d_theta, chunk)
            rho = (ne.sse - sse) / pred if pred > 0 and np.isfinite(sse) else -1.0
            if rho > 0:
                lam *= 0.1 if rho > 0.9 else max(1 / 3, 1 - (2 * rho - 1) ** 3)
                nu = 2.0
                break
            lam, nu = lam * nu, nu * 2
            if lam > 1e10:
                break
        if lam > 1e10:
            converged = True  # no step lowers the error any more
            break
        windows, theta = trial, theta + d_theta
        ne = linearize(engine, vec, windows, basis, theta, chunk, exact_gradient=exact_gradient)
        _, _, newton, S = schur_step(ne, 0.0)
        history.append(ne.sse / ne.m)
        if progress is not None:
            progress(history[-1])
        if newton < tol * ne.sse / dof or history[-1] < exact:
            converged = True
            break
    stderr = _stderr(S, ne.sse / dof).numpy()
    return WindowFit(theta, windows, history, stderr, score, converged)


def _stderr(S: torch.Tensor, sigma2: float) -> torch.Tensor:
    """Standard errors ``sqrt(diag(σ² S⁻¹))`` of the parameters, (n_g,)."""
    return torch.sqrt(torch.diagonal(sigma2 * torch.linalg.pinv(S, hermitian=True)).clamp_min(0))


def window_schedule(first: int, last: int, factor: float = 4.0) -> list[int]:
    """Window lengths growing geometrically, by at most ``factor``, from ``first`` to ``last``."""
    if first >= last:
        return [last]
    n = int(np.ceil(np.log(last / first) / np.log(factor) - 1e-9))
    return [round(first * (last / first) ** (k / n)) for k in range(n + 1)]


# ---------------------------------------------------------------------- the estimator
class TrajectoryIdentifier:
    """Identification from (noisy) end caps: smoothing + regression, then trajectory fits.

    Stage 2 runs :func:`fit_windows` on windows growing from ``first_window`` to
    ``window`` steps (:func:`window_schedule`); each stage starts from the previous
    stage's parameters and, for its windows' initial states, from the previous
    stage's fitted trajectories. Short windows forgive a rough start; long windows
    carry far more information per sample (see the module notes).

    Args:
        anchors: known values fixing the common scale of M, I, K, c, h, e.g.
            ``{"mass[rod0]": 1.95}`` (see :func:`parse_anchors`). Without one, results
            are ratios to ``mass`` of the first rod (``mode_ == "ratios"``).
        window: steps per window in the final stage (capped at the trajectory length).
        smoothing: Savitzky-Golay window of stage 1 [s] (cubic).
        max_iter: Levenberg-Marquardt iterations per stage (one Jacobian each).
        seed: seed of the random window subset of the first stage.
        progress: show a progress bar over the iterations.
        first_window: steps per window in the first stage.
        max_windows: at most this many (random) windows in the first stage; None: all.
        gravity: known gravitational acceleration, (3,) [m/s^2].
        tol: the final windows' stages stop when the full Gauss-Newton step would lower
            the chi-square by less than this (earlier stages: 1); see :func:`fit_windows`.
        exact_gradient: use the reverse-mode gradient (see :func:`linearize`).
        threads: torch intra-op threads during ``fit`` (restored after); the tensors are
            small, so extra threads mostly add overhead (and stall on a busy machine).

    After ``fit``: ``params_`` (:class:`Params`), ``initial_params_`` (stage 1),
    ``history_`` (mean squared end-cap error [m^2] before the first and after each
    iteration, all stages), ``stages_`` (window length, windows, whether the axial
    spins were free, iterations and RMS error [m] per stage; the spin stage is skipped
    when a score test finds the spins invisible, and ``spin_fitted_`` says which),
    ``stderr_`` (relative standard error of each fitted
    parameter), ``notes_`` (parameter name -> why the data cannot identify it; its value
    in ``params_`` is assumed, for simulation only), ``rms_`` (final end-cap RMS error
    [m], an estimate of the measurement noise), ``mode_``, ``converged_``.
    """

    def __init__(
        self,
        anchors: Mapping[str, float] | None = None,
        window: int = 1000,
        smoothing: float = 0.1,
        max_iter: int = 20,
        seed: int = 0,
        progress: bool = False,
        first_window: int = 100,
        max_windows: int | None = 64,
        gravity: Sequence[float] = (0.0, 0.0, -9.81),
        tol: float = 0.1,
        exact_gradient: bool = False,
        threads: int | None = 1,
    ) -> None:
        if min(window, first_window) < 1 or max_iter < 0 or not smoothing > 0:
            raise InputError("windows >= 1 step, max_iter >= 0 and smoothing > 0 are required")
        self.anchors = dict(anchors or {})
        self.window = int(window)
        self.smoothing = float(smoothing)
        self.max_iter = int(max_iter)
        self.seed = seed
        self.progress = progress
        self.first_window = int(first_window)
        self.max_windows = max_windows
        self.gravity = tuple(float(g) for g in gravity)
        self.tol = tol
        self.exact_gradient = exact_gradient
        self.threads = threads

    def fit(self, dataset: Dataset, split: str = "train") -> TrajectoryIdentifier:
        """Identify the parameters from the end caps (and control) of ``split``."""
        threads = torch.get_num_threads()
        try:
            if self.threads is not None:
                torch.set_num_threads(self.threads)
            return self._fit(dataset, split)
        finally:
            torch.set_num_threads(threads)

    def _fit(self, dataset: Dataset, split: str) -> TrajectoryIdentifier:
        topo, data = dataset.topology, dataset.split(split)
        axes = RodAxes.of(topo)
        anchors = parse_anchors(topo, self.anchors)
        sg = _odd(self.smoothing / dataset.dt)
        smooth = smooth_rod_states(data.nodes, dataset.dt, axes, sg)
        start = smoothed_regression(topo, smooth, data.control, self.anchors, self.gravity)
        has_control = bool(np.any(data.control != 0))
        vec = self._vector(topo, axes, start, anchors, has_control)
        engine = Engine(topo, dataset.dt)
        grid = {k: getattr(smooth, k).copy() for k in STATE_KEYS}
        theta = vec.start[vec.free]
        schedule = window_schedule(self.first_window, min(self.window, data.n_transitions))
        self.history_, self.stages_ = [], []
        bar = tqdm(
            total=self.max_iter * (len(schedule) + 1), desc="trajectory fit", unit="it",
            disable=not self.progress,
        )  # fmt: skip
        # the axial spins are fitted last, on the final windows, if the data can see them
        plan = [(W, False) for W in schedule] + [(schedule[-1], True)]
        self.spin_fitted_ = False
        for k, (W, spin) in enumerate(plan):
            windows = cut_windows(data.nodes, data.control, grid, W)
            if k == 0 and self.max_windows is not None and windows.size > self.max_windows:
                rng = np.random.default_rng(self.seed)
                windows = windows.take(np.sort(rng.choice(windows.size, self.max_windows, False)))

            def tick(mse: float, W: int = W) -> None:
                bar.update(1)
                bar.set_postfix(window=W, rms=f"{np.sqrt(mse):.3e} m")

            n_spin = windows.size * topo.n_rods if spin else 0
            gate = n_spin + 3 * np.sqrt(2 * n_spin) if spin else None  # chi2(n_spin) + 3 sd
            tol = self.tol if k >= len(schedule) - 1 else 1.0
            fit = fit_windows(
                engine, vec, windows, theta, self.max_iter, tol, tick, self.exact_gradient,
                spin=spin, gate=gate,
            )  # fmt: skip
            if spin and gate is not None and fit.score < gate:  # spins invisible: keep 0
                self.stages_.append(
                    {"window": windows.steps, "windows": windows.size, "spin": True,
                     "iterations": 0,
                     "skipped": f"score test: chi2 gain {fit.score:.1f} < {gate:.1f} "
                     f"for {n_spin} axial spins, which stay 0"}
                )  # fmt: skip
                break
            self.spin_fitted_ = spin
            final, theta = fit, fit.theta
            fill_grid(engine, vec.params(vec.full(theta)), fit.windows, grid)
            self.history_ += fit.history if k == 0 else fit.history[1:]
            self.stages_.append(
                {"window": windows.steps, "windows": windows.size, "spin": spin,
                 "iterations": len(fit.history) - 1, "rms": float(np.sqrt(fit.history[-1]))}
            )  # fmt: skip
        bar.total = bar.n
        bar.close()
        self.topology_, self.dt_ = topo, dataset.dt
        self.vector_ = vec
        self.params_ = vec.params(vec.full(theta).detach())
        self.initial_params_ = vec.params(vec.start)
        self.converged_ = final.converged
        self.windows_ = final.windows
        self.rms_ = float(np.sqrt(self.history_[-1]))
        names = vec.names()
        free = torch.nonzero(vec.free)[:, 0].tolist()
        self.stderr_ = {names[i]: float(s) for i, s in zip(free, final.stderr, strict=True)}
        self.notes_ = self._notes(topo, axes, has_control)
        return self

    def _vector(
        self, topo: Topology, axes: RodAxes, start: dict[str, np.ndarray],
        anchors: dict[tuple[str, int], float], has_control: bool,
    ) -> ParamVector:  # fmt: skip
        """Log-parameter vector: stage-1 values (repaired where unusable), anchors fixed."""
        values, free = [], []
        self.mode_ = "anchored"
        if not any(g != "rest_length" for g, _ in anchors):
            anchors = {**anchors, ("mass", 0): 1.0}
            self.mode_ = "ratios"
        for group in GROUPS:
            v = np.array(start[group], dtype=float)
            good = np.isfinite(v) & (v > 0)
            v[~good] = np.median(v[good]) if good.any() else 1.0
            fixed = np.zeros(len(v), dtype=bool)
            for (g, i), value in anchors.items():
                if g == group:
                    v[i], fixed[i] = value, True
            if group == "control_gain" and not has_control:
                v[:], fixed[:] = 1.0, True
            values.append(v)
            free.append(~fixed)
        return ParamVector(
            topology=topo,
            axes=axes,
            start=torch.as_tensor(np.log(np.concatenate(values)), dtype=DTYPE),
            free=torch.as_tensor(np.concatenate(free)),
            gravity=torch.tensor(self.gravity, dtype=DTYPE),
        )

    @staticmethod
    def _notes(topo: Topology, axes: RodAxes, has_control: bool) -> dict[str, str]:
        notes = {
            f"inertia[{rod.name},{'xyz'[k]}]": (
                "axial inertia: spin about the axis through both end caps is invisible in "
                "end-cap data; not identifiable (value in params_ is the assumed solid "
                "cylinder M r^2/2, for simulation only)"
            )
            for rod, k in zip(topo.rods, axes.axis, strict=True)
        }
        if not has_control:
            notes["control_gain"] = "no control in this data; not identifiable (assumed 1)"
        return notes

    @property
    def unidentifiable(self) -> list[str]:
        """Names of the parameters the data cannot identify (see ``notes_``)."""
        return list(self.notes_)
