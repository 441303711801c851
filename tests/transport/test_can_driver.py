"""CAN driver between a fake LTC-1 controller (seqpacket hub) and a zenoh router, in-process.

The driver opens its links from config exactly as in production (``can.Bus(**transport)``,
a zenoh client session); only the transport differs. Controller cycles are 20 ms here so that
a 10 ms deadline is the binding one.
"""

from __future__ import annotations

import itertools
import logging
import os
import re
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from conftest_can import ControlStub, FakeController, GatewayStub, free_port, wait_for

from drivers.can.adapter import HostRequest
from drivers.can.config import CanDriverConfig
from drivers.can.driver import (
    PROCESS_NAME,
    CanDriver,
    CanDriverProcess,
    cli_main,
    configure_parser,
)
from drivers.can.ltc_frames import ControllerStatus, FaultCode, JointFeedback, crc8_sae_j1850
from drivers.can.ltc_protocol import LtcProtocol
from gateway.bus import BusConfig, open_client, open_router
from gateway.errors import EXIT_CONFIG, FrameError, LinkTimeoutError
from gateway.messages import (
    FLAG_ESTOP,
    FLAG_PREV_HOLD,
    FLAG_SERVO_POWER,
    ControllerState,
    JointCommand,
    JointState,
    Lifecycle,
)
from gateway.runner import run_service
from gateway.signals import StopSignals
from sim_bridge import proc_stat
from sim_bridge.can_hub import SeqpacketHubBus
from sim_bridge.harness import unique_can_address

REPO = Path(__file__).resolve().parents[2]
PERIOD_S = 0.02
DEADLINE_S = 0.010
N = 6


def own_threads() -> set[threading.Thread]:
    # zenoh's native threads that ever ran Python appear as _DummyThread: not ours.
    return {t for t in threading.enumerate() if not isinstance(t, threading._DummyThread)}


@pytest.fixture(scope="module")
def router() -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_router(BusConfig(endpoint=endpoint))
    yield endpoint
    session.close()


@dataclass
class Cell:
    server: SeqpacketHubBus
    controller: FakeController
    driver: CanDriver
    gateway: GatewayStub
    control: ControlStub
    bus: BusConfig
    config: CanDriverConfig

    def teach(self, policy: Callable[[JointState], Any] | None) -> None:
        self.control.policy = policy
        self.gateway.set(Lifecycle.TEACHING, enabling=True)


def driver_config(**overrides: Any) -> CanDriverConfig:
    values: dict[str, Any] = {
        "transport": {"interface": "seqpacket", "channel": "@leadthrough-test-none"},
        "deadline_s": DEADLINE_S,
        "heartbeat_period_s": 0.05,
        "max_following_error_rad": 0.05,
        "max_velocity_rad_s": 1.0,
        "current_zero_cycles": 0,  # currents as reported, the servo at once (rt/src/core_tests.rs)
    }
    values.update(overrides)
    return CanDriverConfig(**values)


@pytest.fixture
def make_cell(router: str) -> Iterator[Callable[..., Cell]]:
    threads_before = own_threads()
    cleanups: list[Callable[[], None]] = []

    def make(
        first_counter: int = 0,
        setup: Callable[[FakeController], None] | None = None,
        brake_on_signals: bool = False,
        **overrides: Any,
    ) -> Cell:
        bus = BusConfig(endpoint=router, key_prefix=f"t{uuid.uuid4().hex[:8]}")
        address = unique_can_address()
        server = SeqpacketHubBus(address, max_backlog_frames=1_000_000)
        overrides["transport"] = {"interface": "seqpacket", "channel": address}
        cleanups.append(server.shutdown)
        controller = FakeController(server, N, PERIOD_S, first_counter)
        if setup is not None:
            setup(controller)
        cleanups.append(controller.stop)
        session = open_client(bus)
        cleanups.append(session.close)
        control = ControlStub(session, bus.keys)
        cleanups.append(control.close)
        gateway = GatewayStub(session, bus.keys).start()
        cleanups.append(gateway.stop)
        config = driver_config(**overrides)
        driver = CanDriver(config, bus, brake_on_signals=brake_on_signals)
        cleanups.append(driver.close)
        driver.start()
        assert server.wait_for_clients(1, 5.0)
        controller.start()
        return Cell(server, controller, driver, gateway, control, bus, config)

    yield make
    for cleanup in reversed(cleanups):
        cleanup()
    deadline = time.monotonic() + 2.0
    while (leaked := own_threads() - threads_before) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not leaked, f"threads left running: {leaked}"


#: how far from the measured position :func:`follow`'s commands reach [rad]: its offset, plus
#: one period of its velocity for a late cycle the driver coasts on the last command
FOLLOW_REACH_RAD = 0.01 + 0.05 * PERIOD_S


def follow(offset_rad: float = 0.01, dq_rad_s: float = 0.05) -> Callable[[JointState], Any]:
    """A control process that commands the measured position plus ``offset_rad``."""

    def policy(s: JointState) -> JointCommand:
        q = s.q_rad + offset_rad
        return JointCommand(s.cycle, s.stamp_s, time.monotonic(), q, np.full(s.n, dq_rad_s))

    return policy


