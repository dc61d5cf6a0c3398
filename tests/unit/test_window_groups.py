"""A large windowed fit's window groups: the same normal equations and error whether the
groups run in worker processes or one after the other (identification.trajectory.forked)."""

from __future__ import annotations

import itertools
import os
from functools import partial

import numpy as np
import pytest
import torch

from identification.simulation.generate import GenerateSpec, generate_dataset
from identification.trajectory import forked, window_errors
from identification.trajectory.floor_fit import with_floor
from identification.trajectory.forked import side_by_side, window_groups, window_workers
from identification.trajectory.param_vector import ParamVector
from identification.trajectory.window_errors import window_sse
from identification.trajectory.windowed_fit import (
    FD_BATCH,
    SPLIT_WINDOWS,
    group_size,
    linearize,
)
from identification.trajectory.windows import STATE_KEYS, cut_windows, local_basis
from tensegrity_env.effects import GroundContact
from tensegrity_env.engine import Engine

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_groups_are_the_fewest_of_at_most_the_chunk_and_of_equal_sizes() -> None:
    sizes = [[g.stop - g.start for g in window_groups(n, most)]
             for n, most in ((48, 38), (8, 38), (38, 38), (39, 38), (10, 3), (1, 1))]  # fmt: skip
    assert sizes == [[24, 24], [8], [38], [20, 19], [3, 3, 2, 2], [1]]
    groups = window_groups(10, 3)
    assert groups[0].start == 0 and groups[-1].stop == 10
    assert all(a.stop == b.start for a, b in itertools.pairwise(groups))


def test_a_group_holds_at_most_the_batch_and_a_states_fit_from_split_windows_on_half() -> None:
    basis, states_only = torch.zeros(66, 6, 2, 3), torch.zeros(0)
    joint, few = torch.zeros(90), torch.zeros(5)
    assert group_size(basis, joint, 8) == FD_BATCH // 157 == 38  # 8 windows: one group
    assert group_size(basis, states_only, 8) == FD_BATCH // 67
    assert group_size(basis, states_only, SPLIT_WINDOWS - 1) == FD_BATCH // 67
    assert group_size(basis, states_only, 48) == 24  # two groups of 24, not one of 48
    assert group_size(basis, few, 48) == FD_BATCH // 72  # a joint fit: one group of 48
    assert [g.stop - g.start for g in window_groups(48, group_size(basis, joint, 48))] == [24, 24]
    assert len(window_groups(100, group_size(basis, joint, 100))) == 3  # the batch binds


def _floor_fit_parts():
    """Noisy floor windows (seed 2), the true model with its contact, and the fit's basis."""
    ds, truth = generate_dataset(GenerateSpec(n_train=2, n_val=0, n_test=0, steps=300, seed=2,
                                              ground=True))  # fmt: skip
    split, topo = ds.split("train"), ds.topology
    grid = {k: getattr(split, k)[:, 200:] for k in STATE_KEYS}
    noise = np.random.default_rng(0).normal(0.0, 1e-3, split.nodes[:, 200:].shape)
    windows = cut_windows(split.nodes[:, 200:] + noise, split.control[:, 200:], grid, 20)
    windows = windows.take(slice(0, 5))
    contact = GroundContact(topo, **truth.effects[0]["params"])
    vec = with_floor(ParamVector.at(topo, truth.params), [], contact, None)
    return Engine(topo, ds.dt), vec, windows, local_basis(vec.axes, True)


def test_window_groups_in_workers_give_the_serial_normal_equations_exactly(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(forked, "MIN_FORKED_WORK", 0)  # these small groups go to workers too
    engine, vec, windows, basis = _floor_fit_parts()
    theta = vec.theta0() * 1.01  # away from the truth: a real residual and gradient
    chunk = 2  # 5 windows: groups of 2, 2 and 1
    assert windows.size == 5
    serial = linearize(engine, vec, windows, basis, theta, chunk)
    sse = window_sse(engine, vec, windows, basis, theta, chunk)
    with window_workers(2):
        forked_ne = linearize(engine, vec, windows, basis, theta, chunk)
        forked_sse = window_sse(engine, vec, windows, basis, theta, chunk)
    for name in ("H_ll", "H_lg", "g_l", "H_gg", "g_g", "g_gb"):
        assert torch.equal(getattr(forked_ne, name), getattr(serial, name)), name
    assert forked_ne.sse == serial.sse > 0 and forked_ne.m == serial.m
    assert forked_sse == sse == pytest.approx(serial.sse, rel=1e-12)
    whole = linearize(engine, vec, windows, basis, theta, windows.size)  # one group
    torch.testing.assert_close(whole.H_gg, serial.H_gg, rtol=1e-9, atol=0.0)


def _pid_and_nested(_: int) -> tuple[int, list[int]]:
    """This worker's pid and the pids its own two tasks ran in."""
    return os.getpid(), side_by_side([os.getpid, os.getpid], jobs=2)


def test_a_worker_runs_its_own_tasks_itself() -> None:
    out = side_by_side([partial(_pid_and_nested, i) for i in range(2)], jobs=2)
    for pid, nested in out:
        assert pid != os.getpid() and nested == [pid, pid]
    assert forked.window_jobs() == 1
    with window_workers(3):
        assert forked.window_jobs() == 3
    assert forked.window_jobs() == 1


def test_groups_of_little_work_run_in_this_process() -> None:
    """A trial point's errors (one rollout per window) stay here; a linearization's groups
    (one rollout per coordinate too) go to the workers."""
    with window_workers(2):
        assert forked.window_jobs() == 2
        assert forked.window_jobs(forked.MIN_FORKED_WORK) == 2
        assert forked.window_jobs(forked.MIN_FORKED_WORK - 1) == 1
        assert forked.window_jobs(38 * 30) == 1  # 38 windows of 30 samples, rolled out once
        assert forked.window_jobs(38 * 157 * 30) == 2  # their linearization


def test_a_trial_point_s_errors_fork_no_worker(monkeypatch: pytest.MonkeyPatch) -> None:
    engine, vec, windows, basis = _floor_fit_parts()
    theta = vec.theta0() * 1.01
    asked: list[int] = []

    def recorded(tasks: list, jobs: int, log: object = print) -> list:  # side_by_side, recorded
        asked.append(jobs)
        return [task() for task in tasks]

    monkeypatch.setattr(window_errors, "side_by_side", recorded)
    with window_workers(2):
        window_sse(engine, vec, windows, basis, theta, 2)
    assert asked == [1]
