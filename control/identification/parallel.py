"""Independent CPU-bound tasks of an analysis, side by side in forked worker processes.

The analysis's searches make thousands of small solves and per-sample pinocchio calls: most
of their time is Python holding the GIL, so threads share one core in practice. Measured on
the 2-core machine class (2 × 60 s at 500 Hz): the three friction families took 3.8-4.5 s
in two threads against 4.2 s one after another, and 2.7-2.9 s in two forked processes, with
the same results to the last bit.

A forked worker shares the parent's memory copy-on-write: a task reads its inputs (the
prepared files, the regressor, the least-squares tables) where the parent left them, and
only its result is pickled back. Where ``fork`` is not available, or this process may use
only one CPU (``taskset -c 0``), the tasks run one after another in this process, with the
same results. A worker that dies (killed, out of memory) raises
:class:`concurrent.futures.process.BrokenProcessPool` here instead of hanging the analysis.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: Worker processes at most (the machine class has two cores).
WORKERS = 2

#: The task of the current :func:`map_forked`: set before the workers fork, so they find it
#: without pickling (a closure over the analysis's arrays would not pickle cheaply, if at all).
_task: Callable[[Any], Any] | None = None
_one_at_a_time = threading.Lock()


def _call(item: Any) -> Any:
    assert _task is not None, "worker forked without a task"
    return _task(item)


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask, e.g. ``taskset``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def map_forked(
    fn: Callable[[T], R],
    items: Iterable[T],
    workers: int = WORKERS,
    while_waiting: Callable[[], None] | None = None,
) -> list[R]:
    """``[fn(x) for x in items]``, in up to ``workers`` forked processes (module docstring).

    Items are handed out one at a time in order, so put the costliest first. ``fn``'s
    exceptions are raised here. ``while_waiting()`` runs in this process meanwhile (work this
    process needs next, e.g. an import); without workers it runs first.
    """
    global _task
    todo = list(items)
    count = min(workers, len(todo), available_cpus())
    if count < 2 or "fork" not in multiprocessing.get_all_start_methods():
        if while_waiting is not None:
            while_waiting()
        return [fn(x) for x in todo]
    with _one_at_a_time:
        _task = fn
        try:
            context = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(max_workers=count, mp_context=context) as pool:
                pending = [pool.submit(_call, x) for x in todo]
                if while_waiting is not None:
                    while_waiting()
                return [p.result() for p in pending]
        finally:
            _task = None
