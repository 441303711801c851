"""The CAN driver process: the robot controller's CAN link on one side, the zenoh bus on the other.

Every control cycle the controller sends its joint feedback; the driver publishes it as a
JointState and answers the cycle exactly once, with either

* the control process's JointCommand for that cycle, forwarded only if every check passes
  (lifecycle TEACHING or IDENTIFYING, enabling device held and e-stop chain closed, controller
  servoing, the command fresh, for this very cycle, within the following-error and velocity
  limits), or
* a hold set (hold=1, zero velocity) at a position latched when holding began: at once when
  forwarding is not allowed, otherwise when the cycle's answer deadline passes.

The answer deadline of a cycle is ``min(deadline_s, answer_by_period_fraction × period)`` after
its JointState stamp: a command set must reach the controller before the next cycle begins or
it is a missed cycle (PROTOCOL.md §3), so with the defaults (10 ms, 0.5) and a 4 ms cycle the
hold goes out 2 ms into the cycle. A command arriving after its cycle was answered is rejected
as ``late_cycle``.

Servo power is requested from the gateway's lifecycle (READY, TEACHING or IDENTIFYING, and
fresh: SERVO_ON; anything else, including silence: BRAKE), repeated with every host heartbeat.
The default, the ``except`` path and the exit path all lead to BRAKE.

Threads: the main loop owns the CAN receive side and the adapter's cycle assembly; zenoh
callbacks decode, check and send under one lock and never wait for anything but that lock.
"""

from __future__ import annotations

import argparse
import logging
import signal
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np

from drivers.can.adapter import ADAPTER_GROUP, CanAdapter, CycleFeedback, HostRequest
from drivers.can.config import CanDriverConfig, load_can_config
from drivers.registry import load_adapter
from gateway.bus import BusConfig, declare_loop_publisher, open_peer, undeclare_all
from gateway.config import require
from gateway.errors import ConfigError, FrameError, LinkTimeoutError, MessageError
from gateway.messages import (
    COMMANDING,
    FLAG_ESTOP,
    FLAG_PREV_COAST,
    FLAG_PREV_HOLD,
    FLAG_SERVO_POWER,
    HEALTH_RATE_HZ,
    ControllerState,
    IoState,
    JointCommand,
    Lifecycle,
    LifecycleMsg,
    encode_json,
    make_joint_state,
)

log = logging.getLogger(__name__)

PROCESS_NAME = "can_driver"

#: Why a JointCommand was not forwarded (the keys of the health message's "rejected").
REJECT_REASONS = (
    "stale",  # older than deadline_s
    "blocked_lifecycle",  # lifecycle not TEACHING/IDENTIFYING, or silent
    "blocked_enabling",  # enabling device released, e-stop chain open, or I/O silent
    "blocked_controller",  # controller not servoing (BRAKED/FAULT) or its link is down
    "bad_message",  # undecodable payload, NaN, wrong joint count
    "out_of_range",  # following error, velocity, or a value the protocol cannot carry
    "late_cycle",  # not for the current cycle, or that cycle was already answered
)

_SERVOING = (ControllerState.HOLD, ControllerState.EXTERNAL)
_BRAKED = (ControllerState.BRAKED, ControllerState.FAULT)


def _fresh(stamp_s: float, received_s: float, now_s: float, timeout_s: float) -> bool:
    """Both the sender's stamp and our receipt are recent (a future stamp never keeps it fresh)."""
    return (now_s - received_s) < timeout_s and -timeout_s < (now_s - stamp_s) < timeout_s


