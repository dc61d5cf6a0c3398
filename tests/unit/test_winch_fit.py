"""The winding of a winch-driven robot from its end caps and command log at uneven
sample times (:func:`identification.trajectory.winch_fit.fit_winding`), on the 3-bar of
``test_bekris_crawl`` simulated by the engine at jittered times."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from test_bekris_crawl import CAPS, lab_take

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from bekris_crawl import LENGTH, convert

from identification.data.end_caps import rod_states_from_nodes
from identification.trajectory.winch_fit import fit_winding
from tensegrity_env.engine import Engine, State
from tensegrity_env.model import Model
from tensegrity_env.rotations import quat_to_matrix

#: the plant's winding: v_max [m/s] and motor lag [s] (one of the lags the fit tries)
SPEED, LAG = 0.03, 0.05


def test_the_winding_is_recovered_at_uneven_times(tmp_path: Path) -> None:
    """Stiff cables (20x the lab's) in free flight, six motors under random commands held
    0.5 s, samples ~50 ms apart with 2 ms steps among them: ``v_max`` within 3 %, the
    lag found among those tried, the cables' lengths about the fitted winding within a
    few millimetres (their stretch), closer than about a winding 30 % too slow."""
    files = convert(lab_take(tmp_path / "lab"), tmp_path / "out")
    declared = Model.read(files.robot)
    W = declared.topology.n_winches
    p = declared.params.replace(winch_speed=torch.full((W,), SPEED, dtype=torch.float64),
                                winch_lag=torch.full((W,), LAG, dtype=torch.float64),
                                stiffness=declared.params.stiffness * 20, damping=declared.params.damping * 5)  # fmt: skip
    rng = np.random.default_rng(5)
    steps = rng.normal(0.05, 0.01, size=80)
    steps[rng.choice(80, 8, replace=False)] = 0.002
    t = np.concatenate(([0.0], np.cumsum(steps)))
    u = np.repeat(rng.uniform(-1, 1, size=(8, W)), 10, axis=0)
    st = rod_states_from_nodes(np.stack([CAPS, CAPS]) * LENGTH, declared.topology, 1.0)
    s0 = State(*(torch.as_tensor(st[k][:1]) * (k in ("p", "q")) for k in ("p", "v", "q", "omega")))
    engine = Engine(declared.topology, dt=1e-3)
    out = engine.rollout_at(s0, p, t, winches=torch.as_tensor(u)[None])
    arms = torch.einsum("btrij,rkj->btrki", quat_to_matrix(out.q), engine.end_offsets)
    caps = (out.p.unsqueeze(3) + arms).flatten(2, 3)[0].numpy()
    plant = Model(declared.topology, p)
    fit = fit_winding(plant, caps, t, u, 1e-3)
    assert abs(fit.winch_speed / SPEED - 1) < 0.03, fit.winch_speed
    assert fit.winch_lag == LAG, fit.lag_rms
    assert fit.rms < 0.005
    slow = plant.params.replace(winch_speed=torch.full((W,), 0.7 * SPEED, dtype=torch.float64))
    assert fit.rms < 0.5 * fit_winding(Model(declared.topology, slow), caps, t, u, 1e-3).declared_rms
