"""A small residual network: absorbs structure no physical effect explains. NOT PHYSICAL.

When the residual loop (:mod:`identification.discovery.loop`) stops with structure left on
noise-free data, no candidate of the library explains it. :class:`ResidualNetwork` is
the paper's "future work" escape hatch: a small MLP, shared by all rods, mapping each
rod's state features to an extra force and torque about its centre of mass (world
frame). It has no physical parameters and no units to interpret; reports list it as
**unexplained**, never as a named effect.

Per-rod input features (world frame, 12 values), chosen so that the usual missing
physics can show through:

====================  =====  =========================================================
feature               size   reveals
====================  =====  =========================================================
COM height ``p_z``    1      height-dependent fields, the floor
velocity ``v``        3      drag (translational)
angular vel. ``ω``    3      drag (rotational)
end-cap heights       2      contact at the end caps
rod axis ``â``        3      anisotropic (per-axis) effects, from cap 0 to cap 1
====================  =====  =========================================================

The network's last layer is linear, so the effect is a
:class:`~tensegrity_env.effects.base.LinearEffect` in its readout weights θ (6 outputs
x (hidden + 1)): with the hidden layers held, θ joins the regression's design matrix
and is solved jointly with the declared parameters, like any linear effect
(``identification.discovery.residual_network``). Inputs are standardised, outputs scaled, by
buffers stored with the weights, so the state dict alone rebuilds the network. The
weights live in a sidecar file beside a params file (``torch.save`` of
:meth:`ResidualNetwork.state`, written atomically); the params file's ``effects``
list holds a reference::

    {"name": "residual_network", "sidecar": "residual_network.pt", "unexplained": true,
     "params": {}, "units": {}, "uncertainty": {}, "note": "..."}

It is not in :data:`tensegrity_env.effects.EFFECTS` (the registry of physical
candidates with named parameters); :func:`tensegrity_env.effects.effect_from_dict`
knows it by name and loads the sidecar relative to its ``root`` argument (the params
file's directory).
"""

from __future__ import annotations

import copy
import itertools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from tensegrity_env.effects.base import LinearEffect, ParamSpec
from tensegrity_env.engine.kinematics import Kinematics
from tensegrity_env.engine.state import State
from tensegrity_env.io_utils import InputError, atomic_path
from tensegrity_env.params import Params
from tensegrity_env.topology import Topology

#: per-rod input features (see the module docstring)
FEATURES: tuple[str, ...] = (
    "p_z", "v_x", "v_y", "v_z", "omega_x", "omega_y", "omega_z",
    "cap0_z", "cap1_z", "axis_x", "axis_y", "axis_z",
)  # fmt: skip
#: per-rod outputs: force [N] then torque [N*m], world frame
OUTPUTS: tuple[str, ...] = ("F_x", "F_y", "F_z", "tau_x", "tau_y", "tau_z")
#: default file name of the weights, beside the params file
SIDECAR = "residual_network.pt"
#: the sentence every report prints next to it
NOT_PHYSICAL = "unexplained: a fitted neural network, NOT a physical effect"
_ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "silu": nn.SiLU}


