"""The measured benchmark's crash sweep: random cells of the matrix not yet run."""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from bench_measured import sample_cells
from measured_plant import DROPOUTS, NOISES, PLANTED, RATES, SETTINGS, Cell

MATRIX = [Cell(s, r, n * 1e-3, d / 100, e, 0) for s, r, n, d, e in
          itertools.product(SETTINGS, RATES, NOISES, DROPOUTS, PLANTED)]  # fmt: skip


def test_a_sample_skips_the_cells_already_run_and_is_reproducible() -> None:
    done = {c.label for c in MATRIX[::3]}
    first = sample_cells(MATRIX, done, 10, seed=4, shard="0/1")
    assert len(first) == 10 and len({c.label for c in first}) == 10
    assert not {c.label for c in first} & done
    assert [c.label for c in sample_cells(MATRIX, done, 10, 4, "0/1")] == [c.label for c in first]
    assert [c.label for c in sample_cells(MATRIX, done, 10, 5, "0/1")] != [c.label for c in first]


def test_shards_split_the_sample_without_overlap() -> None:
    whole = [c.label for c in sample_cells(MATRIX, set(), 9, 0, "0/1")]
    parts = [[c.label for c in sample_cells(MATRIX, set(), 9, 0, f"{k}/3")] for k in range(3)]
    assert sorted(itertools.chain.from_iterable(parts)) == sorted(whole) and all(len(p) == 3 for p in parts)
    with pytest.raises(SystemExit, match="expected K/N"):
        sample_cells(MATRIX, set(), 9, 0, "half")
    with pytest.raises(SystemExit, match="K must be in"):
        sample_cells(MATRIX, set(), 9, 0, "3/3")
