"""Independent analysis tasks in forked worker processes (``control/identification/parallel.py``):
the same results as one after another, errors raised where they were asked for, a dead worker
reported instead of a hang, and no worker left behind."""

from __future__ import annotations

import multiprocessing
import os
import signal
from concurrent.futures.process import BrokenProcessPool

import numpy as np
import pytest

from control.identification import parallel
from control.identification.parallel import map_forked
from gateway.errors import ConfigError

needs_workers = pytest.mark.skipif(
    "fork" not in multiprocessing.get_all_start_methods() or parallel.available_cpus() < 2,
    reason="needs fork and two CPUs",
)


def _no_children() -> bool:
    return not multiprocessing.active_children()


@needs_workers
def test_results_come_back_in_order_and_equal_to_one_after_another():
    data = np.random.default_rng(0).standard_normal((2_000, 30))  # read by the workers unpickled

    def task(k: int) -> tuple[int, int, np.ndarray]:
        return k, os.getpid(), np.linalg.svd(data[:, : k + 2], compute_uv=False)

    forked = map_forked(task, range(6))
    assert [k for k, _, _ in forked] == list(range(6))
    assert {pid for _, pid, _ in forked} - {os.getpid()}, "no task ran in a worker"
    for (_, _, a), k in zip(forked, range(6), strict=True):
        assert np.array_equal(a, task(k)[2])
    assert _no_children()


@needs_workers
def test_a_task_error_is_raised_here():
    def task(k: int) -> int:
        if k == 3:
            raise ConfigError("joint 3: no data")
        return k

    with pytest.raises(ConfigError, match="joint 3: no data"):
        map_forked(task, range(5))
    assert _no_children()


@needs_workers
def test_a_worker_killed_is_reported_not_waited_for():
    def task(k: int) -> int:
        if k == 1:
            os.kill(os.getpid(), signal.SIGKILL)
        return k

    with pytest.raises(BrokenProcessPool):
        map_forked(task, range(4))
    assert _no_children()


def test_one_cpu_runs_here_and_while_waiting_runs_once(monkeypatch):
    monkeypatch.setattr(parallel, "available_cpus", lambda: 1)
    calls: list[str] = []
    out = map_forked(lambda k: (k, os.getpid()), range(3), while_waiting=lambda: calls.append("x"))
    assert out == [(k, os.getpid()) for k in range(3)] and calls == ["x"]


@needs_workers
def test_while_waiting_runs_here_during_the_workers():
    calls: list[int] = []
    map_forked(lambda k: k, range(3), while_waiting=lambda: calls.append(os.getpid()))
    assert calls == [os.getpid()]