class ResidualMLP(nn.Module):
    """``x (…, 12) -> (force, torque) (…, 6)`` with standardisation buffers, float64.

    Args:
        hidden: widths of the hidden layers.
        activation: ``"tanh"`` or ``"silu"``.

    Buffers ``in_mean``, ``in_scale`` (12,) and ``out_mean``, ``out_scale`` (6,):
    ``y = out_mean + out_scale * mlp((x - in_mean) / in_scale)``.
    """

    in_mean: torch.Tensor
    in_scale: torch.Tensor
    out_mean: torch.Tensor
    out_scale: torch.Tensor
    mlp: nn.Sequential

    def __init__(self, hidden: Sequence[int] = (32, 32), activation: str = "tanh") -> None:
        super().__init__()
        if activation not in _ACTIVATIONS:
            raise InputError(f"residual network: unknown activation '{activation}'")
        self.hidden = tuple(int(h) for h in hidden)
        self.activation = activation
        widths = (len(FEATURES), *self.hidden)
        layers: list[nn.Module] = []
        for a, b in itertools.pairwise(widths):
            layers += [nn.Linear(a, b, dtype=torch.float64), _ACTIVATIONS[activation]()]
        layers.append(nn.Linear(widths[-1], len(OUTPUTS), dtype=torch.float64))
        self.mlp = nn.Sequential(*layers)
        f64 = torch.float64
        self.register_buffer("in_mean", torch.zeros(len(FEATURES), dtype=f64))
        self.register_buffer("in_scale", torch.ones(len(FEATURES), dtype=f64))
        self.register_buffer("out_mean", torch.zeros(len(OUTPUTS), dtype=f64))
        self.register_buffer("out_scale", torch.ones(len(OUTPUTS), dtype=f64))

    def set_scaling(self, x: torch.Tensor, y: torch.Tensor) -> None:
        """Standardise by the training inputs ``x`` (n, 12) and targets ``y`` (n, 6)."""

        def scale(t: torch.Tensor) -> torch.Tensor:
            s = t.std(0)
            return torch.where(s > 1e-12 * (1 + t.abs().max()), s, torch.ones_like(s))

        with torch.no_grad():
            self.in_mean.copy_(x.mean(0))
            self.in_scale.copy_(scale(x))
            self.out_mean.copy_(y.mean(0))
            self.out_scale.copy_(scale(y))

    def hidden_features(self, x: torch.Tensor) -> torch.Tensor:
        """Last hidden layer's activations and a constant 1, (…, H + 1)."""
        h = self.mlp[:-1]((x - self.in_mean) / self.in_scale)
        return torch.cat([h, torch.ones_like(h[..., :1])], dim=-1)

    @property
    def readout(self) -> nn.Linear:
        """The last (linear) layer."""
        last = self.mlp[-1]
        assert isinstance(last, nn.Linear)
        return last

    def standardised(self, x: torch.Tensor) -> torch.Tensor:
        """The MLP's raw output on standardised inputs (the training target's scale)."""
        result: torch.Tensor = self.mlp((x - self.in_mean) / self.in_scale)
        return result

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out_mean + self.out_scale * self.standardised(x)


def rod_features(state: State, kin: Kinematics) -> torch.Tensor:
    """Per-rod network inputs (B, R, 12), world frame [m, m/s, rad/s, m, -]."""
    caps = state.p.unsqueeze(2) + kin.arms  # (B, R, 2, 3)
    axis = kin.arms[:, :, 1] - kin.arms[:, :, 0]
    axis = axis / torch.linalg.vector_norm(axis, dim=-1, keepdim=True).clamp_min(1e-12)
    return torch.cat([state.p[..., 2:], state.v, state.omega, caps[..., 2], axis], dim=-1)


