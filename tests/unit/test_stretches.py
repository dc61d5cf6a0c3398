"""Stretches of a take: at rest, free, and acted on from outside the model (a planted push)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from identification.data.mocap.importer import ImportedTake, Robot, build_dataset
from identification.data.mocap.stretches import (
    Stretch,
    assign_splits,
    find_stretches,
    named_stretches,
    parse_segments,
    pieces,
)
from identification.data.mocap.vertical import G
from tensegrity_env.io_utils import InputError
from tensegrity_env.topology import Rod, Topology

RATE = 120.0
LIFT = 0.5  # [m] the person raises the robot's centre this high before letting go
RELEASE = 4.0  # [s]


def _shape(rng: np.random.Generator) -> np.ndarray:
    """(12, 3) [m]: end caps of a rigid robot, its lowest three on z = 0."""
    caps = rng.normal(size=(12, 3)) * 0.15
    caps[:3, 2] = caps[:, 2].min() - 0.05
    return caps - np.array([0.0, 0.0, caps[:, 2].min()])


def _take(centre: np.ndarray, time: np.ndarray, seed: int = 0) -> np.ndarray:
    """(F, 12, 3) [m]: the rigid shape moved by ``centre`` (F, 3) [m], with 0.1 mm marker
    noise and 3 % of the samples unseen."""
    rng = np.random.default_rng(seed)
    caps = _shape(rng)[None] + centre[:, None] + rng.normal(scale=1e-4, size=(len(time), 12, 3))
    caps[rng.random((len(time), 12)) < 0.03] = np.nan
    return caps


def _lifted(time: np.ndarray) -> np.ndarray:
    """(F, 3) [m]: at rest until 2 s; pushed along the floor by a hand (2-2.5 s); lifted
    (2.5-3.5 s) and held (3.5-4 s); let go at 4 s: a free fall onto the floor, where it
    stays."""
    c = np.zeros((len(time), 3))
    push = np.clip((time - 2.0) / 0.5, 0, 1)
    c[:, 0] = 0.05 * (1 - np.cos(np.pi * push)) / 2
    lift = np.clip(time - 2.5, 0, 1)
    c[:, 2] = LIFT * (1 - np.cos(np.pi * lift)) / 2
    fall = time > RELEASE
    c[fall, 2] = np.maximum(LIFT - G / 2 * (time[fall] - RELEASE) ** 2, 0.0)
    return c


def test_a_planted_lift_is_found_with_its_times_and_the_rest_around_it() -> None:
    time = np.arange(0, 7.0, 1 / RATE)
    found = find_stretches(_take(_lifted(time), time), time)
    external = [s for s in found if s.kind == "external"]
    assert len(external) == 1
    (held,) = external
    assert abs(held.start - 2.0) < 0.15  # the robot starts to move from rest: touched
    assert abs(held.end - RELEASE) < 0.05  # the release: free fall starts
    assert held.held is not None and 2.5 < held.held[0] < 2.8  # off the floor from here
    landing = RELEASE + np.sqrt(2 * LIFT / G)
    rest = [s for s in found if s.kind == "rest"]
    assert rest[0].start == 0.0 and abs(rest[0].end - 2.0) < 0.15
    assert abs(rest[-1].start - landing) < 0.2 and rest[-1].end == pytest.approx(
        time[-1] + 1 / RATE
    )
    free = [s for s in found if s.kind == "free"]
    assert free and all(held.end - 1e-9 <= s.start and s.end <= rest[-1].start + 1e-9 for s in free)
    # consecutive, covering the take
    assert all(a.end == pytest.approx(b.start) for a, b in itertools.pairwise(found))


def test_a_jump_from_rest_is_free_flight_not_a_person() -> None:
    time = np.arange(0, 5.0, 1 / RATE)
    c = np.zeros((len(time), 3))
    up = time > 2.0
    c[up, 2] = np.maximum(
        2.0 * (time[up] - 2.0) - G / 2 * (time[up] - 2.0) ** 2, 0.0
    )  # 2 m/s off the floor
    found = find_stretches(_take(c, time, seed=1), time)
    assert [s.kind for s in found] == ["rest", "free", "rest"]
    assert abs(found[1].start - 2.0) < 0.15 and abs(found[1].end - (2.0 + 4.0 / G)) < 0.2


def test_segments_are_parsed_and_refused_in_one_line() -> None:
    assert parse_segments("11.5-20, 0-7") == [(0.0, 7.0), (11.5, 20.0)]
    for bad in ("0-7,x-3", "7-3", "0-7,5-9", "3"):
        with pytest.raises(InputError, match="--segments"):
            parse_segments(bad)
    time = np.arange(0, 3.0, 1 / RATE)
    with pytest.raises(InputError, match=r"take\.csv: --segments 5-6 s holds 0 frames"):
        named_stretches([(5.0, 6.0)], time, "take.csv")


def test_splits_are_made_of_whole_pieces_of_the_free_stretches() -> None:
    time = np.arange(0, 7.0, 1 / RATE)
    caps = _take(_lifted(time), time)
    found = find_stretches(caps, time)
    cut = pieces(found, time, 0.5)
    held = next(s for s in found if s.kind == "external")
    assert cut and all(b - a == 60 for a, b in cut)
    assert all(
        time[b - 1] < held.start or time[a] >= held.end for a, b in cut
    )  # none touches the hands
    names = assign_splits(len(cut), (0.7, 0.15, 0.15))
    assert names[0] == "train" and {"val", "test"} <= set(names)
    assert abs(names.count("train") / len(names) - 0.7) < 0.15

    topo = Topology(rods=tuple(Rod(f"rod{r}", 0.3) for r in range(6)), springs=())
    take = ImportedTake(Path("take.csv"), time, caps, RATE, 0, 0, np.zeros((len(time), 12), int),
                        stretches=tuple(found))  # fmt: skip
    data = build_dataset(
        [take], Robot(topo, None, Path("robot.yaml")), (0.7, 0.15, 0.15), piece=0.5
    )
    placed = data.attrs["pieces"]
    assert sum(len(v) for v in placed.values()) == len(cut)
    assert data.splits["train"].nodes.shape[1] == 60
    assert data.attrs["stretches"]["take.csv"][0]["kind"] == "rest"


def test_stretch_text_names_its_kind_and_times() -> None:
    s = Stretch(6.37, 11.3, "external", (7.28, 11.3))
    assert str(s) == "external 6.37-11.30 s (off the floor and not falling freely 7.28-11.30 s)"
    assert s.to_dict()["held_s"] == [7.28, 11.3]


def test_end_caps_that_repeat_their_frame_are_read_as_unseen() -> None:
    from identification.data.mocap.importer import without_placeholders

    rng = np.random.default_rng(3)
    caps = rng.normal(size=(10, 12, 3))
    caps[5] = caps[4] + 1e-8  # the caps copied from the frame before (a ghost kept the frame apart)
    out, n = without_placeholders(caps)
    assert n == 12 and np.isnan(out[5]).all() and np.isfinite(np.delete(out, 5, axis=0)).all()