class _DropPartialReadNotes(logging.Filter):
    """python-can's socketcand client warns "Got incomplete message" whenever one TCP read ends
    mid-frame (it then waits for the rest: nothing is lost). Under load that is every few
    cycles; keep its other warnings (bad data, invalid frames)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Got incomplete message")


_SOCKETCAND_LOG = logging.getLogger("can.interfaces.socketcand.socketcand")


def _quiet_socketcand_partial_reads() -> None:
    if not any(isinstance(f, _DropPartialReadNotes) for f in _SOCKETCAND_LOG.filters):
        _SOCKETCAND_LOG.addFilter(_DropPartialReadNotes())


def _await_socketcand_server(transport: dict[str, Any], timeout_s: float) -> None:
    """Wait until the socketcand server accepts TCP connections, or raise LinkTimeoutError.

    python-can's client retries a refused connection in a tight loop for 10 s, logging each
    attempt; checking first turns "the virtual controller is not up" into one clear error.
    """
    host, port = transport["host"], transport["port"]
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=0.5):
                return
        except OSError as exc:
            if time.monotonic() >= deadline:
                raise LinkTimeoutError(
                    f"no socketcand server at {host}:{port} after {timeout_s:g} s ({exc}); "
                    "is the virtual controller (leadthrough sim) running?"
                ) from None
            time.sleep(0.1)


def _next_tick(previous_s: float, period_s: float, now_s: float) -> float:
    """Next time of a periodic action: on the grid, or one period from now if behind."""
    following = previous_s + period_s
    return following if following > now_s else now_s + period_s


class _RateLimitedLog:
    """At most one record per key and period; says how many were suppressed in between."""

    def __init__(self, logger: logging.Logger, period_s: float, clock: Callable[[], float]):
        self._log, self._period_s, self._clock = logger, period_s, clock
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._lock = threading.Lock()

    def __call__(self, level: int, key: str, msg: str, *args: Any) -> None:
        now = self._clock()
        with self._lock:
            last = self._last.get(key)
            if last is not None and now - last < self._period_s:
                self._suppressed[key] = self._suppressed.get(key, 0) + 1
                return
            self._last[key] = now
            suppressed = self._suppressed.pop(key, 0)
        if suppressed:
            msg += f" (+{suppressed} similar in the last {self._period_s:g} s)"
        self._log.log(level, msg, *args)


@dataclass
class _Cycle:
    """The newest complete controller cycle, waiting for (or given) its answer."""

    cycle: int  #: widened cycle counter (JointState.cycle)
    counter: int  #: the counter as on the wire
    stamp_s: float  #: JointState.stamp_s [s]
    answer_by_s: float  #: hold if still unanswered at this time [s]
    q_rad: np.ndarray  #: measured positions of the cycle [rad]
    answered: bool = False
    #: how it was answered: "command" (forwarded), "coast" or "hold"
    answer: str = ""


class CanDriver:
    """The CAN driver. ``start()`` opens the links and runs the loop thread; ``close()`` brakes.

    ``clock`` returns monotonic seconds; every stamp and deadline uses it. ``can_bus`` and
    ``session`` may be injected (then the caller closes them); otherwise they are opened from
    ``config.transport`` and ``bus_config``.
    """

    #: Longest wait in bus.recv before the loop checks deadlines and heartbeats [s].
    RECV_TIMEOUT_S = 0.001
    #: Longest a CAN send may block (socketcan tx queue full) [s].
    SEND_TIMEOUT_S = 0.005
    #: Period of health messages [s].
    HEALTH_PERIOD_S = 1.0 / HEALTH_RATE_HZ
    #: Rate limit of repeated log records, per reason [s].
    LOG_PERIOD_S = 1.0
    #: How long stop() waits for the loop thread [s].
    JOIN_TIMEOUT_S = 2.0
    #: How long open() waits for a socketcand server to accept connections [s].
    CONNECT_TIMEOUT_S = 5.0

    def __init__(
        self,
        config: CanDriverConfig,
        bus_config: BusConfig,
        *,
        clock: Callable[[], float] = time.monotonic,
        adapter: CanAdapter | None = None,
        can_bus: can.BusABC | None = None,
        session: Any = None,
    ) -> None:
        self.config = config
        self.bus_config = bus_config
        self.keys = bus_config.keys
        self._clock = clock
        if adapter is None:
            adapter_cls = load_adapter(ADAPTER_GROUP, config.adapter)
            adapter = adapter_cls(n_joints=config.joints)
        self.adapter: CanAdapter = adapter
        require(
            adapter.n_joints == config.joints,
            "[can].joints",
            f"{config.joints} but the adapter is built for {adapter.n_joints}",
        )
        require(
            config.heartbeat_period_s <= adapter.host_heartbeat_timeout_s / 2,
            "[can].heartbeat_period_s",
            f"{config.heartbeat_period_s} s; the controller faults after "
            f"{adapter.host_heartbeat_timeout_s} s without a heartbeat, so send at least twice "
            "within that",
        )
        self._max_fe = np.array(config.max_following_error_rad, dtype=float)
        self._max_dq = np.array(config.max_velocity_rad_s, dtype=float)
        self._zeros = np.zeros(config.joints)

        self._bus = can_bus
        self._owns_bus = can_bus is None
        self._session = session
        self._owns_session = session is None
        self._subscribers: list[Any] = []
        self._publisher: Any = None

        self._lock = threading.Lock()  # guards everything below and every CAN send
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closing = False
        self._closed = False
        self.failed: BaseException | None = None  #: the error that ended the loop, if any
        self._rlog = _RateLimitedLog(log, self.LOG_PERIOD_S, clock)

        # inputs from zenoh
        self._lifecycle: LifecycleMsg | None = None
        self._lifecycle_rx_s = -np.inf
        self._io: IoState | None = None
        self._io_rx_s = -np.inf
        self._reset_wanted = False
        # controller
        self._feedback: CycleFeedback | None = None
        self._last_cycle_rx_s = -np.inf
        self._last_counter: int | None = None
        self._cycle = 0
        self._pending: _Cycle | None = None
        # what we asked for and sent
        self._request_sent: HostRequest | None = None
        self._next_heartbeat_s = -np.inf
        self._next_health_s = -np.inf
        self._last_sent_q: np.ndarray | None = None
        self._last_sent_dq: np.ndarray | None = None
        self._last_forwarded_q: np.ndarray | None = None  #: since servo-on
        #: (state stamp, cycle, q_cmd, dq_cmd, period) of the last forwarded command: coasting
        self._last_forward: tuple[float, int, np.ndarray, np.ndarray, float] | None = None
        self.coasted = 0  #: late cycles answered by coasting on the last command
        self._hold_q: np.ndarray | None = None
        self._holding = False
        # counters
        self.rejected = dict.fromkeys(REJECT_REASONS, 0)
        self.cycles = 0
        self.forwarded = 0
        self.held = 0
        self.unanswered = 0
        self.send_errors = 0
        self.bad_inputs = 0
        self.recv_errors = 0

    # --- lifecycle --------------------------------------------------------------------------
    def start(self) -> None:
        """:meth:`open` the links, then run :meth:`spin_once` in the loop thread."""
        if self._thread is not None or self._closed:
            raise RuntimeError("CanDriver.start() called twice or after close()")
        self.open()
        self._thread = threading.Thread(target=self._loop, name="can-driver", daemon=True)
        self._thread.start()

    def open(self) -> None:
        """Open the CAN bus and the zenoh session and subscribe; no thread (tests may then
        drive :meth:`spin_once` themselves). Idempotent; on failure everything is closed."""
        if self._closed:
            raise RuntimeError("CanDriver.open() after close()")
        if self._publisher is not None:
            return
        try:
            if self._bus is None:
                if self.config.transport.get("interface") == "socketcand":
                    _await_socketcand_server(self.config.transport, self.CONNECT_TIMEOUT_S)
                    _quiet_socketcand_partial_reads()
                self._bus = can.Bus(**self.config.transport)
            if self._session is None:
                self._session = open_peer(self.bus_config)
            session, keys = self._session, self.keys
            self._publisher = declare_loop_publisher(session, keys.joint_state)
            self._subscribers = [
                session.declare_subscriber(keys.lifecycle, self._on_lifecycle),
                session.declare_subscriber(keys.io_state, self._on_io_state),
                session.declare_subscriber(keys.joint_command, self._on_joint_command),
            ]
        except BaseException:
            self.close()
            raise
        log.info(
            "CAN driver up: adapter %s, %d joints, CAN %s, zenoh %s",
            self.adapter.name,
            self.config.joints,
            getattr(self._bus, "channel_info", "?"),
            self.bus_config.endpoint,
        )

    def stop(self) -> None:
        """Stop the loop thread. Idempotent; never raises."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(self.JOIN_TIMEOUT_S)
            if thread.is_alive():
                log.error("CAN driver loop did not stop within %.1f s", self.JOIN_TIMEOUT_S)

    def close(self) -> None:
        """Stop, ask the controller to brake (and hold), release every link. Never raises."""
        self.stop()
        with self._lock:
            if self._closed:
                return
            self._closing = True  # callbacks stop sending from here on
            self._closed = True
            if self._bus is not None:
                try:
                    self._send_locked([self.adapter.request_frame(HostRequest.BRAKE)])
                    self._request_sent = HostRequest.BRAKE
                except Exception:
                    log.exception("could not send the BRAKE request on exit")
                try:
                    if self._pending is not None:
                        self._send_locked(self._hold_frames_locked(self._pending))
                except Exception:
                    log.exception("could not send the hold set on exit")
        undeclare_all([*self._subscribers, self._publisher])
        self._subscribers, self._publisher = [], None
        if self._owns_session and self._session is not None:
            try:
                self._session.close()
            except Exception:
                log.exception("could not close the zenoh session")
        self._session = None
        if self._owns_bus and self._bus is not None:
            try:
                self._bus.shutdown()
            except Exception:
                log.exception("could not shut the CAN bus down")
        self._bus = None

    def __enter__(self) -> CanDriver:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def running(self) -> bool:
        thread = self._thread
        return thread is not None and thread.is_alive()

    # --- main loop --------------------------------------------------------------------------
    def _loop(self) -> None:
        try:
            while not self._stop.is_set():
                self.spin_once()
        except Exception as exc:  # a bug: stop answering; close() brakes
            self.failed = exc
            log.exception("CAN driver loop failed; stopping (the controller will brake)")
            self._stop.set()

    def spin_once(self, recv_timeout_s: float | None = None) -> None:
        """Receive at most one frame, then run the deadline, request, heartbeat and health
        checks. The loop thread calls this; tests without the thread may call it directly."""
        bus = self._bus
        if bus is None:
            raise RuntimeError("CanDriver is not open")
        timeout = self.RECV_TIMEOUT_S if recv_timeout_s is None else recv_timeout_s
        try:
            msg = bus.recv(timeout=timeout)
        except can.CanError as exc:
            self.recv_errors += 1
            self._rlog(logging.ERROR, "recv", "CAN receive failed: %s", exc)
            self._stop.wait(0.01)
            msg = None
        now = self._clock()
        if msg is not None:
            stats = self.adapter.stats
            dropped = stats.bad_frames + stats.incomplete_cycles + stats.corrupt_cycles
            feedback = self.adapter.feed(msg)
            if feedback is not None:
                self._on_cycle(feedback, now)
            elif stats.bad_frames + stats.incomplete_cycles + stats.corrupt_cycles != dropped:
                self._rlog(logging.WARNING, "frame", "CAN: %s", stats.last_error)
        self._periodic(now)

    def _widen(self, counter: int) -> int | None:
        """Wire counter → monotonically increasing cycle number; None for a repeated counter."""
        if self._last_counter is None:
            self._cycle = counter
        else:
            delta = (counter - self._last_counter) % self.adapter.counter_modulus
            if delta == 0:
                return None
            self._cycle += delta
        self._last_counter = counter
        return self._cycle

    def _on_cycle(self, fb: CycleFeedback, now: float) -> None:
        with self._lock:
            if self._closing:
                return
            cycle = self._widen(fb.counter)
            if cycle is None:
                self._rlog(logging.WARNING, "dup", "controller repeated cycle %d", fb.counter)
                return
            previous = self._pending
            if previous is not None and not previous.answered:
                self.unanswered += 1
                self._rlog(
                    logging.WARNING,
                    "unanswered",
                    "cycle %d got no answer before cycle %d arrived",
                    previous.cycle,
                    cycle,
                )
            self.cycles += 1
            self._feedback, self._last_cycle_rx_s = fb, now
            if fb.controller_state in _BRAKED:
                # On its brakes the arm is where it is: the next hold starts from there.
                self._holding, self._last_forwarded_q = False, None
                self._last_forward = None
            budget_s = self.config.deadline_s
            if fb.cycle_period_s > 0:
                budget_s = min(budget_s, self.config.answer_by_period_fraction * fb.cycle_period_s)
            pending = _Cycle(cycle, fb.counter, now, now + budget_s, fb.q_rad)
            self._pending = pending
            q_cmd = fb.q_rad if self._last_sent_q is None else self._last_sent_q
            dq_cmd = self._zeros if self._last_sent_dq is None else self._last_sent_dq
            flags = int(fb.estop_active) * FLAG_ESTOP | int(fb.servo_power) * FLAG_SERVO_POWER
            if previous is not None and previous.cycle == cycle - 1:
                if previous.answer == "coast":
                    flags |= FLAG_PREV_COAST
                elif previous.answer != "command":  # a hold, or none (the controller froze)
                    flags |= FLAG_PREV_HOLD
            state = make_joint_state(
                cycle,
                now,
                fb.controller_state,
                flags,
                fb.q_rad,
                fb.dq_rad_s,
                fb.current_a,
                q_cmd,
                dq_cmd,
                fb.cycle_period_s,
            )
            blocked = self._blocked_locked(now)
            if blocked is not None:
                self._send_hold_locked(pending)
        publisher = self._publisher
        if publisher is not None:
            try:
                publisher.put(state.to_bytes())
            except Exception as exc:  # zenoh; the controller is still answered (hold)
                self._rlog(logging.ERROR, "put", "cannot publish the joint state: %s", exc)

    def _periodic(self, now: float) -> None:
        health: dict[str, Any] | None = None
        with self._lock:
            if self._closing:
                return
            pending = self._pending
            late = pending is not None and not pending.answered and now >= pending.answer_by_s
            if late and not self._send_coast_locked(pending, now):
                self._send_hold_locked(pending)
            desired = self._desired_request(now)
            heartbeat_due = now >= self._next_heartbeat_s
            frames: list[can.Message] = []
            if heartbeat_due:
                frames.append(self.adapter.heartbeat_frame())
                self._next_heartbeat_s = _next_tick(
                    self._next_heartbeat_s, self.config.heartbeat_period_s, now
                )
            if desired != self._request_sent or heartbeat_due:
                if desired == HostRequest.SERVO_ON and self._request_sent != desired:
                    # A new servo-on period: nothing forwarded in it yet.
                    self._holding, self._last_forwarded_q = False, None
                    self._last_forward = None
                if desired != self._request_sent:
                    log.info("requesting %s from the controller", desired.name)
                frames.append(self.adapter.request_frame(desired))
                self._request_sent = desired
            if self._reset_wanted:
                self._reset_wanted = False
                fb = self._feedback
                if fb is not None and fb.controller_state == ControllerState.FAULT:
                    log.info("operator reset: asking the controller to leave FAULT (%s)", fb.fault)
                    frames.append(self.adapter.request_frame(HostRequest.RESET_FAULT))
                    self._request_sent = HostRequest.RESET_FAULT  # BRAKE follows next pass
            if frames:
                self._send_locked(frames)
            if now >= self._next_health_s:
                self._next_health_s = _next_tick(self._next_health_s, self.HEALTH_PERIOD_S, now)
                health = self._health_locked(now)
        session = self._session
        if health is not None and session is not None:
            try:
                session.put(self.keys.health(PROCESS_NAME), encode_json(health))
            except Exception as exc:
                self._rlog(logging.ERROR, "health", "cannot publish health: %s", exc)

    # --- decisions (call with the lock held) ------------------------------------------------
    def _desired_request(self, now: float) -> HostRequest:
        lc = self._lifecycle
        if lc is None or not _fresh(
            lc.stamp_s, self._lifecycle_rx_s, now, self.config.lifecycle_timeout_s
        ):
            return HostRequest.BRAKE
        if lc.state in (Lifecycle.READY, *COMMANDING):
            return HostRequest.SERVO_ON
        return HostRequest.BRAKE

    def _link_ok(self, now: float) -> bool:
        return (now - self._last_cycle_rx_s) < self.config.controller_timeout_s

    def _blocked_locked(self, now: float) -> str | None:
        """The reason forwarding is not allowed right now, or None if it is."""
        lc = self._lifecycle
        if (
            lc is None
            or lc.state not in COMMANDING
            or not _fresh(lc.stamp_s, self._lifecycle_rx_s, now, self.config.lifecycle_timeout_s)
        ):
            return "blocked_lifecycle"
        io = self._io
        if (
            io is None
            or not io.enabling
            or not io.estop_ok
            or not _fresh(io.stamp_s, self._io_rx_s, now, self.config.io_timeout_s)
        ):
            return "blocked_enabling"
        fb = self._feedback
        if fb is None or fb.controller_state not in _SERVOING or not self._link_ok(now):
            return "blocked_controller"
        return None

    def _check_command(self, cmd: JointCommand, now: float) -> tuple[str, str] | None:
        """(reason, detail) if ``cmd`` must not be forwarded, else None."""
        n = self.config.joints
        if cmd.n != n:
            return "bad_message", f"{cmd.n} joints, expected {n}"
        blocked = self._blocked_locked(now)
        if blocked is not None:
            return blocked, f"cycle {cmd.cycle}"
        pending = self._pending
        if pending is None or cmd.cycle != (pending.cycle & 0xFFFFFFFF):
            current = None if pending is None else pending.cycle
            return "late_cycle", f"for cycle {cmd.cycle}, current cycle is {current}"
        if pending.answered:
            return "late_cycle", f"cycle {cmd.cycle} was already answered"
        age_s = now - min(cmd.state_stamp_s, pending.stamp_s)
        if age_s > self.config.deadline_s:
            return "stale", f"cycle {cmd.cycle} is {age_s * 1e3:.1f} ms old"
        error = np.abs(cmd.q_cmd_rad - pending.q_rad)
        if np.any(error > self._max_fe):
            k = int(np.argmax(error - self._max_fe))
            return "out_of_range", (
                f"joint {k + 1}: |q_cmd - q| = {error[k]:.4f} rad > {self._max_fe[k]:g} rad"
            )
        speed = np.abs(cmd.dq_cmd_rad_s)
        if np.any(speed > self._max_dq):
            k = int(np.argmax(speed - self._max_dq))
            return "out_of_range", (
                f"joint {k + 1}: |dq_cmd| = {speed[k]:.4f} rad/s > {self._max_dq[k]:g} rad/s"
            )
        return None

    def _hold_frames_locked(self, pending: _Cycle) -> list[can.Message]:
        if not self._holding:
            q_meas = pending.q_rad
            last = self._last_forwarded_q
            if last is not None and np.all(np.abs(last - q_meas) <= self._max_fe):
                self._hold_q = last.copy()
            else:
                self._hold_q = q_meas.copy()
            self._holding = True
        assert self._hold_q is not None
        return self.adapter.command_frames(pending.counter, self._hold_q, self._zeros, True)

    def _send_coast_locked(self, pending: _Cycle, now: float) -> bool:
        """Answer a cycle whose command is late with the last forwarded command, moved on by its
        own velocity (what the controller's interpolation does within a cycle), as long as that
        command is not older than ``deadline_s``; True if sent. One late answer then costs
        nothing, where a hold would jerk the operator's arm."""
        last = self._last_forward
        if last is None or self._holding or now - last[0] > self.config.deadline_s:
            return False
        _stamp, cycle, q, dq, period = last
        q_coast = q + dq * (pending.cycle - cycle) * period
        try:
            frames = self.adapter.command_frames(pending.counter, q_coast, dq, False)
        except FrameError:
            return False
        if self._send_locked(frames):
            pending.answered, pending.answer = True, "coast"
            self.coasted += 1
            self._last_sent_q, self._last_sent_dq = q_coast, dq
        return True

    def _send_hold_locked(self, pending: _Cycle) -> None:
        try:
            frames = self._hold_frames_locked(pending)
        except FrameError as exc:  # measured q the protocol cannot carry: nothing to hold
            self._rlog(logging.ERROR, "hold", "cannot build a hold set: %s", exc)
            return
        if self._send_locked(frames):
            pending.answered, pending.answer = True, "hold"
            self.held += 1
            self._last_sent_q, self._last_sent_dq = self._hold_q, self._zeros

    def _send_locked(self, frames: list[can.Message]) -> bool:
        bus = self._bus
        if bus is None:
            return False
        try:
            for frame in frames:
                bus.send(frame, timeout=self.SEND_TIMEOUT_S)
        except (can.CanError, OSError) as exc:
            self.send_errors += 1
            self._rlog(logging.ERROR, "send", "CAN send failed: %s", exc)
            return False
        return True

    def _reject_locked(self, reason: str, detail: str) -> None:
        self.rejected[reason] += 1
        level = logging.INFO if reason.startswith("blocked_") else logging.WARNING
        self._rlog(level, reason, "JointCommand not forwarded (%s): %s", reason, detail)

    def _health_locked(self, now: float) -> dict[str, Any]:
        fb, stats = self._feedback, self.adapter.stats
        return {
            "process": PROCESS_NAME,
            "stamp_s": now,
            "controller_state": None if fb is None else fb.controller_state.name,
            "controller_fault": None if fb is None else fb.fault,
            "link_ok": self._link_ok(now),
            "servo_request": None if self._request_sent is None else self._request_sent.name,
            "cycles": self.cycles,
            "forwarded": self.forwarded,
            "held": self.held,
            "coasted": self.coasted,
            "unanswered": self.unanswered,
            "rejected": dict(self.rejected),
            "bad_frames": stats.bad_frames,
            "incomplete_cycles": stats.incomplete_cycles,
            "corrupt_cycles": stats.corrupt_cycles,
            "send_errors": self.send_errors,
            "recv_errors": self.recv_errors,
            "bad_inputs": self.bad_inputs,
        }

    # --- zenoh callbacks (never block, never sleep) ------------------------------------------
    def _on_lifecycle(self, sample: Any) -> None:
        now = self._clock()
        try:
            msg = LifecycleMsg.from_bytes(sample.payload.to_bytes())
        except MessageError as exc:
            with self._lock:
                self.bad_inputs += 1
            self._rlog(logging.WARNING, "lifecycle", "bad lifecycle message: %s", exc)
            return
        with self._lock:
            previous = self._lifecycle
            if (
                previous is not None
                and previous.state == Lifecycle.FAULT
                and msg.state == Lifecycle.STOPPED
            ):
                self._reset_wanted = True  # the operator's reset reached the gateway
            self._lifecycle, self._lifecycle_rx_s = msg, now

    def _on_io_state(self, sample: Any) -> None:
        now = self._clock()
        try:
            msg = IoState.from_bytes(sample.payload.to_bytes())
        except MessageError as exc:
            with self._lock:
                self.bad_inputs += 1
            self._rlog(logging.WARNING, "io", "bad IoState message: %s", exc)
            return
        with self._lock:
            self._io, self._io_rx_s = msg, now

    def _on_joint_command(self, sample: Any) -> None:
        now = self._clock()
        try:
            cmd = JointCommand.from_bytes(sample.payload.to_bytes())
        except MessageError as exc:
            with self._lock:
                self._reject_locked("bad_message", str(exc))
            return
        with self._lock:
            if self._closing:
                return
            problem = self._check_command(cmd, now)
            pending = self._pending
            frames: list[can.Message] = []
            if problem is None:
                assert pending is not None
                try:
                    frames = self.adapter.command_frames(
                        pending.counter, cmd.q_cmd_rad, cmd.dq_cmd_rad_s, False
                    )
                except FrameError as exc:
                    problem = ("out_of_range", str(exc))
            if problem is not None:
                self._reject_locked(*problem)
                mine = pending is not None and cmd.cycle == (pending.cycle & 0xFFFFFFFF)
                if mine and not pending.answered and problem[0] in ("stale", "out_of_range"):
                    self._send_hold_locked(pending)  # no better answer will come for it
                return
            assert pending is not None
            if self._send_locked(frames):
                pending.answered, pending.answer = True, "command"
                self.forwarded += 1
                self._last_sent_q, self._last_sent_dq = cmd.q_cmd_rad, cmd.dq_cmd_rad_s
                self._last_forwarded_q = cmd.q_cmd_rad
                period = self._feedback.cycle_period_s if self._feedback is not None else 0.0
                self._last_forward = (
                    min(cmd.state_stamp_s, pending.stamp_s),
                    pending.cycle,
                    cmd.q_cmd_rad,
                    cmd.dq_cmd_rad_s,
                    period,
                )
                self._holding = False