class ResidualNetwork(LinearEffect):
    """Extra per-rod force (B, R, 3) [N] and torque (B, R, 3) [N*m] from a small MLP.

    Not a physical effect (see the module docstring): no named physical parameters,
    reported as unexplained. Linear in the readout θ (:meth:`theta`), so it can join
    the regression with the hidden layers held.

    Args:
        topology: the assembly.
        network: the MLP (a fresh, untrained one if None).
        sidecar: file name of the weights, relative to the params file's directory.
        info: what the fit measured (errors before and after; written into the entry).
    """

    name: ClassVar[str] = "residual_network"
    summary: ClassVar[str] = (
        "UNEXPLAINED: a small neural network absorbing what no candidate explains "
        "(not a physical effect)"
    )
    PARAMS: ClassVar[dict[str, ParamSpec]] = {}

    def __init__(
        self,
        topology: Topology,
        network: ResidualMLP | None = None,
        sidecar: str = SIDECAR,
        info: Mapping[str, Any] | None = None,
        uncertainty: Mapping[str, Any] | None = None,
        *,
        validate: bool = True,
        **values: Any,
    ) -> None:
        super().__init__(topology, uncertainty, validate=validate, **values)
        self.network = network if network is not None else ResidualMLP()
        self.sidecar = str(sidecar)
        self.info: dict[str, Any] = dict(info or {})

    def wrench(
        self,
        state: State,
        kin: Kinematics,
        params: Params,
        applied: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        x = rod_features(state, kin)
        out = self.network(x.to(torch.float64)).to(state.p)
        return out[..., :3], out[..., 3:]

    # ------------------------------------------------------------------ linear readout
    def basis(
        self, state: State, kin: Kinematics, params: Params
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Force (B, R, 3, P) [N/unit] and torque (B, R, 3, P) [N*m/unit] per readout entry.

        ``P = 6 (H + 1)``; entry ``(i, j)`` moves output ``i`` by ``out_scale_i h_j``.
        ``out_mean`` is a fixed offset outside the basis (zero in a joint fit). Not
        differentiable in the hidden layers (they are held).
        """
        net = self.network
        with torch.no_grad():
            h = net.hidden_features(rod_features(state, kin).to(torch.float64)).to(state.p)
        B, R, K = h.shape
        eye = torch.eye(6, dtype=h.dtype, device=h.device) * net.out_scale.to(h)[:, None]
        full = (eye[None, None, :, :, None] * h[:, :, None, None, :]).reshape(B, R, 6, 6 * K)
        return full[:, :, :3], full[:, :, 3:]

    def theta(self) -> torch.Tensor:
        """Readout weights and biases, (6 (H + 1),): row i = output i, last column the bias."""
        lin = self.network.readout
        return torch.cat([lin.weight, lin.bias[:, None]], dim=1).reshape(-1).detach()

    def theta_lower(self) -> torch.Tensor:
        """No bound on the readout, (6 (H + 1),)."""
        return torch.full_like(self.theta(), -np.inf, dtype=torch.float64)

    def theta_names(self) -> list[str]:
        K = self.network.readout.in_features + 1
        return [f"{o}[{'bias' if j == K - 1 else j}]" for o in OUTPUTS for j in range(K)]

    def with_theta(self, theta: Any, stderr: Any = None) -> ResidualNetwork:
        """A copy (own network) with the readout replaced; ``stderr`` is not kept."""
        net = copy.deepcopy(self.network)
        lin = net.readout
        t = torch.as_tensor(np.asarray(theta, dtype=float)).reshape(lin.out_features, -1)
        with torch.no_grad():
            lin.weight.copy_(t[:, :-1])
            lin.bias.copy_(t[:, -1])
        return ResidualNetwork(self.topology, net, self.sidecar, self.info)

    def with_values(self, validate: bool = True, **values: Any) -> ResidualNetwork:
        """A copy sharing the network (it has no physical parameters to replace)."""
        if values:
            raise InputError("effect 'residual_network' has no physical parameters")
        return ResidualNetwork(self.topology, self.network, self.sidecar, self.info)

    def n_weights(self) -> int:
        """Number of trained weights (for an information criterion)."""
        return sum(p.numel() for p in self.network.parameters())

    # ------------------------------------------------------------------ (de)serialise
    def state(self) -> dict[str, Any]:
        """What the sidecar holds: architecture, feature names and the state dict."""
        return {
            "format": "tensegrity-sr residual network",
            "hidden": list(self.network.hidden),
            "activation": self.network.activation,
            "features": list(FEATURES),
            "outputs": list(OUTPUTS),
            "state_dict": {k: v.detach().cpu() for k, v in self.network.state_dict().items()},
        }

    def save(self, directory: str | Path) -> Path:
        """Write the weights to ``directory / sidecar`` atomically; returns the path."""
        path = Path(directory) / self.sidecar
        with atomic_path(path) as tmp:
            torch.save(self.state(), tmp)
        return path

    def to_dict(self) -> dict[str, Any]:
        """The params-file entry: a reference to the sidecar, marked unexplained."""
        return {
            "name": self.name,
            "unexplained": True,
            "note": NOT_PHYSICAL,
            "sidecar": self.sidecar,
            "hidden": list(self.network.hidden),
            "activation": self.network.activation,
            "features": list(FEATURES),
            "params": {},
            "units": {},
            "uncertainty": {},
            "info": self.info,
        }

    @classmethod
    def from_dict(
        cls, doc: Mapping[str, Any], topology: Topology, root: str | Path | None = None
    ) -> ResidualNetwork:
        """Load the sidecar named in ``doc`` (relative to ``root``, else the working dir)."""
        sidecar = str(doc.get("sidecar", SIDECAR))
        path = Path(sidecar) if root is None else Path(root) / sidecar
        if not path.is_file():
            raise InputError(
                f"effect 'residual_network': weights file {path} not found (pass the params "
                "file's directory as root to effects_from_document)"
            )
        return cls.load(path, topology, info=doc.get("info"))

    @classmethod
    def load(
        cls, path: str | Path, topology: Topology, info: Mapping[str, Any] | None = None
    ) -> ResidualNetwork:
        """Rebuild from a sidecar file written by :meth:`save`."""
        try:
            blob = torch.load(Path(path), map_location="cpu", weights_only=True)
            if list(blob["features"]) != list(FEATURES):
                raise InputError(f"{path}: the network's features differ from this version's")
            net = ResidualMLP(blob["hidden"], blob["activation"])
            net.load_state_dict(blob["state_dict"])
            net.requires_grad_(False)  # for use; still differentiable in the state
        except (KeyError, RuntimeError, TypeError, EOFError) as e:
            raise InputError(f"{path}: not a residual-network file ({e})") from None
        return cls(topology, net, sidecar=Path(path).name, info=info)

    def describe(self) -> str:
        """One line: what it is, its size, and that it is not physical."""
        sizes = "-".join(str(n) for n in (len(FEATURES), *self.network.hidden, len(OUTPUTS)))
        return f"{self.name}: MLP {sizes} ({self.network.activation}), {NOT_PHYSICAL}"
