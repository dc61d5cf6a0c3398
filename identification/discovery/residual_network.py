"""Fit a residual network to the wrench the model is missing (reported as unexplained).

On clean data a transition ``t -> t+1`` of MuJoCo's semi-implicit Euler gives the
accelerations that produced it exactly (:mod:`identification.linear.features`):
``a = (v_{t+1} - v_t) / dt`` and ``α_l = (ω_l,{t+1} - ω_l,t) / dt`` in the rod frame.
The engine with a model (params + effects) predicts ``a_m`` and ``α_l,m`` at state
``t``; an extra wrench enters them linearly (``a = F/M + g``,
``α_l = I⁻¹(Rᵀτ - ω_l × Iω_l)``), so the wrench the model is missing is, per rod,

* force ``ΔF = M (a - a_m)`` [N], world frame;
* torque ``Δτ = R I (α_l - α_l,m)`` [N*m], world frame.

Fitting a network to that residual with the identified parameters held absorbs
almost nothing: the regression has already folded the missing effect into biased
``K, c, M, I`` (with drag planted and no drag candidate, masses come out 2-6x too
small), and what is left depends on the whole configuration, not on one rod's state
(measured on planted linear drag: held-out one-step 3.44e-6 m -> 3.40e-6 m). So
:func:`fit_residual_network` fits it **jointly**:

1. the network's readout is linear (:class:`ResidualNetwork` is a
   :class:`~tensegrity_env.effects.base.LinearEffect`): with seeded random hidden
   layers it joins the regression's design matrix and is solved together with the
   declared parameters and the model's linear effects (exact least squares, one
   regression: :class:`~identification.linear.extended.ExtendedIdentifier`);
2. then every layer is fine-tuned by Adam on ``(ΔF, Δτ)`` of the refitted model
   (mean-square error of scaled targets, minibatches, early stopping on the
   validation split; the least-squares readout is the starting point and is kept if
   Adam does not beat it).

The refitted declared parameters belong to the network (the pair predicts; neither
alone): they are returned beside it, while the loop's physical model and its params
file stay as identified. How far they move is reported (``moved``): a large move says
the identified values were biased by whatever the network absorbs.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from identification.data.dataset import Dataset
from identification.discovery.library import FitSettings
from identification.linear.extended import ExtendedIdentifier, acting_split, evaluate_model
from identification.linear.features import (
    cable_commands_at,
    drawn_transitions,
    transition_features,
    transitions_of,
)
from identification.trajectory.fitted_model import FittedModel
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.effects.residual_network import ResidualMLP, ResidualNetwork, rod_features
from tensegrity_env.engine import Engine
from tensegrity_env.engine.kinematics import AttachmentPoints, node_kinematics
from tensegrity_env.params import Params

DTYPE = torch.float64


@dataclass
class ResidualFit:
    """A fitted residual network, the declared parameters refitted with it, and errors.

    Attributes:
        effect: the network as an engine effect.
        params: the declared parameters refitted jointly with the network.
        effects: the model's effects refitted with it, the network included (the
            model that predicts is ``(params, effects)``).
        before, after: per split (``"val"``, ``"test"``), the errors of
            :func:`~identification.linear.extended.evaluate_model` of the loop's model and of
            ``(params, effects)`` (``one_step``, ``rollout`` [m]; no per-step curve).
        moved: relative change ``‖p' - p‖ / ‖p‖`` of each declared parameter group
            (stiffness, damping, mass, inertia) from the loop's values [-].
        train_loss, val_loss: mean-square error of the scaled residual targets of the
            refitted model at the kept weights [-] (training / validation split).
        steps: Adam steps taken; ``best_step``: the step of the kept weights (0: the
            least-squares readout).
        samples: rod samples (transitions x rods) fine-tuned on.
        seconds: wall time of the fit [s].
    """

    effect: ResidualNetwork
    params: Params
    effects: list[PhysicalEffect]
    before: dict[str, dict[str, float]]
    after: dict[str, dict[str, float]]
    moved: dict[str, float]
    train_loss: float
    val_loss: float
    steps: int
    best_step: int
    samples: int
    seconds: float
    settings: dict[str, Any] = field(default_factory=dict)

    def gain(self, split: str = "test", key: str = "one_step") -> float:
        """``before / after`` of an error on a split (> 1: the network lowers it)."""
        return self.before[split][key] / max(self.after[split][key], 1e-300)

    def summary(self) -> dict[str, Any]:
        """JSON-able numbers (for the params file and the sidecar entry's ``info``)."""
        return {
            "before": self.before,
            "after": self.after,
            "moved": self.moved,
            "train_loss": self.train_loss,
            "val_loss": self.val_loss,
            "steps": self.steps,
            "best_step": self.best_step,
            "samples": self.samples,
            "seconds": self.seconds,
            **self.settings,
        }


def missing_wrench(
    dataset: Dataset,
    model: FittedModel,
    split: str = "train",
    max_transitions: int = 20_000,
    seed: int = 0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Network inputs and the wrench the model is missing, per rod sample.

    Returns features (n*R, 12) (see
    :func:`~tensegrity_env.effects.residual_network.rod_features`) and targets
    (n*R, 6): force [N] then torque [N*m], world frame, on a random subset of
    ``max_transitions`` transitions of the split.
    """
    data = dataset.split(split)
    topo = dataset.topology
    idx = drawn_transitions(data, max_transitions, seed)
    acting = acting_split(model.effects, data, dataset.dt)
    s0, s1, u = transitions_of(acting, idx)
    cables = cable_commands_at(acting, idx)
    feat = transition_features(topo, s0, s1, u, dataset.dt, cables)
    engine = Engine(topo, dataset.dt, effects=model.effects)
    with torch.no_grad():
        acc, alpha_l, _ = engine.accelerations(s0, model.params, u, cables)
    params = model.params
    force = params.mass.detach()[None, :, None] * (feat.accel - acc)
    torque_l = params.inertia.detach() * (feat.alpha_local - alpha_l)
    torque = torch.einsum("nrij,nrj->nri", feat.rot, torque_l)
    kin = node_kinematics(
        s0,
        torch.as_tensor(topo.end_offsets, dtype=DTYPE),
        torch.as_tensor(topo.anchor_positions, dtype=DTYPE),
        AttachmentPoints.of(topo),
    )
    x = rod_features(s0, kin)
    y = torch.cat([force, torque], dim=-1)
    return x.reshape(-1, x.shape[-1]).detach(), y.reshape(-1, y.shape[-1]).detach()


def fit_residual_network(
    dataset: Dataset,
    model: FittedModel,
    settings: FitSettings | None = None,
    split: str = "train",
    val_split: str = "val",
    eval_splits: Sequence[str] = ("val", "test"),
    hidden: Sequence[int] = (32, 32),
    activation: str = "tanh",
    max_steps: int = 2000,
    batch_size: int = 1024,
    lr: float = 1e-3,
    eval_every: int = 100,
    patience: int = 5,
    max_transitions: int = 20_000,
    horizon_s: float = 1.0,
    seed: int = 0,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> ResidualFit:
    """Fit a residual network jointly with the declared parameters (module docstring).

    Args:
        dataset: clean data with rod states.
        model: the loop's model (params + effects); not changed.
        settings: anchors and starting params of the regression (those of the loop).
        split, val_split: training split and the early-stopping split.
        eval_splits: held-out splits measured before / after (those present).
        hidden, activation: the MLP (:class:`ResidualMLP`).
        max_steps, batch_size, lr: Adam fine-tuning on minibatches of rod samples
            (``max_steps=0``: the least-squares readout only).
        eval_every, patience: check the validation loss every ``eval_every`` steps;
            stop after ``patience`` checks without improvement (best weights kept).
        max_transitions: transitions sampled per split for the fine-tuning targets.
        horizon_s: rollout horizon of the held-out errors [s].
        seed: seed of the weights, the transition subsets and the minibatches.
        progress: show a tqdm bar while fine-tuning.
        log: where to print one summary line (None: silent).
    """
    t0 = time.perf_counter()
    settings = settings or FitSettings()
    if val_split not in dataset.splits:
        val_split = split
    topo = dataset.topology
    torch.manual_seed(seed)
    # 1. random hidden layers, scaled by the loop model's residual; readout solved jointly
    net = ResidualMLP(hidden, activation)
    x, y = missing_wrench(dataset, model, split, max_transitions, seed)
    net.set_scaling(x, y)
    with torch.no_grad():
        net.out_mean.zero_()  # a fixed offset would sit outside the regression's basis
        net.readout.weight.zero_()
        net.readout.bias.zero_()
    start = ResidualNetwork(topo, net)
    others = [e for e in model.effects if not e.constraint]
    contact = [e for e in model.effects if e.constraint]
    est = ExtendedIdentifier(
        effects=[*others, start, *contact], reference=model.params, anchors=settings.anchors,
        init_params=settings.init_params, fit_rest_length=settings.fit_rest_length,
        iterations=5, chunk_size=500,
    ).fit(dataset, split)  # fmt: skip
    effects = list(est.effects_)
    k = len(others)
    fitted = effects[k]
    assert isinstance(fitted, ResidualNetwork)  # narrowing: the fit keeps each effect's class
    net = fitted.network
    params = est.params_
    physical = FittedModel(
        model.model.replace(params=params, effects=[e for i, e in enumerate(effects) if i != k]),
        model.n_params,
    )
    # 2. fine-tune every layer on what the refitted model still misses
    x, y = missing_wrench(dataset, physical, split, max_transitions, seed)
    xv, yv = missing_wrench(dataset, physical, val_split, max_transitions // 2, seed + 1)
    ys, yvs = y / net.out_scale, yv / net.out_scale
    best, best_step, step, n = _val_loss(net, xv, yvs), 0, 0, x.shape[0]
    best_state = copy.deepcopy(net.state_dict())
    if max_steps > 0:
        best, best_state, best_step, step = _finetune(
            net, x, ys, xv, yvs, max_steps, batch_size, lr, eval_every, patience, seed, progress
        )
    net.load_state_dict(best_state)
    net.eval()
    net.requires_grad_(False)  # trained: engines using it need no graph through its weights
    with torch.no_grad():
        train_loss = float(((net.standardised(x) - ys) ** 2).mean())
    effect = ResidualNetwork(topo, net)
    effects[k] = effect
    before: dict[str, Any] = {}
    after: dict[str, Any] = {}
    for s in eval_splits:
        if s not in dataset.splits:
            continue
        for out, (p, eff) in ((before, (model.params, model.effects)), (after, (params, effects))):
            e = evaluate_model(topo, p, eff, dataset, s, horizon_s)
            out[s] = {key: float(v) for key, v in e.items() if key != "curve"}
    moved = {
        f: float(torch.linalg.vector_norm(getattr(params, f) - getattr(model.params, f))
                 / torch.linalg.vector_norm(getattr(model.params, f)).clamp_min(1e-300))
        for f in ("stiffness", "damping", "mass", "inertia")
    }  # fmt: skip
    fit = ResidualFit(
        effect=effect, params=params, effects=effects, before=before, after=after, moved=moved,
        train_loss=train_loss, val_loss=best, steps=step, best_step=best_step, samples=int(n),
        seconds=time.perf_counter() - t0,
        settings={"hidden": list(net.hidden), "activation": activation, "lr": lr,
                  "batch_size": batch_size, "seed": seed},
    )  # fmt: skip
    effect.info = fit.summary()
    if log is not None and after:
        key = "test" if "test" in after else next(iter(after))
        log(f"residual network ({fit.seconds:.1f} s, Adam best at step {best_step}): held-out "
            f"({key}) one-step {before[key]['one_step']:.3e} m -> {after[key]['one_step']:.3e} m "
            f"({fit.gain(key):.3g}x); unexplained, NOT a physical effect")  # fmt: skip
    return fit


def _val_loss(net: ResidualMLP, xv: torch.Tensor, yvs: torch.Tensor) -> float:
    with torch.no_grad():
        return float(((net.standardised(xv) - yvs) ** 2).mean())


def _finetune(
    net: ResidualMLP, x: torch.Tensor, ys: torch.Tensor, xv: torch.Tensor, yvs: torch.Tensor,
    max_steps: int, batch_size: int, lr: float, eval_every: int, patience: int, seed: int,
    progress: bool,
) -> tuple[float, dict[str, torch.Tensor], int, int]:  # fmt: skip
    """Adam on minibatches with early stopping; returns (best val loss, its weights, its
    step, steps taken). Step 0 (the starting weights) competes too."""
    gen = torch.Generator().manual_seed(seed)
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    best, best_state, best_step, bad, step = _val_loss(net, xv, yvs), None, 0, 0, 0
    best_state = copy.deepcopy(net.state_dict())
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_steps, desc="residual network", leave=False)
    n = x.shape[0]
    for step in range(1, max_steps + 1):
        i = torch.randint(0, n, (min(batch_size, n),), generator=gen)
        loss = ((net.standardised(x[i]) - ys[i]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        if bar is not None:
            bar.update()
        if step % eval_every == 0:
            v = _val_loss(net, xv, yvs)
            if bar is not None:
                bar.set_postfix(val=f"{v:.3g}")
            if v < best:
                best, best_state, best_step, bad = v, copy.deepcopy(net.state_dict()), step, 0
            else:
                bad += 1
                if bad >= patience:
                    break
    if bar is not None:
        bar.close()
    return best, best_state, best_step, step
