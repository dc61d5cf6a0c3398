"""Is an identified contact good enough for the environment? A 2-s drop against MuJoCo.

A check of an identified ground contact: the icosahedron is released at rest 0.1-0.5 m
above the floor (MuJoCo ground truth with its default soft contact, friction 1),
falls, bounces and settles; the identified model (declared parameters and effects,
contact included) is rolled out open-loop from the same initial states. The error is
the mean end-cap distance [m] at each sample, worst over samples and drops; it passes
below 2 cm (:data:`DROP_TOLERANCE`).

``python -m identification.experiments.drop_check PARAMS.json`` runs it on a params file the
residual loop wrote (``tensegrity-sr diagnose ... -o DIR`` -> ``DIR/params.json``).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from identification.simulation.generate import GenerateSpec, InitialConditions, generate_dataset
from identification.trajectory.windows import rollout_caps
from tensegrity_env.effects.base import PhysicalEffect
from tensegrity_env.engine import Engine, State
from tensegrity_env.io_utils import InputError
from tensegrity_env.model import Model
from tensegrity_env.params import Params

#: a contact passes when its 2-s drop-and-bounce stays within this of MuJoCo [m]
DROP_TOLERANCE = 0.02


@dataclass(frozen=True)
class DropResult:
    """Errors of a model on MuJoCo drops.

    Attributes:
        error: mean end-cap distance [m] per drop and sample, (N, T+1).
        lowest: lowest end-cap height reached in MuJoCo [m] (negative: it touched the
            floor, the cap's centre below its radius).
    """

    error: np.ndarray
    lowest: float

    @property
    def worst(self) -> float:
        """The largest mean end-cap distance [m] over samples and drops."""
        return float(self.error.max())

    @property
    def final(self) -> float:
        """The mean end-cap distance [m] at the end, averaged over drops."""
        return float(self.error[:, -1].mean())


def drop_trajectories(n: int = 3, seconds: float = 2.0, seed: int = 21):
    """``n`` MuJoCo drops from rest (the icosahedron, floor, friction 1), 1 kHz."""
    still = InitialConditions(speed=(0.0, 0.0), tumble=(0.0, 0.0), spin=0.0, position_std=0.0,
                              rotation_std=0.0, lift=(0.1, 0.5))  # fmt: skip
    spec = GenerateSpec(ground=True, n_train=n, n_val=0, n_test=0, steps=round(seconds / 1e-3),
                        seed=seed, initial=still)  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the collapse on the floor stretches springs a lot
        return generate_dataset(spec)


def drop_check(
    params: Params, effects: Sequence[PhysicalEffect], n: int = 3, seed: int = 21
) -> DropResult:
    """Roll the model (``params``, ``effects``) out from MuJoCo's drops; see the module doc."""
    if not any(e.gate.needs == "floor" for e in effects):
        raise InputError("the model has no ground_contact effect: it would fall through the floor")
    ds, _ = drop_trajectories(n, seed=seed)
    if not effects[0].topology.same_as(ds.topology):
        raise InputError("the drop check needs the icosahedron (its topology differs)")
    s = ds.split("train")
    init = State.from_numpy(*(getattr(s, k)[:, 0] for k in ("p", "v", "q", "omega")))
    with torch.no_grad():
        caps = rollout_caps(Engine(ds.topology, ds.dt, effects=list(effects), native=True), params, init,
                            torch.as_tensor(s.control))  # fmt: skip
    err = np.linalg.norm(caps.numpy() - s.nodes, axis=-1).mean(-1)
    return DropResult(error=err, lowest=float(s.nodes[..., 2].min()))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("params", type=Path, help="params file with a ground_contact effect")
    p.add_argument("--drops", type=int, default=3, help="number of drops (default 3)")
    p.add_argument("--seed", type=int, default=21, help="seed of the drop heights (default 21)")
    args = p.parse_args(argv)
    try:
        model = Model.load(args.params)
        r = drop_check(model.params, model.effects, args.drops, args.seed)
    except InputError as e:
        print(f"error: {args.params}: {e}", file=sys.stderr)
        return 2
    verdict = "within" if r.worst < DROP_TOLERANCE else "NOT within"
    print(f"2-s drop and bounce, {args.drops} drops: worst mean end-cap error "
          f"{r.worst * 1e3:.2f} mm, at the end {r.final * 1e3:.2f} mm "
          f"({verdict} {DROP_TOLERANCE * 1e2:g} cm of MuJoCo)")  # fmt: skip
    return 0 if r.worst < DROP_TOLERANCE else 1


if __name__ == "__main__":
    raise SystemExit(main())