# --- process entry points -------------------------------------------------------------------
def run(
    cell_config_path: str | Path,
    bus_endpoint: str | None = None,
    *,
    stop_event: threading.Event | None = None,
) -> None:
    """Run the CAN driver until SIGTERM/SIGINT (or ``stop_event``), then brake and close.

    Raises ConfigError for a bad cell config, and re-raises the error that stopped the loop.
    """
    can_cfg, bus_cfg = load_can_config(cell_config_path)
    bus_cfg = bus_cfg.with_overrides(bus_endpoint)
    driver = CanDriver(can_cfg, bus_cfg)
    stop = stop_event or threading.Event()
    previous: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGTERM, signal.SIGINT):
            previous[signum] = signal.signal(signum, lambda *_: stop.set())
    try:
        driver.start()
        while not stop.wait(0.1):
            if not driver.running:
                break
        if driver.failed is not None:
            raise driver.failed
    finally:
        driver.close()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        log.info("CAN driver stopped")


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the CAN driver's options to ``p`` (used by ``leadthrough can-driver``)."""
    p.description = (
        "Bridge the robot controller's CAN link to the zenoh bus. Publishes the joint state of "
        "every controller cycle; forwards the control process's joint commands only while the "
        "cell is TEACHING (or IDENTIFYING) with the enabling device held; otherwise tells the "
        "controller to hold "
        "still, and to brake whenever the gateway is silent or stopped. Stop it with Ctrl-C or "
        "SIGTERM: it asks the controller to brake before it exits."
    )
    p.add_argument(
        "--config",
        required=True,
        metavar="CELL.toml",
        help="cell configuration file; its [can] section picks the adapter, the CAN interface "
        "(transport) and the limits, its [bus] section the zenoh router",
    )
    p.add_argument(
        "--bus",
        metavar="ENDPOINT",
        default=None,
        help="zenoh router to connect to, e.g. tcp/127.0.0.1:7460 (default: environment "
        "variable LEADTHROUGH_BUS_ENDPOINT, then [bus].endpoint of the cell config)",
    )
    return p


def cli_main(args: argparse.Namespace) -> int:
    """Run from parsed arguments; 0 on a clean stop, 2 for a bad config, 1 for other errors."""
    if not logging.getLogger().handlers:
        logging.basicConfig(
            level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s"
        )
    try:
        run(args.config, args.bus)
    except ConfigError as exc:
        log.error("configuration refused: %s", exc)
        return 2
    except Exception as exc:  # anything else: report it, the controller brakes on its own
        log.error("CAN driver failed: %s: %s", type(exc).__name__, exc)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = configure_parser(argparse.ArgumentParser(prog="python -m drivers.can.driver"))
    return cli_main(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
