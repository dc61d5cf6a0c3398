"""The slack-cable hypothesis when every spring is a cable already: nothing further to
ask, said in words (identification.discovery.slack_hypothesis)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from identification.discovery import slack_hypothesis as module
from identification.trajectory.slack_regression import SlackRegression
from tensegrity_env import assemblies
from tensegrity_env.effects import SlackSprings


def test_no_further_cable_is_proposed_when_every_spring_is_one(monkeypatch) -> None:
    topo = assemblies.icosahedron().topology
    S = topo.n_springs
    reg = SlackRegression(
        values={"stiffness": np.ones(S), "compression_stiffness": -np.ones(S),
                "compression_stiffness_se": np.full(S, 0.01)},
        iterations=1, knot_change=0.0,
    )  # fmt: skip
    monkeypatch.setattr(module, "slack_regression", lambda *a, **k: reg)
    monkeypatch.setattr(module, "airborne_keep", lambda data: None)
    data = SimpleNamespace(topology=topo, on_floor=False, smooth={"train": None},
                           train=SimpleNamespace(control=None))  # fmt: skip
    current = SimpleNamespace(effects=[SlackSprings(topo, springs=list(range(S)))])
    proposal = module.slack_hypothesis(data, current, {})
    assert proposal.effect is None
    assert proposal.gate == f"all {S} springs are cables already"
