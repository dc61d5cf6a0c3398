"""What the floor checks can tell: the errors of models that meet the parameter targets.

The drop and rolling checks of a floor cell (:func:`measured_report.drop_error`,
:func:`measured_report.rollout_error`) compare open-loop rollouts through impacts,
where the direction a structure tips after touching down depends sharply on its
parameters. To read an identified model's check, this module measures the same
checks for models that are *right to within the identification targets*: the true
model with every parameter scaled by an independent uniform factor within
:data:`TOLERANCES` (masses and inertias per rod, stiffness and damping per spring,
the contact's stiffness, damping and friction), :data:`N_MODELS` draws seeded by the
cell. An identified model whose check errors lie within that spread is as good as
the checks can resolve at those tolerances.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from measured_plant import CellData
from measured_report import DROP_TOLERANCE, drop_error, rollout_error

from tensegrity_env.assemblies import icosahedron
from tensegrity_env.effects import GroundContact
from tensegrity_env.model import Model
from tensegrity_env.params import Params

#: the half-width of each parameter's relative error [-]: the identification targets
TOLERANCES = {"mass": 0.03, "inertia": 0.03, "stiffness": 0.03, "damping": 0.10,
              "contact stiffness": 0.10, "contact damping": 0.10, "friction": 0.10}  # fmt: skip
#: models drawn per cell
N_MODELS = 5
#: the plant's contact: MuJoCo's default soft contact, friction 1, floor at z = 0
PLANT_CONTACT = {"friction": 1.0, "height": 0.0}


def within_targets(truth: Params, rng: np.random.Generator) -> tuple[Params, dict[str, float]]:
    """The true parameters, each scaled by ``1 + u``, ``u ~ U(-tol, tol)`` per element
    (per rod for the inertia, so the principal moments keep their ratios), and the
    contact's factors ``{"stiffness", "damping", "friction"}`` drawn the same way."""
    p = truth.numpy()

    def scaled(x: np.ndarray, tol: float, shape: tuple[int, ...]) -> np.ndarray:
        return x * (1.0 + rng.uniform(-tol, tol, shape))

    out = dict(p)
    for group in ("mass", "stiffness", "damping"):
        out[group] = scaled(p[group], TOLERANCES[group], p[group].shape)
    out["inertia"] = scaled(p["inertia"], TOLERANCES["inertia"], (p["inertia"].shape[0], 1))
    contact = {k: float(1.0 + rng.uniform(-TOLERANCES[name], TOLERANCES[name]))
               for k, name in (("stiffness", "contact stiffness"),
                               ("damping", "contact damping"), ("friction", "friction"))}  # fmt: skip
    return Params.create(**out), contact


def tolerance_reference(data: CellData, n_models: int = N_MODELS) -> dict[str, Any]:
    """The floor checks of ``n_models`` models within :data:`TOLERANCES` of the truth.

    Returns ``rolling_mean`` and ``drop_worst`` [m] per model (lists), their medians
    ``rolling_median`` and ``drop_median`` [m], ``drop_passes`` (how many pass the
    drop check's :data:`~measured_report.DROP_TOLERANCE`), and the tolerances used.
    """
    topo = icosahedron().topology
    nominal = GroundContact(topo, **PLANT_CONTACT)
    rng = np.random.default_rng([data.cell.seed, 31])
    rolling, drops = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n_models):
            params, factors = within_targets(data.truth.params, rng)
            # the contact's scalar values; the per-cap radii stay the robot file's
            values = {k: float(v) for k, v in nominal.values.items() if v.numel() == 1}
            for k, f in factors.items():
                values[k] *= f
            path = Path(tmp) / f"model{i}.json"
            Model(topo, params, [GroundContact(topo, **values)]).save(path, {})
            doc = json.loads(path.read_text())
            rolling.append(rollout_error(data, doc, path)["mean"])
            drops.append(drop_error(data, doc, path)["worst"])
    return {
        "tolerances": dict(TOLERANCES),
        "rolling_mean": rolling,
        "drop_worst": drops,
        "rolling_median": float(np.median(rolling)),
        "drop_median": float(np.median(drops)),
        "drop_passes": int(sum(d < DROP_TOLERANCE for d in drops)),
        "models": n_models,
    }
