"""Limits on the contact's coordinates after the floor fit
(identification.trajectory.floor_fit.contact_box, EffectCoords' box)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from identification.trajectory.effect_coords import CONTACT_BOX, EffectCoords
from identification.trajectory.floor_fit import CONTACT_RANGE, FLOOR_FREE, contact_box
from tensegrity_env import assemblies
from tensegrity_env.effects import GroundContact, LinearDrag


def test_box_spans_the_contact_range_around_its_values() -> None:
    topo = assemblies.icosahedron().topology
    contact = GroundContact(topo, stiffness=1200.0, damping=80.0, friction=0.6,
                            impedance=0.9, height=0.002)  # fmt: skip
    box = contact_box(contact)
    assert set(box) == set(FLOOR_FREE)
    f = CONTACT_RANGE["factor"]
    for k, v in (("stiffness", 1200.0), ("damping", 80.0)):
        lo, hi = np.exp(box[k])
        assert lo == pytest.approx(v / f) and hi == pytest.approx(v * f)
    lo, hi = box["height"]
    assert lo == pytest.approx(0.002 - CONTACT_RANGE["height"])
    assert hi == pytest.approx(0.002 + CONTACT_RANGE["height"])
    for k, v in (("friction", 0.6), ("impedance", 0.9)):
        lo, hi = 1 / (1 + np.exp(-np.array(box[k])))  # logit -> fraction
        assert lo < v < hi and 0 < lo and hi < 1


def test_effect_coords_take_the_box_for_the_contact_and_only_bound_drag_at_zero() -> None:
    topo = assemblies.icosahedron().topology
    contact = GroundContact(topo, stiffness=1200.0, damping=80.0, friction=0.6,
                            impedance=0.9, height=0.002)  # fmt: skip
    drag = LinearDrag(topo)
    boxed = EffectCoords.of([drag, contact], None, FLOOR_FREE, contact_box(contact))
    lo, hi = boxed.bounds()
    n_drag = boxed.sizes()[0]
    assert np.all(lo[:n_drag].numpy() == 0.0) and np.all(np.isinf(hi[:n_drag].numpy()))
    k = FLOOR_FREE.index("height")
    assert float(hi[n_drag + k] - lo[n_drag + k]) == pytest.approx(2 * CONTACT_RANGE["height"])
    # without a box: ±CONTACT_BOX around the start (5 m on the floor height)
    lo, hi = EffectCoords.of([drag, contact], None, FLOOR_FREE).bounds()
    assert float(hi[n_drag + k] - lo[n_drag + k]) == pytest.approx(2 * CONTACT_BOX)


def test_the_first_round_holds_every_free_spring_damping_and_nothing_else() -> None:
    from identification.trajectory.floor_fit import held_groups, with_floor
    from identification.trajectory.param_vector import ParamVector

    asm = assemblies.icosahedron()
    topo = asm.topology
    vec = ParamVector.at(topo, asm.params)
    vec = replace(vec, free=torch.ones_like(vec.free))  # every declared parameter fitted
    vec = with_floor(vec, [LinearDrag(topo)], GroundContact(topo), None)
    hold = held_groups(vec, ("damping",))
    names = [n for n, free in zip(vec.names(), vec.free.tolist(), strict=True) if free]
    assert len(hold) == len(names) + vec.n_effect
    held = [n for n, h in zip(names, hold.tolist(), strict=False) if h]
    assert held == [f"damping[{s.name}]" for s in topo.springs]
    assert not bool(hold[len(names) :].any())  # the effects and the contact are fitted


def test_the_floor_height_stays_near_where_the_caps_touch_however_many_fits_follow() -> None:
    from identification.trajectory.floor_fit import FLOOR_SEARCH_RANGE

    topo = assemblies.icosahedron().topology
    # a contact the last fit moved 8 mm above the measured floor (z = 0)
    contact = GroundContact(
        topo, stiffness=1200.0, damping=80.0, friction=0.6, impedance=0.9, height=0.008
    )
    free = contact_box(contact)["height"]
    assert free[1] == pytest.approx(0.008 + CONTACT_RANGE["height"])  # alone: 11 mm, then 14 ...
    lo, hi = contact_box(contact, floor=0.0)["height"]
    assert lo == pytest.approx(0.008 - CONTACT_RANGE["height"]) and hi == pytest.approx(
        FLOOR_SEARCH_RANGE
    )
    # a value already outside the band keeps its own place in the range (never cut off)
    far = contact_box(replace_height(contact, 0.012), floor=0.0)["height"]
    assert far[0] <= 0.012 <= far[1] and far[1] == pytest.approx(0.012)


def replace_height(contact: GroundContact, h: float) -> GroundContact:
    return contact.with_values(height=torch.tensor(h, dtype=torch.float64))