def at_least(n: int, get: Callable[[], list[Any]]) -> Callable[[], list[Any] | None]:
    def check() -> list[Any] | None:
        items = get()
        return items if len(items) >= n else None

    return check


# --- joint state ----------------------------------------------------------------------------
def test_joint_state_published_every_cycle_with_the_feedback_values(make_cell):
    cell = make_cell(first_counter=65530)  # the 16-bit counter wraps during the test
    states = wait_for(at_least(12, cell.control.joint_states), what="12 joint states")
    cycles = [s.cycle for s in states]
    assert cycles == list(range(cycles[0], cycles[0] + len(cycles))), "a cycle was skipped"
    assert cycles[0] == 65531 and cycles[-1] > 65535, "counter widened past the wrap"
    for s in states:
        sent = cell.controller.sent[s.cycle & 0xFFFF]
        np.testing.assert_allclose(s.q_rad, sent.q_rad, atol=0.5e-6)
        np.testing.assert_allclose(s.dq_rad_s, sent.dq_rad_s, atol=0.5e-4)
        np.testing.assert_allclose(s.current_a, sent.current_a, atol=0.5e-2)
        assert s.controller_state == ControllerState.BRAKED
        assert s.flags & (FLAG_ESTOP | FLAG_SERVO_POWER) == 0
        np.testing.assert_allclose(s.q_cmd_rad, s.q_rad, atol=1e-6)  # nothing commanded yet
        np.testing.assert_array_equal(s.dq_cmd_rad_s, np.zeros(N))
    assert all(b.stamp_s > a.stamp_s for a, b in itertools.pairwise(states))
    assert states[-1].flags & FLAG_PREV_HOLD  # braked: every cycle is answered with a hold


#: cycles the controller sends back to back in the burst test below
BURST = 12
#: ... and how many such bursts (about 1 s of the test each 10)
BURSTS = 20


def test_a_burst_of_cycles_reaches_control_whole_its_newest_included(make_cell):
    """A controller that ran late sends the cycles it owes back to back (so does a driver that
    reads a backlog after its own thread was held): every one of their joint states reaches the
    control process, the newest (the one the driver waits to have answered) included. With
    zenoh's default real-time queue of 2 batches, the driver's and the router's, the states of
    such a burst past the first two were dropped, the newest among them (CI, 2026-12-07: "a
    cycle was skipped" in the test above; here 4 of 6 runs failed on an idle machine)."""
    cell = make_cell()
    for _ in range(BURSTS):
        newest = wait_for(at_least(1, cell.control.joint_states))[-1].cycle
        start = newest + 3
        with cell.controller.lock:
            cell.controller.rush.update((start + k) & 0xFFFF for k in range(BURST - 1))
        end = start + BURST - 1
        wait_for(
            lambda end=end: any(s.cycle > end + 1 for s in cell.control.joint_states()),
            what=f"the cycles after the burst {start}..{end}",
        )
        got = {s.cycle for s in cell.control.joint_states()}
        lost = [c for c in range(start, end + 1) if c not in got]
        assert not lost, f"the burst {start}..{end} lost the joint states of cycles {lost}"


# --- forwarding -----------------------------------------------------------------------------
def test_fresh_command_is_forwarded_with_counter_and_crc(make_cell):
    cell = make_cell()
    cell.teach(follow(offset_rad=0.01, dq_rad_s=0.05))
    sets = wait_for(at_least(10, lambda: cell.controller.command_sets(hold=False)))
    coasts, forwarded = 0, []
    for cset in sets:
        sent = cell.controller.sent[cset.cycle_counter]
        if np.allclose(cset.q_cmd_rad, sent.q_rad + FOLLOW_REACH_RAD, atol=1.5e-6):
            coasts += 1  # a late cycle: the last command moved on by its velocity (the arm rests)
            continue
        forwarded.append(cset)
        np.testing.assert_allclose(cset.q_cmd_rad, sent.q_rad + 0.01, atol=1.5e-6)
        np.testing.assert_allclose(cset.dq_cmd_rad_s, 0.05, atol=0.5e-4)
        for k, msg in enumerate(cset.raw):
            assert msg.arbitration_id == 0x201 + k and not msg.is_extended_id
            assert msg.data[6] == cset.cycle_counter & 0xFF, "counter = low byte of the cycle"
            id_bytes = bytes((msg.arbitration_id & 0xFF, msg.arbitration_id >> 8))
            assert msg.data[7] == crc8_sae_j1850(id_bytes + bytes(msg.data[:7]))
    assert coasts <= cell.driver.coasted
    # the commands came in time (a coast is sent at the answer deadline, when one did not)
    assert forwarded and np.median([s.after_status_s for s in forwarded]) < DEADLINE_S
    assert cell.controller.bad_frames == []
    assert cell.controller.state == ControllerState.EXTERNAL
    assert cell.driver.forwarded >= len(forwarded)  # the sets that were not coasts
    # JointState echoes the command last sent to the controller (here: q + 0.01, 0.05 rad/s)
    echoed = [
        s
        for s in cell.control.joint_states()[-5:]
        if np.allclose(s.q_cmd_rad, s.q_rad + 0.01, atol=2e-6)
        and np.allclose(s.dq_cmd_rad_s, 0.05, atol=1e-4)
    ]
    assert echoed, "no JointState echoed the forwarded command"


