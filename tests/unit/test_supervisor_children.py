"""The gateway's supervision of its children (gateway/supervisor.py): a child that crashes is
restarted after the back-off; one that refuses its configuration (EXIT_CONFIG) is not, the
fault says why, and `reset` starts it again."""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from gateway.bus import BusConfig
from gateway.children import Child
from gateway.errors import EXIT_CONFIG
from gateway.gateway_config import GatewayConfig
from gateway.lifecycle import Lifecycle
from gateway.supervisor import Gateway


def _gateway_with_child(exit_code: int) -> tuple[Gateway, Child]:
    cfg = GatewayConfig(processes=(), restart_backoff_s=0.05)
    gw = Gateway(Path("cell.toml"), BusConfig(), cfg, spawn=False)
    child = Child("control", [sys.executable, "-c", f"import sys; sys.exit({exit_code})"])
    gw.children[child.name] = child
    gw._start_child(child)
    return gw, child


def _poll_until_exited(gw: Gateway, child: Child, n: int) -> None:
    deadline = time.monotonic() + 10.0
    while len(child.exits) < n:
        assert time.monotonic() < deadline, "the child did not exit"
        gw._poll_children(time.monotonic())
        time.sleep(0.01)


def _reap(child: Child) -> None:
    if child.proc is not None:
        child.proc.wait(10.0)
        child.proc = None


def test_a_crashed_child_is_restarted_after_the_backoff():
    gw, child = _gateway_with_child(1)
    try:
        _poll_until_exited(gw, child, 1)
        assert gw.machine.state == Lifecycle.FAULT
        assert "exited (code 1)" in gw.machine.reason
        time.sleep(0.06)
        assert gw._poll_children(time.monotonic()) == []  # restarted, not dead
        assert child.proc is not None
    finally:
        _reap(child)


def test_a_child_that_refuses_its_config_stays_down_until_reset():
    gw, child = _gateway_with_child(EXIT_CONFIG)
    try:
        _poll_until_exited(gw, child, 1)
        assert gw.machine.state == Lifecycle.FAULT
        assert "refused its configuration" in gw.machine.reason
        time.sleep(0.2)  # four back-offs
        assert gw._poll_children(time.monotonic()) == ["control"]
        assert child.proc is None and child.exits == [EXIT_CONFIG], "it was restarted"
        ok, message = gw._command("reset", None, None, gw.observations(time.monotonic()))
        assert not ok and "restarted control" in message
        assert child.proc is not None and not child.config_refused
        _poll_until_exited(gw, child, 2)  # the file is still bad: refused again, stays down
        assert child.config_refused and child.proc is None
    finally:
        _reap(child)


@pytest.mark.parametrize("code", [0, 2])
def test_other_exits_are_restarted(code):
    gw, child = _gateway_with_child(code)
    try:
        _poll_until_exited(gw, child, 1)
        assert not child.config_refused and child.restart_at_s is not None
    finally:
        _reap(child)


def _gateway_with_a_silent_control(boot_grace_s: float) -> tuple[Gateway, Child]:
    """A gateway (nothing spawned by it) and a started "control" child that never sends a
    heartbeat; the caller kills and reaps the child."""
    cfg = GatewayConfig(processes=(), boot_grace_s=boot_grace_s)
    gw = Gateway(Path("cell.toml"), BusConfig(), cfg, spawn=False)
    child = Child("control", [sys.executable, "-c", "import time; time.sleep(30)"])
    gw.children[child.name] = child
    gw._start_child(child)
    return gw, child


def test_a_child_without_a_heartbeat_is_booting_for_the_grace_then_silent():
    """[gateway].boot_grace_s: no heartbeat yet within it is a child still starting (a slow
    machine took 12 s); past it, or once a heartbeat came and went stale, it is silent."""
    gw, child = _gateway_with_a_silent_control(boot_grace_s=20.0)
    try:
        t0 = child.started_s
        assert gw.observations(t0 + 12.0).stale_processes == ()
        assert gw.observations(t0 + 20.5).stale_processes == ("control",)
        gw.health_rx_s["control"] = t0 + 1.0  # a heartbeat, then none for longer than 0.5 s
        assert gw.observations(t0 + 2.0).stale_processes == ("control",)
    finally:
        child.proc.kill()
        _reap(child)


def test_a_boot_grace_outside_its_range_is_refused():
    from gateway.errors import ConfigError

    for bad in (0.0, -1.0, 600.0):
        with pytest.raises(ConfigError, match=r"\[gateway\].boot_grace_s"):
            GatewayConfig(boot_grace_s=bad)


def test_start_is_refused_while_a_child_boots_and_a_booting_child_faults_nothing():
    """A child with no heartbeat yet within [gateway].boot_grace_s: ``start`` is refused with
    its name (the cell does not servo on before control is up), the status says why; READY is
    not faulted by it (only a silent or dead child faults the cell)."""
    gw, child = _gateway_with_a_silent_control(boot_grace_s=20.0)
    try:
        obs = gw.observations(child.started_s + 5.0)
        assert obs.booting_processes == ("control",) and obs.stale_processes == ()
        assert gw.machine.link_problems(obs) == gw.machine.link_problems(
            replace(obs, booting_processes=())
        )
        problems = gw.machine.start_problems(obs)
        assert "process(es) still starting: control" in problems
        ok, message = gw.machine.command("start", obs)
        assert not ok and "still starting: control" in message
        assert gw.machine.state == Lifecycle.STOPPED
        # up: its heartbeat came; the booting entry is gone and nothing else changed
        gw.health_rx_s["control"] = child.started_s + 5.5
        up = gw.observations(child.started_s + 5.6)
        assert up.booting_processes == () and up.stale_processes == ()
        assert gw.machine.start_problems(up) == gw.machine.link_problems(up)
    finally:
        child.proc.kill()
        _reap(child)
