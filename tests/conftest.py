"""Fixtures shared by every tier. Autouse checks fail any test that leaks a CAN bus, a Python
thread or a child process (zenoh sessions are closed by the fixtures that open them)."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
import weakref

import can
import pytest

from sim_bridge import proc_stat
from sim_bridge.harness import free_port

HARDWARE_ENV = "LEADTHROUGH_HARDWARE"
LEAK_GRACE_S = 2.0

_open_buses: weakref.WeakSet[can.BusABC] = weakref.WeakSet()
_original_init = can.BusABC.__init__


def _tracking_init(self: can.BusABC, *args: object, **kwargs: object) -> None:
    _original_init(self, *args, **kwargs)
    _open_buses.add(self)


can.BusABC.__init__ = _tracking_init  # type: ignore[method-assign]


def _children(pid: int) -> list[int]:
    """PIDs whose parent is ``pid`` (Linux /proc), zombies excluded."""
    return proc_stat.children(pid, zombies=False)


@pytest.fixture(autouse=True)
def no_leaks():
    threads_before = set(threading.enumerate())
    yield
    deadline = time.monotonic() + LEAK_GRACE_S
    leaked_threads: list[threading.Thread] = []
    leaked_children: list[int] = []
    while time.monotonic() < deadline:
        # _DummyThread: a native thread (zenoh's) that ran Python code; not ours to join.
        leaked_threads = [
            t
            for t in threading.enumerate()
            if t not in threads_before
            and t.is_alive()
            and not isinstance(t, threading._DummyThread)
        ]
        leaked_children = _children(os.getpid())
        if not leaked_threads and not leaked_children:
            break
        time.sleep(0.05)
    leaked_buses = [b for b in list(_open_buses) if not getattr(b, "_is_shutdown", True)]
    for pid in leaked_children:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    for bus in leaked_buses:
        bus.shutdown()
    problems = []
    if leaked_threads:
        problems.append(f"threads left running: {[t.name for t in leaked_threads]}")
    if leaked_children:
        problems.append(f"child processes left running: {leaked_children}")
    if leaked_buses:
        problems.append(f"CAN buses left open: {leaked_buses}")
    if problems:
        pytest.fail("; ".join(problems))


@pytest.fixture
def port() -> int:
    return free_port()


@pytest.fixture
def router(port):
    """A zenoh router on a free local port: its BusConfig; closed after the test (a test module
    may define its own)."""
    from gateway.bus import BusConfig, open_router

    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{port}")
    session = open_router(bus)
    yield bus
    session.close()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if os.environ.get(HARDWARE_ENV) == "1":
        return
    skip = pytest.mark.skip(reason=f"needs the real cell: set {HARDWARE_ENV}=1")
    for item in items:
        if "hardware" in item.keywords:
            item.add_marker(skip)
