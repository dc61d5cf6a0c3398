"""The window-length benchmark's child process: identify with the floor fit's first
windows restricted to one length (benchmarks/floor_window_lengths.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from floor_window_lengths import restricted


@pytest.mark.parametrize("steps, kept", [(15, [(15, 16)]), (4, [(4, 8)])])
def test_the_first_windows_are_restricted_to_one_length(monkeypatch, steps, kept) -> None:
    """The data's choices keep only the asked length with the count the data gives it; a
    length the data does not offer runs with the floor fit's own count."""
    import identification.trajectory.floor_declared as fd
    import tensegrity_sr.cli as cli

    offered = [(30, 8), (15, 16), (8, 30)]
    monkeypatch.setattr(fd, "windows_from_data", lambda d, v, longest, count, noise: (offered, "why"))
    seen: dict[str, object] = {}

    def command(argv: list[str]) -> int:
        seen["argv"] = argv
        seen["choices"] = fd.windows_from_data(None, None, 30, 8, 1e-4)
        return 3

    monkeypatch.setattr(cli, "main", command)
    assert restricted(steps, ["identify", "take.h5"]) == 3
    choices, why = seen["choices"]  # type: ignore[misc]
    assert seen["argv"] == ["identify", "take.h5"] and choices == kept
    assert why == f"why (restricted to {steps} steps)"
