"""The shared training helper of the MLP baselines: normalisation, MLPs, Adam, early stopping.

Training minimises the mean squared error of standardised one-step targets with Adam
and a cosine learning-rate schedule; after every epoch the validation loss is measured
and the best weights are kept; training stops after ``patience`` epochs without
improvement. Every number is recorded in :class:`History` (the training curve).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from torch import nn
from tqdm.auto import tqdm


@dataclass(frozen=True)
class TrainConfig:
    """Hyperparameters of one MLP baseline.

    Attributes:
        hidden: width of every hidden layer.
        layers: hidden layers per MLP.
        lr: peak Adam learning rate (cosine-decayed to ``lr * lr_floor``).
        lr_floor: final learning rate as a fraction of ``lr``.
        weight_decay: Adam weight decay.
        batch: transitions per gradient step.
        epochs: maximum passes over the training transitions.
        patience: epochs without a better validation loss before stopping.
        max_train: training transitions used (a random subset; None: all).
        max_val: validation transitions used for early stopping (random subset).
        seed: seed of the subsets, the initial weights and the batch order.
        threads: torch CPU threads while training (small MLPs run fastest on one,
            and far faster than on several when other work shares the cores).
    """

    hidden: int = 128
    layers: int = 2
    lr: float = 3e-3
    lr_floor: float = 1e-2
    weight_decay: float = 0.0
    batch: int = 512
    epochs: int = 30
    patience: int = 5
    max_train: int | None = 100_000
    max_val: int | None = 20_000
    seed: int = 0
    threads: int = 1

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class History:
    """The training curve: mean standardised loss per epoch and how training ended."""

    train_loss: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    lr: list[float] = field(default_factory=list)
    best_epoch: int = -1
    stopped: str = ""
    seconds: float = 0.0
    n_train: int = 0
    n_val: int = 0

    @property
    def best_val(self) -> float:
        return self.val_loss[self.best_epoch] if self.best_epoch >= 0 else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class Standardizer(nn.Module):
    """Per-feature affine normalisation ``(x - mean) / std`` with statistics from data.

    Args:
        x: training samples (n, *shape); statistics are taken over the first axis, so
            they keep the per-rod / per-spring layout of ``shape``.
        floor: smallest std, relative to the largest one. A feature that barely moves
            (e.g. the axial angular acceleration of a rod no spring can twist, round-off
            in the data) is not blown up into noise the model would chase.
    """

    mean: torch.Tensor  # buffers (*shape)
    std: torch.Tensor

    def __init__(self, x: torch.Tensor, floor: float = 1e-3) -> None:
        super().__init__()
        mean = x.mean(0)
        std = x.std(0, correction=0)
        std = std.clamp_min(floor * float(std.max()) + 1e-30)
        self.register_buffer("mean", mean)
        self.register_buffer("std", std)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean.to(x.dtype)) / self.std.to(x.dtype)

    def inverse(self, y: torch.Tensor) -> torch.Tensor:
        return y * self.std.to(y.dtype) + self.mean.to(y.dtype)


def mlp(n_in: int, n_out: int, hidden: int, layers: int) -> nn.Sequential:
    """``layers`` hidden SiLU layers of width ``hidden``, then a linear output."""
    mods: list[nn.Module] = []
    width = n_in
    for _ in range(layers):
        mods += [nn.Linear(width, hidden), nn.SiLU()]
        width = hidden
    mods.append(nn.Linear(width, n_out))
    return nn.Sequential(*mods)


LossFn = Callable[[Sequence[torch.Tensor]], torch.Tensor]


def _mean_loss(loss_fn: LossFn, data: Sequence[torch.Tensor], batch: int) -> float:
    n = data[0].shape[0]
    total = 0.0
    with torch.no_grad():
        for lo in range(0, n, batch):
            part = [x[lo : lo + batch] for x in data]
            total += float(loss_fn(part)) * part[0].shape[0]
    return total / n


def train(
    model: nn.Module,
    loss_fn: LossFn,
    train_data: Sequence[torch.Tensor],
    val_data: Sequence[torch.Tensor],
    cfg: TrainConfig,
    desc: str = "train",
    progress: bool = False,
) -> History:
    """Fit ``model`` in place; it ends with the weights of the best validation epoch.

    Args:
        model: the parameters to train.
        loss_fn: mean loss of a batch, given the batch slices of ``train_data``.
        train_data, val_data: tensors sharing their first (transition) axis.
        cfg: the hyperparameters.
        desc: progress-bar label.
        progress: show a progress bar over epochs.
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        return _train(model, loss_fn, train_data, val_data, cfg, desc, progress)
    finally:
        torch.set_num_threads(threads)


def _train(
    model: nn.Module,
    loss_fn: LossFn,
    train_data: Sequence[torch.Tensor],
    val_data: Sequence[torch.Tensor],
    cfg: TrainConfig,
    desc: str,
    progress: bool,
) -> History:
    t0 = time.perf_counter()
    gen = torch.Generator().manual_seed(cfg.seed)
    n = train_data[0].shape[0]
    steps_per_epoch = max(1, -(-n // cfg.batch))
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(
        opt, T_max=cfg.epochs * steps_per_epoch, eta_min=cfg.lr * cfg.lr_floor
    )
    hist = History(n_train=n, n_val=val_data[0].shape[0])
    best = copy.deepcopy(model.state_dict())
    bar = tqdm(range(cfg.epochs), desc=desc, unit="epoch", leave=False, disable=not progress)
    for epoch in bar:
        model.train()
        perm = torch.randperm(n, generator=gen)
        total = 0.0
        for lo in range(0, n, cfg.batch):
            idx = perm[lo : lo + cfg.batch]
            loss = loss_fn([x[idx] for x in train_data])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(idx)
        model.eval()
        val = _mean_loss(loss_fn, val_data, 4 * cfg.batch)
        hist.train_loss.append(total / n)
        hist.val_loss.append(val)
        hist.lr.append(float(opt.param_groups[0]["lr"]))
        bar.set_postfix(train=f"{total / n:.2e}", val=f"{val:.2e}")
        if not torch.isfinite(torch.tensor(val)):
            hist.stopped = f"validation loss not finite at epoch {epoch}"
            break
        if hist.best_epoch < 0 or val < hist.best_val:
            hist.best_epoch = epoch
            best = copy.deepcopy(model.state_dict())
        elif epoch - hist.best_epoch >= cfg.patience:
            hist.stopped = f"early stop: no better validation loss for {cfg.patience} epochs"
            break
    else:
        hist.stopped = f"epoch budget ({cfg.epochs}) reached"
    model.load_state_dict(best)
    model.eval()
    hist.seconds = time.perf_counter() - t0
    return hist
