"""The first contact search on the floor keeps the floor where the end caps are seen
touching it: a few short windows of a gapped take cannot lift it centimetres above them;
its second start, a spread of soft contacts."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch


def test_the_floor_search_stays_within_the_band_the_caps_are_read_in(monkeypatch) -> None:
    from identification.trajectory import floor_fit, touchdown
    from identification.trajectory.floor_fit import FLOOR_FREE, FLOOR_SEARCH_RANGE, floor_contact
    from identification.trajectory.touchdown import TOUCH, Touchdowns, search_contact
    from tensegrity_env.assemblies import icosahedron

    topo = icosahedron().topology
    # end caps resting 2 mm into the floor: the search starts the floor there
    nodes = np.zeros((1, 3, 2 * topo.n_rods, 3))
    nodes[..., 2] = np.repeat([r.radius for r in topo.rods], 2) - 0.002
    start = floor_contact(topo, nodes)
    assert abs(float(start.values["height"]) + 0.002) < 1e-9
    # a misfit that a floor 68 mm up would explain best (as a jump's few short windows did)
    target = 0.068

    def residual(engine, params, others, contact, touch, steps):
        return torch.tensor(
            [contact.values["height"].item() - target, np.log(contact.values["stiffness"].item())]
        )

    monkeypatch.setattr(touchdown, "touchdown_residual", residual)
    monkeypatch.setattr(touchdown, "_stderr", lambda *a: np.zeros(len(a[-1])))
    touch = Touchdowns(state=None, obs=torch.zeros(1, 5, 2 * topo.n_rods, 3), control=None,  # type: ignore[arg-type]
                       traj=np.zeros(1, int), first=np.zeros(1, int), prefix_rms=float("nan"))  # fmt: skip
    h0 = float(start.values["height"])
    free = search_contact(None, None, [], start, touch, horizons=(4,), keys=FLOOR_FREE, restarts=1)  # type: ignore[arg-type]
    assert abs(float(free.contact.values["height"]) - target) < 2e-3  # unbounded: it goes there
    bounded = search_contact(None, None, [], start, touch, horizons=(4,), keys=FLOOR_FREE, restarts=1,  # type: ignore[arg-type]
                             bounds={"height": (h0 - FLOOR_SEARCH_RANGE, h0 + FLOOR_SEARCH_RANGE)})  # fmt: skip
    h = float(bounded.contact.values["height"])
    assert FLOOR_SEARCH_RANGE == TOUCH and h0 - TOUCH - 1e-12 <= h <= h0 + TOUCH + 1e-12
    assert h > h0 + 0.9 * TOUCH  # it still moves within the band, towards the misfit
    # the floor fit's search passes that band
    seen = {}

    def spy(*args, **kwargs):
        seen.update(kwargs)
        raise RuntimeError("stop")

    monkeypatch.setattr(floor_fit, "search_contact", spy)
    vec = SimpleNamespace(coords=SimpleNamespace(effects_at=lambda x: [start]), n_free=0,
                          params=lambda t: None, full=lambda t: t)  # fmt: skip
    w = SimpleNamespace(state=None, obs=None, control=None, traj=None, start=None, steps=4,
                        seen=lambda: None)  # fmt: skip
    try:
        floor_fit.search_floor_contact(
            None, vec, w, torch.zeros(len(FLOOR_FREE), dtype=torch.float64)
        )  # type: ignore[arg-type]
    except RuntimeError:
        pass
    assert seen["bounds"] == {"height": (h0 - TOUCH, h0 + TOUCH)}


def test_the_spread_of_contact_starts_is_critically_damped_at_each_time_constant() -> None:
    """MuJoCo's solref at damping ratio 1: K = 1/(d tc)^2, B = 2/(d tc) at impedance d."""
    from identification.trajectory.effect_coords import from_free
    from identification.trajectory.touchdown import TIME_CONSTANTS, time_constant_starts
    from tensegrity_env.assemblies import icosahedron
    from tensegrity_env.effects import GroundContact

    contact = GroundContact(icosahedron().topology, impedance=0.9, friction=0.8)
    keys = ("stiffness", "damping", "friction", "impedance")
    starts = time_constant_starts(contact, keys)
    assert len(starts) == len(TIME_CONSTANTS)
    for tc, x in zip(TIME_CONSTANTS, starts, strict=True):
        v = {k: float(from_free(contact.PARAMS[k], torch.tensor(x[i]))) for i, k in enumerate(keys)}
        assert v["impedance"] == pytest.approx(0.9) and v["friction"] == pytest.approx(0.8)
        assert v["damping"] / (2 * np.sqrt(v["stiffness"])) == pytest.approx(1.0)  # critical
        assert 2 / (v["damping"] * v["impedance"]) == pytest.approx(tc)