def test_stale_command_is_not_forwarded_and_hold_is_sent(make_cell):
    cell = make_cell()

    def stale(s: JointState) -> JointCommand:
        return JointCommand(s.cycle, s.stamp_s - 0.05, time.monotonic(), s.q_rad, np.zeros(N))

    cell.teach(stale)
    wait_for(lambda: cell.driver.rejected["stale"] >= 5, what="5 stale rejections")
    holds = wait_for(at_least(5, lambda: cell.controller.command_sets(hold=True)))
    assert cell.controller.command_sets(hold=False) == []
    assert cell.driver.forwarded == 0
    assert all(np.all(h.dq_cmd_rad_s == 0) for h in holds)


@pytest.mark.parametrize(
    ("lifecycle", "enabling", "reason"),
    [
        (Lifecycle.TEACHING, False, "blocked_enabling"),
        (Lifecycle.READY, True, "blocked_lifecycle"),
    ],
)
def test_without_teaching_and_enabling_only_hold_is_sent(make_cell, lifecycle, enabling, reason):
    cell = make_cell()
    cell.control.policy = follow()
    cell.gateway.set(lifecycle, enabling=enabling)
    wait_for(lambda: cell.driver.rejected[reason] >= 5, what=f"5 {reason} rejections")
    wait_for(lambda: cell.controller.state == ControllerState.EXTERNAL, what="servo on")
    holds = wait_for(at_least(5, lambda: cell.controller.command_sets(hold=True)))
    assert cell.controller.command_sets(hold=False) == []
    delays = [h.after_status_s for h in holds]
    assert np.median(delays) < DEADLINE_S, f"blocked cycles are held at once: {delays}"
    assert HostRequest.SERVO_ON in cell.controller.request_log()


def test_when_commands_stop_hold_keeps_the_last_forwarded_position(make_cell):
    cell = make_cell()
    cell.teach(follow(offset_rad=0.02, dq_rad_s=0.1))
    wait_for(at_least(5, lambda: cell.controller.command_sets(hold=False)))
    with cell.controller.lock:
        cell.controller.q_drift_rad_per_cycle = -0.001  # the arm sags: q must not be re-sampled
    cell.control.policy = None
    assert_holds_keep_the_last_forwarded_position(cell)


def test_a_cycle_not_answered_before_the_next_arrived_is_counted_and_held_from_there(make_cell):
    cell = make_cell()
    cell.teach(follow(offset_rad=0.02, dq_rad_s=0.1))
    wait_for(at_least(5, lambda: cell.controller.command_sets(hold=False)))
    with cell.controller.lock:
        cell.controller.q_drift_rad_per_cycle = -0.001
        stop_at = cell.controller.counter + 10  # cycle counters are the driver's cycles here
        cell.controller.rush.add(stop_at)  # its next cycle follows at once: no time to answer
    policy = follow(offset_rad=0.02, dq_rad_s=0.1)
    cell.control.policy = lambda s: policy(s) if s.cycle < stop_at else None
    # past the rushed cycle: under a loaded suite an earlier cycle can go unanswered too (the
    # fake control's thread woke late: "cycle 7 got no answer before cycle 8", 2026-12-07),
    # and a count of 1 from it is no sign that the rush happened
    wait_for(
        lambda: cell.driver.unanswered >= 1 and cell.controller.counter > stop_at + 1,
        what="the rushed cycle passed and counted as unanswered",
    )
    assert_holds_keep_the_last_forwarded_position(cell)
    assert not cell.controller.sent_for(stop_at), "a cycle is not answered after the next came"
    assert all(s.cycle_counter != stop_at for s in cell.controller.command_sets())


def assert_holds_keep_the_last_forwarded_position(cell: Cell) -> None:
    """Once the control process stops answering, the driver holds every cycle at the last
    forwarded command (moved on by a coast, if one answered in between), never at a newly
    sampled q of a sagging arm, and each hold reaches the controller within its cycle."""
    n_sets = len(cell.controller.command_sets())
    wait_for(lambda: len(cell.controller.command_sets()) >= n_sets + 8, what="8 more sets")
    sets = cell.controller.command_sets()
    last_forwarded = max(i for i, s in enumerate(sets) if not s.hold)
    holds = sets[last_forwarded + 1 :]
    assert len(holds) >= 6 and all(h.hold for h in holds)
    # Between the last recorded command and the first recorded hold, each cycle was either
    # answered too late for this controller (a command, a coast or a hold set that reached
    # it after its next cycle began: dropped there, but kept by conftest_can) or not answered
    # at all (the driver's thread woke after the next cycle's frames, counted as unanswered:
    # seen once in a loaded suite, 2026-11-28). The holds keep the last set that was not a
    # hold: a forwarded command's position, or where a coast moved it on.
    last = sets[last_forwarded]
    unseen = (holds[0].cycle_counter - last.cycle_counter - 1) & 0xFFFF
    gap = [(last.cycle_counter + k) & 0xFFFF for k in range(1, unseen + 1)]
    unanswered = [c for c in gap if not cell.controller.sent_for(c)]
    assert len(unanswered) <= cell.driver.unanswered, "only late or unanswered cycles unseen"
    late = [cell.controller.sent_set(c) for c in gap if c not in unanswered]
    assert all(s is not None for s in late), "a late set came whole"
    moved_on = [s for s in late if s is not None and not s.hold]
    expected = moved_on[-1].q_cmd_rad if moved_on else last.q_cmd_rad
    for h in holds:
        np.testing.assert_allclose(h.q_cmd_rad, expected, atol=1e-9)
        np.testing.assert_array_equal(h.dq_cmd_rad_s, np.zeros(N))
    # Held once the deadline passed (typically ~11 ms here), within the same 20 ms cycle; a
    # rushed cycle's successor is the first hold, answered at its own deadline.
    delays = np.array([h.after_status_s for h in holds])
    assert np.all(delays >= DEADLINE_S - 0.001), f"held before the deadline: {delays * 1e3} ms"
    assert np.all(delays < PERIOD_S), "every hold reached the controller within its cycle"
    assert cell.driver.held >= len(holds)


def test_garbled_nan_and_out_of_range_commands_are_rejected(make_cell):
    cell = make_cell()

    def unsafe(s: JointState) -> Any:
        nan = np.full(N, np.nan)
        variants = [
            b"\x00 not a command",
            JointCommand(s.cycle, s.stamp_s, 0.0, nan, np.zeros(N)),  # NaN on the wire
            JointCommand(s.cycle, s.stamp_s, 0.0, s.q_rad[:5], np.zeros(5)),  # 5 joints
            JointCommand(s.cycle, s.stamp_s, 0.0, s.q_rad + 0.5, np.zeros(N)),  # following error
            JointCommand(s.cycle, s.stamp_s, 0.0, s.q_rad, np.full(N, 2.0)),  # too fast
        ]
        return variants[s.cycle % len(variants)]

    cell.teach(unsafe)
    wait_for(lambda: cell.driver.rejected["bad_message"] >= 6, what="6 bad messages")
    wait_for(lambda: cell.driver.rejected["out_of_range"] >= 4, what="4 out-of-range commands")
    assert cell.controller.command_sets(hold=False) == []
    assert cell.driver.forwarded == 0
    assert cell.controller.command_sets(hold=True)
    assert cell.controller.bad_frames == []


# --- CAN side faults ------------------------------------------------------------------------
def test_corrupt_or_missing_feedback_frame_drops_that_cycle(make_cell):
    def setup(controller: FakeController) -> None:
        controller.corrupt_joint[106] = 3  # JOINT_FB_J3 with DLC 7
        controller.skip_joint[109] = 2  # JOINT_FB_J2 missing

    cell = make_cell(first_counter=100, setup=setup)
    wait_for(lambda: any(s.cycle >= 112 for s in cell.control.joint_states()), what="cycle 112")
    cycles = {s.cycle for s in cell.control.joint_states()}
    assert {105, 107, 108, 110, 111} <= cycles
    assert 106 not in cycles and 109 not in cycles
    health = wait_for(
        lambda: (h := cell.control.last_health()) and h["cycles"] >= 10 and h,
        what="health after the bad cycles",
    )
    assert health["bad_frames"] >= 1
    assert health["corrupt_cycles"] >= 1 and health["incomplete_cycles"] >= 1


# --- servo requests -------------------------------------------------------------------------
def test_lifecycle_stopped_requests_brake(make_cell):
    cell = make_cell()
    cell.teach(follow())
    wait_for(lambda: cell.controller.state == ControllerState.EXTERNAL, what="EXTERNAL")
    n_before = len(cell.controller.request_log())
    cell.gateway.set(Lifecycle.STOPPED)
    wait_for(lambda: cell.controller.state == ControllerState.BRAKED, timeout_s=1.0)
    after = cell.controller.request_log()[n_before:]
    # (a SERVO_ON repeat may have been on its way; from the first BRAKE on, only BRAKE)
    assert HostRequest.BRAKE in after
    assert set(after[after.index(HostRequest.BRAKE) :]) == {HostRequest.BRAKE}
    wait_for(lambda: cell.controller.request_log().count(HostRequest.BRAKE) >= 3, timeout_s=1.0)


def test_silent_gateway_means_brake(make_cell):
    cell = make_cell()
    cell.gateway.set(Lifecycle.READY)
    wait_for(lambda: cell.controller.state == ControllerState.EXTERNAL, what="servo on (hold)")
    cell.gateway.silent = True
    t0 = time.monotonic()
    wait_for(lambda: cell.controller.state == ControllerState.BRAKED, timeout_s=2.0)
    assert time.monotonic() - t0 < cell.config.lifecycle_timeout_s + 0.15


def test_operator_reset_sends_reset_fault_once(make_cell):
    cell = make_cell()
    with cell.controller.lock:
        cell.controller.state, cell.controller.fault = ControllerState.FAULT, FaultCode.CMD_TIMEOUT
    cell.gateway.set(Lifecycle.FAULT)
    wait_for(
        lambda: any(s.controller_state == ControllerState.FAULT for s in cell.control.states),
        what="the controller's FAULT in a JointState",
    )
    time.sleep(0.1)
    assert HostRequest.RESET_FAULT not in cell.controller.request_log()
    cell.gateway.set(Lifecycle.STOPPED)
    wait_for(lambda: cell.controller.state == ControllerState.BRAKED, timeout_s=1.0)
    time.sleep(0.2)
    assert cell.controller.request_log().count(HostRequest.RESET_FAULT) == 1


# --- health and shutdown ----------------------------------------------------------------------
def test_health_reports_link_and_counters(make_cell):
    cell = make_cell()
    cell.teach(follow())
    wait_for(lambda: cell.driver.forwarded >= 3)
    health = wait_for(lambda: (h := cell.control.last_health()) and h["forwarded"] >= 3 and h)
    assert health["process"] == "can_driver"
    assert health["link_ok"] is True
    assert health["controller_state"] == "EXTERNAL"
    assert health["cycles"] >= 3 and health["held"] >= 0
    assert set(health["rejected"]) >= {
        "stale",
        "blocked_lifecycle",
        "blocked_enabling",
        "bad_message",
        "out_of_range",
        "late_cycle",
    }
    cell.controller.stop()  # controller silent → link down
    wait_for(lambda: cell.control.last_health()["link_ok"] is False, timeout_s=1.0)


def test_close_requests_brake_and_holds(make_cell):
    cell = make_cell()
    cell.teach(follow(offset_rad=0.02))
    wait_for(at_least(3, lambda: cell.controller.command_sets(hold=False)))
    late_before = cell.controller.late_frames
    cell.driver.close()
    wait_for(lambda: cell.controller.state == ControllerState.BRAKED, timeout_s=1.0)

    def hold_after_brake() -> bool:
        events = cell.controller.event_log()
        brake = max(i for i, (_, v) in enumerate(events) if v == HostRequest.BRAKE)
        holds = [v for kind, v in events[brake + 1 :] if kind == "set" and v.hold]
        return bool(holds) or cell.controller.late_frames > late_before

    # the exit hold set answers the newest cycle (late if the controller has just moved on)
    wait_for(hold_after_brake, timeout_s=1.0, what="the exit hold set")
    events = cell.controller.event_log()
    brake = max(i for i, (kind, v) in enumerate(events) if v == HostRequest.BRAKE)
    assert all(kind == "set" for kind, _ in events[brake + 1 :])
    assert not any(kind == "request" and v != HostRequest.BRAKE for kind, v in events[brake:])
    cell.driver.close()  # idempotent


#: how long the test below keeps this process's Python from running after the signal [s]: far
#: beyond the 90 ms a killed gateway's CiA 402 drives once ran on (drivers/can/rt/src/
#: driver_loop.rs, its docstring)
PYTHON_HELD_S = 0.3
#: how long this process's other threads get the GIL before the hold [s]: ten of the old switch
#: intervals (5 ms), so that every thread waiting for it has had it once
SETTLE_S = 0.05
#: the loop's BRAKE after the signal [ms]: its longest sleep (MAX_WAIT_S, 5 ms) plus the kernel's
#: wake-up of a second runnable thread on one CPU (the held thread keeps it busy; CFS/EEVDF give
#: a woken thread the CPU within its few-ms slice), with room for a slow machine
LOOP_BRAKE_MAX_MS = 30.0


#: how long the braked loop is watched for spinning [s], and the share of a CPU it may use:
#: a wake-up every MAX_WAIT_S (5 ms) costs tens of microseconds, ~1 %; a spinning loop used
#: all of one (2026-12-04); the clock ticks at 10 ms, so 0.5 s reads in steps of 2 %
IDLE_WATCH_S, IDLE_LOOP_MAX_BUSY = 0.5, 0.10


def test_a_stop_signal_makes_the_loop_brake_while_python_cannot_run(make_cell, caplog):
    """SIGTERM while this process's Python is held (one thread keeps the GIL for 0.3 s, so
    neither the signal watcher nor a close can run): the compiled loop sends the BRAKE by
    itself, within a few ms of the signal, and the controller brakes before anything in
    Python closed the driver. The gateway, I/O and controller timeouts are set beyond the
    hold, so that no silence brakes the arm instead."""
    stop = threading.Event()
    caplog.set_level(logging.INFO, logger="drivers.can.driver")
    with StopSignals(stop):
        cell = make_cell(
            brake_on_signals=True,
            lifecycle_timeout_s=5.0,
            io_timeout_s=5.0,
            controller_timeout_s=5.0,
        )
        cell.teach(follow(offset_rad=0.02))
        wait_for(at_least(3, lambda: cell.controller.command_sets(hold=False)))
        assert cell.controller.state != ControllerState.BRAKED
        previous = sys.getswitchinterval()
        sys.setswitchinterval(10 * PYTHON_HELD_S)  # no other Python thread gets the GIL
        try:
            # a thread already waiting for the GIL waits out the interval it started with
            # (5 ms) and then asks for it: given it once now, each waits the new one from here
            # (without this the watcher ran in one suite run of 2026-12-07, the hold not held)
            time.sleep(SETTLE_S)
            os.kill(os.getpid(), signal.SIGTERM)
            held_until = time.perf_counter() + PYTHON_HELD_S
            while time.perf_counter() < held_until:
                pass
            watcher_ran = stop.is_set()
        finally:
            sys.setswitchinterval(previous)
        assert not watcher_ran, "the signal watcher ran: Python was not held, nothing tested"
        wait_for(stop.is_set, timeout_s=1.0, what="the Python stop path")
        wait_for(lambda: cell.controller.state == ControllerState.BRAKED, timeout_s=1.0)
        # braked, the loop waits for the close without spinning (its deadlines are past)
        before_s = proc_stat.thread_cpu_s("can-cycle")
        time.sleep(IDLE_WATCH_S)
        busy = (proc_stat.thread_cpu_s("can-cycle") - before_s) / IDLE_WATCH_S
        cell.driver.close()
    assert busy <= IDLE_LOOP_MAX_BUSY, f"the braked loop kept {busy:.0%} of a CPU"
    notes = [r.getMessage() for r in caplog.records if "BRAKE sent by the loop" in r.getMessage()]
    assert len(notes) == 1, notes
    closes = [r.getMessage() for r in caplog.records if "BRAKE requested on exit" in r.getMessage()]
    assert len(closes) == 1 and "after the stop signal, whose BRAKE the loop had sent" in closes[0]
    after_ms = float(re.search(r"signal 15, ([0-9.]+) ms after it", notes[0]).group(1))
    assert after_ms <= LOOP_BRAKE_MAX_MS, notes[0]


def test_run_entry_point_until_stop_event(make_cell, tmp_path):
    cell = make_cell()
    config = tmp_path / "cell.toml"
    config.write_text(
        f"""
[bus]
endpoint = "{cell.bus.endpoint}"
key_prefix = "{cell.bus.key_prefix}"

[can]
deadline_s = {DEADLINE_S}

[can.transport]
interface = "seqpacket"
channel = "{cell.config.transport["channel"]}"
"""
    )
    cell.driver.close()  # the fixture's driver leaves; the process brings its own
    n_before = len(cell.control.joint_states())
    stop = threading.Event()
    status: list[int] = []

    def process() -> None:
        build = lambda: CanDriverProcess(config, stop_event=stop)  # noqa: E731
        status.append(run_service(PROCESS_NAME, build))

    thread = threading.Thread(target=process)
    thread.start()
    try:
        wait_for(lambda: len(cell.control.joint_states()) >= n_before + 5, what="joint states")
    finally:
        stop.set()
        thread.join(5.0)
    assert not thread.is_alive()
    assert status == [0]
    assert cell.controller.request_log()[-1] == HostRequest.BRAKE


def test_cli_help_and_bad_config(tmp_path, capsys):
    import argparse

    parser = configure_parser(argparse.ArgumentParser(prog="leadthrough can-driver"))
    help_text = parser.format_help()
    assert "--config" in help_text and "--bus" in help_text and "brake" in help_text
    bad = tmp_path / "bad.toml"
    bad.write_text('[can]\ndeadline_s = "soon"\n')
    assert cli_main(parser.parse_args(["--config", str(bad)])) == EXIT_CONFIG
    assert cli_main(parser.parse_args(["--config", str(tmp_path / "missing.toml")])) == EXIT_CONFIG


def test_sigterm_stops_the_process_cleanly(make_cell, tmp_path):
    cell = make_cell()
    cell.driver.close()
    config = tmp_path / "cell.toml"
    config.write_text(
        f"""
[bus]
key_prefix = "{cell.bus.key_prefix}"

[can.transport]
interface = "seqpacket"
channel = "{cell.config.transport["channel"]}"
"""
    )
    n_before = len(cell.control.joint_states())
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "drivers.can.driver", "--config", str(config)]
    proc = subprocess.Popen(
        [*cmd, "--bus", cell.bus.endpoint],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        wait_for(lambda: len(cell.control.joint_states()) >= n_before + 3, timeout_s=10.0)
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=5.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out.decode(errors="replace")
    wait_for(lambda: cell.controller.request_log()[-1] == HostRequest.BRAKE, timeout_s=1.0)


def test_no_virtual_controller_is_one_clear_link_error(router):
    transport = {
        "interface": "seqpacket",
        "channel": unique_can_address(),
        "connect_timeout_s": 0.3,
    }
    bus = BusConfig(endpoint=router, key_prefix="tx")
    driver = CanDriver(driver_config(transport=transport), bus)
    with pytest.raises(LinkTimeoutError, match=r"no seqpacket CAN server at .* after 0\.3 s"):
        driver.start()
    driver.close()


# --- fuzz -------------------------------------------------------------------------------------
FUZZ_FRAMES = 100_000
ADAPTER_STATS = ("unknown_frames", "bad_frames", "incomplete_cycles", "corrupt_cycles")


def adapter_stats(cell: Cell) -> dict[str, int]:
    """The compiled adapter's frame counters, from the driver's health."""
    health = cell.driver.health()
    return {k: health[k] for k in ADAPTER_STATS}


@dataclass
class Fuzz:
    frames: list[can.Message]
    bad: int  #: how many of them LTC-1 refuses to decode
    unknown: int  #: on ids LTC-1 does not define
    forged: list[can.Message]  #: drawn as a valid JOINT_FB or CTRL_STATUS, and drawn again


def random_frames(rng: np.random.Generator, n: int, proto: LtcProtocol) -> Fuzz:
    """``n`` random data frames, half of them on LTC-1's own ids (every length 0..8, any bytes,
    now and then an extended id), the other half on any 11-bit id. (No remote frames: the
    compiled driver's own fuzz tests cover those.)

    A random frame that decodes as a valid JOINT_FB or CTRL_STATUS is drawn again, and counted.
    The controller's frames carry no CRC of their own (PROTOCOL.md §4: classic CAN's frame CRC
    guards the wire), so about one random 8-byte JOINT_FB in nine decodes: such a frame is not
    malformed but forged, indistinguishable from the controller's on any receiver, and the
    driver's defences against it are the cycle counter it must match and the plausibility of
    the positions (the next two tests). Every other frame is classified here as the driver
    must count it.
    """
    ours = sorted(
        {
            *proto.cycle_frame_ids,
            proto.request_id,
            proto.heartbeat_id("CTRL"),
            proto.heartbeat_id("HOST"),
            *(proto.command_id(j + 1) for j in range(N)),
        }
    )
    fuzz = Fuzz([], 0, 0, [])
    while len(fuzz.frames) < n:
        ident = int(rng.choice(ours)) if rng.random() < 0.5 else int(rng.integers(0, 0x800))
        dlc = int(rng.integers(0, 9))
        msg = can.Message(
            arbitration_id=ident,
            is_extended_id=bool(rng.random() < 0.02),
            dlc=dlc,
            data=rng.bytes(dlc),
        )
        try:
            valid = proto.decode(msg)
        except FrameError:
            fuzz.bad += 1
        else:
            if isinstance(valid, JointFeedback | ControllerStatus):
                fuzz.forged.append(msg)
                continue
            fuzz.unknown += valid is None
        fuzz.frames.append(msg)
    return fuzz


def test_100k_random_frames_never_reach_a_measurement_or_a_command(make_cell):
    """Issue 10's fuzz: 100,000 random frames thrown at a teaching driver, as fast as the
    transport takes them, interleaved with the controller's real cycles. Every frame is
    counted as bad or unknown; no fuzzed value reaches a published measurement or a command;
    whatever the lost cycles made the driver do, it answered every cycle it published with a
    hold or with a command within the follower's reach of the controller's true position; and
    the driver is alive and commands again once the operator re-arms."""
    cell = make_cell()
    cell.teach(follow())
    wait_for(lambda: cell.driver.forwarded >= 5, what="teaching")
    before = adapter_stats(cell)
    fuzz = random_frames(np.random.default_rng(10), FUZZ_FRAMES, LtcProtocol(N))
    assert len(fuzz.forged) < FUZZ_FRAMES // 20
    t0 = time.monotonic()
    cell.controller.inject(fuzz.frames)
    wait_for(lambda: not cell.controller.injecting(), timeout_s=60.0, what="the fuzz sent")
    sent_s = time.monotonic() - t0
    wait_for(
        lambda: (
            (stats := adapter_stats(cell))["unknown_frames"] - before["unknown_frames"]
            >= fuzz.unknown
            and stats["bad_frames"] - before["bad_frames"] >= fuzz.bad
        ),
        timeout_s=60.0,
        what=f"the driver to take {FUZZ_FRAMES} frames (now {adapter_stats(cell)})",
    )
    stats = adapter_stats(cell)
    print(f"\n{FUZZ_FRAMES} frames sent in {sent_s:.1f} s; driver stats {stats}")
    assert cell.driver.running, f"the driver died: {cell.driver.failed!r}"
    # every fuzz frame counted as the protocol classifies it, none taken for another kind
    assert stats["unknown_frames"] - before["unknown_frames"] == fuzz.unknown
    assert stats["bad_frames"] - before["bad_frames"] == fuzz.bad
    assert stats["corrupt_cycles"] > before["corrupt_cycles"]
    for s in cell.control.joint_states():
        sent = cell.controller.sent[s.cycle & 0xFFFF]
        np.testing.assert_allclose(s.q_rad, sent.q_rad, atol=0.5e-6)
        np.testing.assert_allclose(s.dq_rad_s, sent.dq_rad_s, atol=0.5e-4)
    for cset in cell.controller.command_sets(hold=False):
        truth = cell.controller.sent[cset.cycle_counter].q_rad
        reach = np.abs(cset.q_cmd_rad - truth)
        assert np.all(reach <= FOLLOW_REACH_RAD + 1e-5), "a command left reach"
    assert cell.controller.bad_frames == [], "the driver itself sent malformed frames"
    # the operator re-arms: teaching commands again
    cell.gateway.set(Lifecycle.STOPPED)
    wait_for(lambda: cell.controller.state == ControllerState.BRAKED, what="braked")
    forwarded = cell.driver.forwarded
    cell.teach(follow())
    wait_for(lambda: cell.driver.forwarded >= forwarded + 5, what="teaching after the fuzz")


def test_random_frames_that_decode_as_feedback_never_move_the_arm(make_cell):
    """The frames the fuzz above draws again: random JOINT_FB and CTRL_STATUS frames that
    decode (LTC-1's feedback carries no CRC of its own), a broken node speaking the
    controller's ids. Most miss the cycle counter and drop their cycle; one whose counter byte
    matches by chance (1 in 256) is a forged measurement, and the driver must not let it move
    the arm: every command set the controller accepts stays within the follower's reach of
    the controller's true position."""
    cell = make_cell()
    cell.teach(follow())
    wait_for(lambda: cell.driver.forwarded >= 5, what="teaching")
    forged = random_frames(np.random.default_rng(11), 2 * FUZZ_FRAMES, LtcProtocol(N)).forged
    assert len(forged) > 2000
    before = adapter_stats(cell)
    cell.controller.inject(forged, per_cycle=40)
    wait_for(lambda: not cell.controller.injecting(), timeout_s=30.0, what="the forged frames sent")
    time.sleep(5 * PERIOD_S)
    stats = adapter_stats(cell)
    dropped = sum(stats[k] - before[k] for k in ("incomplete_cycles", "corrupt_cycles"))
    print(f"\n{len(forged)} forged frames; driver stats {stats}")
    for st in cell.control.joint_states():
        sent = cell.controller.sent[st.cycle & 0xFFFF]
        np.testing.assert_allclose(st.q_rad, sent.q_rad, atol=0.5e-6)
    assert dropped > 0
    assert cell.driver.running, f"the driver died: {cell.driver.failed!r}"
    for cset in cell.controller.command_sets(hold=False):
        truth = cell.controller.sent[cset.cycle_counter].q_rad
        assert np.all(np.abs(cset.q_cmd_rad - truth) <= FOLLOW_REACH_RAD + 1e-5), (
            f"cycle {cset.cycle_counter}: command {cset.q_cmd_rad} for true position {truth}"
        )


def test_a_forged_measurement_with_the_right_counter_never_moves_the_arm(make_cell):
    """A node that knows LTC-1 (or a controller whose encoder glitched): now and then one
    joint's JOINT_FB with the right counter and a position that jumps. Measured positions are
    then wrong for a cycle, and a follower would command them: the driver drops each such
    cycle as implausible (a joint faster than feedback_max_joint_speed_rad_s, here 2 rad/s:
    0.04 rad in a 20 ms cycle), and the arm never follows."""
    cell = make_cell(feedback_max_joint_speed_rad_s=2.0)
    cell.teach(follow())
    wait_for(lambda: cell.driver.forwarded >= 5, what="teaching")
    rng = np.random.default_rng(12)
    proto = LtcProtocol(N)
    forged_at: list[int] = []

    def forge(counter: int) -> list[can.Message]:
        if counter % 7:
            return []
        joint = int(rng.integers(1, N + 1))
        q = float(cell.controller.q_rad[joint - 1] + rng.choice([-1, 1]) * rng.uniform(0.05, 2.0))
        forged_at.append(counter)
        return [proto.encode_feedback(joint, q, 0.0, 0.0, counter & 0xFF)]

    cell.controller.forge = forge
    wait_for(lambda: len(forged_at) >= 30, timeout_s=30.0, what="30 forged cycles")
    cell.controller.forge = None
    time.sleep(5 * PERIOD_S)
    states = cell.control.joint_states()
    n_forged = sum(
        not np.allclose(st.q_rad, cell.controller.sent[st.cycle & 0xFFFF].q_rad, atol=0.5e-6)
        for st in states
    )
    health = cell.driver.health()
    assert n_forged == 0, f"{n_forged} of {len(forged_at)} forged positions were published"
    assert health["implausible_cycles"] == len(forged_at)
    assert cell.driver.forwarded > 100, "the true cycles between the forged ones were taken"
    for cset in cell.controller.command_sets(hold=False):
        truth = cell.controller.sent[cset.cycle_counter].q_rad
        assert np.all(np.abs(cset.q_cmd_rad - truth) <= FOLLOW_REACH_RAD + 1e-5), (
            f"cycle {cset.cycle_counter}: command {cset.q_cmd_rad} for true position {truth}"
        )
