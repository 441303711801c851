"""The CAN host's per-cycle decisions, free of I/O: decode → decide → encode.

:class:`HostCore` is what the CAN driver process (:mod:`drivers.can.driver`) does each control
cycle, with the sockets taken out, so every decision can be tested cycle by cycle with an
injected clock and profiled alone. Its inputs are received CAN frames, zenoh payloads and the
time; its outputs are the frames to send and the JointState payload to publish. It never
blocks, sleeps, sends or publishes; the driver does, around it, under one lock.

Every cycle the controller sends its joint feedback; the core turns it into a JointState and
answers the cycle exactly once (PROTOCOL.md §3), with either

* ``command``: the control process's JointCommand for that cycle, forwarded only if every
  check passes (lifecycle TEACHING or IDENTIFYING, enabling device held and e-stop chain
  closed, controller servoing, the command fresh, for this very cycle, within the
  following-error and velocity limits);
* ``coast``: when the command is late, the last forwarded command moved on by its own
  velocity (what the controller's interpolation does within a cycle, §5), as long as that
  command is not older than ``deadline_s``; one late answer then costs the operator nothing;
* ``hold``: a hold set (hold=1, zero velocity) at a position latched when holding began — at
  once when forwarding is not allowed, otherwise when the cycle's answer deadline passes;
* ``ramp``: a controlled stop (stop_ramp.py) — the enabling device released, or the lifecycle
  gone from a commanding state to READY or STOPPED, while everything else is in order: the
  last command continues along its path with its velocity falling to zero at ``[can]
  stop_deceleration_rad_s2``, then the ramp's end is held (stop category 2; for STOPPED the
  servo power stays on until the ramp ends, then the brakes: category 1). Faults hold at once.

While the driver holds with the servo on, a standstill monitor watches the measured positions
(stop_ramp.py); a drive that does not hold the arm trips it: the brakes, and the gateway faults.

The answer deadline of a cycle is ``min(deadline_s, answer_by_period_fraction × period)`` after
its JointState stamp: a command set must reach the controller before the next cycle begins or
it is a missed cycle (§3). A command arriving after its cycle was answered is rejected as
``late_cycle``.

Servo power is requested from the gateway's lifecycle (READY, TEACHING or IDENTIFYING, and
fresh: SERVO_ON; anything else, including silence: BRAKE), repeated with every host heartbeat.
The default and :meth:`HostCore.closing_frames` lead to BRAKE.

Every published current is the reported one less the current sensors' zero, measured while the
servo power is off (:mod:`drivers.can.current_zero`); the first SERVO_ON waits until that
measurement is complete.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import can
import numpy as np

from drivers.can.adapter import CanAdapter, CycleFeedback, HostRequest
from drivers.can.bus_errors import BusErrors
from drivers.can.config import CanDriverConfig
from drivers.can.current_zero import CurrentZero
from drivers.can.lost_cycles import HOLD_ANSWER, LostCycles
from drivers.can.plausibility import FeedbackPlausibility
from drivers.can.speed_monitor import Points, SpeedMonitor, datasheet_points
from drivers.can.stop_ramp import StandstillMonitor, StopRamp
from gateway.errors import ConfigError, FrameError, MessageError
from gateway.messages import (
    COMMANDING,
    FLAG_ESTOP,
    FLAG_PREV_COAST,
    FLAG_PREV_HOLD,
    FLAG_SERVO_POWER,
    ControllerState,
    IoState,
    JointCommand,
    JointState,
    Lifecycle,
    LifecycleMsg,
    LifecycleOrder,
    StateWindow,
)

if TYPE_CHECKING:
    from control.robot.description import RobotDescription

#: lifecycle states in which the arm moves at hand-guiding speeds: the speed monitor applies
MONITORED = (Lifecycle.TEACHING, Lifecycle.REPLAYING)

log = logging.getLogger("drivers.can.driver")

#: Why a JointCommand was not forwarded (the keys of the health message's "rejected").
REJECT_REASONS = (
    "stale",  # older than deadline_s
    "blocked_lifecycle",  # lifecycle not TEACHING/IDENTIFYING, or silent
    "blocked_enabling",  # enabling device released, e-stop chain open, or I/O silent
    "blocked_controller",  # controller not servoing (BRAKED/FAULT) or its link is down
    "bad_message",  # undecodable payload, NaN, wrong joint count
    "out_of_range",  # following error, velocity, or a value the protocol cannot carry
    "late_cycle",  # not for the current cycle, or that cycle was already answered
    "blocked_speed",  # the speed monitor tripped (speed_monitor.py) and the lifecycle still runs
    "blocked_bus",  # a CAN bus fault is latched (bus_errors.py: bus-off, a burst of errors)
    "blocked_lost",  # too many lost command cycles (lost_cycles.py), until the cell is stopped
)

#: How a cycle was answered.
COMMAND, COAST, HOLD, RAMP = "command", "coast", "hold", "ramp"
#: A controlled stop continues a forwarded command at most this many cycles old.
RAMP_MAX_AGE_CYCLES = 5

_SERVOING = (ControllerState.HOLD, ControllerState.EXTERNAL)
_BRAKED = (ControllerState.BRAKED, ControllerState.FAULT)

#: note(level, key, message): a rate-limited log (key groups repeats)
Note = Callable[[int, str, str], None]


def _fresh(stamp_s: float, received_s: float, now_s: float, timeout_s: float) -> bool:
    """Both the sender's stamp and our receipt are recent (a future stamp never keeps it fresh)."""
    return (now_s - received_s) < timeout_s and -timeout_s < (now_s - stamp_s) < timeout_s


def _next_tick(previous_s: float, period_s: float, now_s: float) -> float:
    """Next time of a periodic action: on the grid, or one period from now if behind."""
    following = previous_s + period_s
    return following if following > now_s else now_s + period_s


def _log_note(level: int, key: str, message: str) -> None:
    log.log(level, "%s", message)


@dataclass(slots=True)
class Cycle:
    """The newest complete controller cycle, waiting for (or given) its answer."""

    cycle: int  #: widened cycle counter (JointState.cycle)
    counter: int  #: the counter as on the wire
    stamp_s: float  #: JointState.stamp_s: when its last frame arrived [s]
    answer_by_s: float  #: coast or hold if still unanswered at this time [s]
    q_rad: np.ndarray  #: measured positions of the cycle [rad]
    answer: str = ""  #: COMMAND, COAST or HOLD once answered

    @property
    def answered(self) -> bool:
        return bool(self.answer)


class FrameResult(NamedTuple):
    """What one received CAN frame asks of the driver."""

    state: bytes | None  #: a JointState payload to publish (the frame completed a cycle)
    frames: list[can.Message]  #: frames to send now (a blocked cycle is held at once)
    window: bytes | None = None  #: a StateWindow payload to publish (the window is complete)


class StateWindowBuilder:
    """Folds each cycle's JointState into the window the readers off the cycle get
    (:class:`~gateway.messages.StateWindow`). A window closes at the first state at or after
    its due time, due times ``period_s`` apart (one window per ``period_s`` on average), or at
    once when ``key`` (the controller's state and its e-stop and servo-power flags) changes:
    the gateway sees an e-stop without waiting for the window. The first state closes a window
    of its own."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._states = 0
        self._speed = 0.0
        self._lo = np.zeros(0)
        self._hi = np.zeros(0)
        self._key: tuple[int, int] | None = None
        self._due_s = -np.inf

    def add(
        self, q: np.ndarray, dq: np.ndarray, key: tuple[int, int], state: bytes, now: float
    ) -> bytes | None:
        """Take one cycle's state; returns the window's bytes when it closes."""
        speed = float(np.abs(dq).max())
        if self._states == 0 or self._lo.shape != q.shape:
            self._lo, self._hi, self._speed, self._states = q.copy(), q.copy(), speed, 0
        else:
            np.minimum(self._lo, q, out=self._lo)
            np.maximum(self._hi, q, out=self._hi)
            self._speed = max(self._speed, speed)
        self._states += 1
        if now < self._due_s and key == self._key:
            return None
        window = StateWindow(self._states, self._speed, self._lo, self._hi, state).to_bytes()
        # on the period's own grid, so windows come every period_s on average whatever the
        # cycle; a gap (or the first window) starts the grid again
        due = self._due_s + self.period_s
        self._key, self._due_s, self._states = key, due if due > now else now + self.period_s, 0
        return window


class CommandResult(NamedTuple):
    """What one JointCommand asks of the driver."""

    frames: list[can.Message]  #: the answer to send (forwarded command or hold), maybe none
    answer: str  #: COMMAND, HOLD, or "" (rejected without an answer)
    command: JointCommand | None  #: the decoded command (None if undecodable)


def _datasheet(n: int) -> RobotDescription:
    """The robot description (the datasheet's) for ``n`` joints."""
    from control.robot.description import load_description

    desc = load_description()
    if desc.n_dof != n:
        raise ConfigError(f"[can].joints = {n}, but the robot description has {desc.n_dof}")
    return desc


class HostCore:
    """The CAN host's decisions. Not thread-safe: the driver calls it under one lock.

    ``note`` receives (level, key, message) for conditions worth a log line; the driver passes
    a rate-limited logger (repeats share a key).
    """

    def __init__(
        self,
        config: CanDriverConfig,
        adapter: CanAdapter,
        note: Note | None = None,
        health_period_s: float = 0.1,
        stored_zero: tuple[np.ndarray, int, np.ndarray] | None = None,
        speed_points: Points | None = None,
        joint_limits_rad: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        self.config = config
        self.adapter = adapter
        self._note = note or _log_note
        self.health_period_s = health_period_s
        n = config.joints
        self._max_fe = np.array(config.max_following_error_rad, dtype=float)
        self._max_dq = np.array(config.max_velocity_rad_s, dtype=float)
        self._zeros = np.zeros(n)
        self._zeros_list = [0.0] * n
        #: the joint range a forwarded command stays in [rad]: the description's limits (the
        #: datasheet's, or ``joint_limits_rad``) less ``joint_limit_margin_rad``
        monitored = config.hand_guiding_max_speed_m_s > 0
        desc = None
        if joint_limits_rad is None or (monitored and speed_points is None):
            desc = _datasheet(n)  # loaded once for the limits and the speed monitor
        if joint_limits_rad is None:
            assert desc is not None
            joint_limits_rad = (np.array(desc.lower_rad), np.array(desc.upper_rad))
        lower, upper = joint_limits_rad
        self._lower = np.asarray(lower, dtype=float) + config.joint_limit_margin_rad
        self._upper = np.asarray(upper, dtype=float) - config.joint_limit_margin_rad

        # inputs from zenoh
        self._lifecycle: LifecycleMsg | None = None
        self.lifecycle_order = LifecycleOrder()
        self._lifecycle_rx_s = -np.inf
        self._io: IoState | None = None
        self._io_rx_s = -np.inf
        self._reset_wanted = False
        # controller
        #: the current sensors' zero, measured with the servo power off
        self.current_zero = CurrentZero(
            n, config.current_zero_cycles, config.current_zero_settle_cycles, stored_zero
        )
        self.feedback: CycleFeedback | None = None
        self._last_cycle_rx_s = -np.inf
        self._last_counter: int | None = None
        self._cycle = 0
        self.pending: Cycle | None = None
        # what we asked for and sent
        self.request_sent: HostRequest | None = None
        self._next_heartbeat_s = -np.inf
        #: when the next host-clocked cycle starts (the adapter's clock_period_s; inf: never)
        self._next_clock_s = -np.inf if adapter.clock_period_s is not None else np.inf
        self._next_health_s = -np.inf
        self._last_sent_q: list[float] | None = None
        self._last_sent_dq: list[float] | None = None
        self._last_forwarded_q: np.ndarray | None = None  #: since servo-on
        #: (state stamp, cycle, q_cmd, dq_cmd, period) of the last forwarded command: coasting
        self._last_forward: tuple[float, int, np.ndarray, np.ndarray, float] | None = None
        self._hold_q: np.ndarray | None = None
        self._holding = False
        #: the controlled stop under way (stop_ramp.py), None when there is none
        self._ramp: StopRamp | None = None
        self._stop_decel = np.array(config.stop_deceleration_rad_s2, dtype=float)
        #: error frames and the bus fault they latch (bus_errors.py)
        self.bus = BusErrors(config.bus_error_limit, config.bus_error_window_s)
        #: lost command cycles and the policy's latched trip (lost_cycles.py)
        self.lost = LostCycles(
            config.lost_cycles_max_consecutive,
            config.lost_cycles_max_per_window,
            config.lost_cycles_window_s,
        )
        self.standstill = StandstillMonitor(
            config.standstill_band_rad, config.standstill_settle_s, config.standstill_confirm_cycles
        )
        #: hand guiding's speed monitor (speed_monitor.py); ``speed_points`` the tool point and
        #: flange of q (default: the datasheet's kinematics)
        self.speed: SpeedMonitor | None = None
        if monitored:
            self.speed = SpeedMonitor(
                speed_points or datasheet_points(desc), config.hand_guiding_max_speed_m_s
            )
        #: measured positions that jump further than the arm can move (plausibility.py)
        self.plausibility = FeedbackPlausibility(config.feedback_max_joint_speed_rad_s)
        self.window = StateWindowBuilder(config.state_window_s)
        # counters (monotonic, reported in health)
        self.rejected = dict.fromkeys(REJECT_REASONS, 0)
        self.cycles = 0
        self.forwarded = 0
        self.coasted = 0
        self.held = 0
        self.ramped = 0
        self.unanswered = 0
        self.bad_inputs = 0

    # --- inputs from zenoh ----------------------------------------------------------------
    def on_lifecycle(self, payload: bytes, now: float) -> None:
        try:
            msg = LifecycleMsg.from_bytes(payload)
        except MessageError as exc:
            self.bad_inputs += 1
            self._note(logging.WARNING, "lifecycle", f"bad lifecycle message: {exc}")
            return
        previous = self._lifecycle
        dropped = self.lifecycle_order.admit(msg)
        if dropped is not None:
            self._note(
                logging.WARNING,
                f"lifecycle_{dropped}",
                f"lifecycle message dropped ({dropped}): seq {msg.seq} {msg.state.name} after "
                f"seq {previous.seq if previous else '-'} "
                f"{previous.state.name if previous else '-'}",
            )
            return
        if (
            previous is not None
            and previous.state == Lifecycle.FAULT
            and msg.state == Lifecycle.STOPPED
        ):
            self._reset_wanted = True  # the operator's reset reached the gateway
        self._lifecycle, self._lifecycle_rx_s = msg, now

    def on_io(self, payload: bytes, now: float) -> None:
        try:
            msg = IoState.from_bytes(payload)
        except MessageError as exc:
            self.bad_inputs += 1
            self._note(logging.WARNING, "io", f"bad IoState message: {exc}")
            return
        self._io, self._io_rx_s = msg, now

    def on_command(self, payload: bytes, now: float) -> CommandResult:
        """Decide on one JointCommand: forward it, hold the cycle it was for, or neither."""
        try:
            cmd = JointCommand.from_bytes(payload)
        except MessageError as exc:
            self._reject("bad_message", str(exc))
            return CommandResult([], "", None)
        problem = self._check_command(cmd, now)
        pending = self.pending
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
            self._reject(*problem)
            mine = pending is not None and cmd.cycle == (pending.cycle & 0xFFFFFFFF)
            if mine and not pending.answered and problem[0] in ("stale", "out_of_range"):
                frames = self._hold(pending, now)  # no better answer comes
                self._record_lost(now)
                return CommandResult(frames, pending.answer or HOLD, cmd)
            return CommandResult([], "", cmd)
        assert pending is not None
        pending.answer = COMMAND
        self.forwarded += 1
        self.lost.record(False, now)
        self._last_sent_q, self._last_sent_dq = cmd.q_cmd_rad.tolist(), cmd.dq_cmd_rad_s.tolist()
        self._last_forwarded_q = cmd.q_cmd_rad
        period = self.feedback.cycle_period_s if self.feedback is not None else 0.0
        self._last_forward = (
            min(cmd.state_stamp_s, pending.stamp_s),
            pending.cycle,
            cmd.q_cmd_rad,
            cmd.dq_cmd_rad_s,
            period,
        )
        self._holding, self._ramp = False, None
        return CommandResult(frames, COMMAND, cmd)

    # --- input from CAN -------------------------------------------------------------------
    def on_frame(self, msg: can.Message, now: float) -> FrameResult:
        """Take one received frame; a frame that completes a cycle yields its JointState."""
        stats = self.adapter.stats
        if msg.is_error_frame:
            fault = self.bus.on_error_frame(msg, now)
            if fault is not None:
                self._note(logging.ERROR, "bus", f"CAN bus fault: {fault}; holding, brakes")
        dropped = stats.bad_frames + stats.incomplete_cycles + stats.corrupt_cycles
        feedback = self.adapter.feed(msg)
        if feedback is None:
            if stats.bad_frames + stats.incomplete_cycles + stats.corrupt_cycles != dropped:
                self._note(logging.WARNING, "frame", f"CAN: {stats.last_error}")
            return FrameResult(None, [])
        return self._on_cycle(feedback, now)

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

    def _on_cycle(self, fb: CycleFeedback, now: float) -> FrameResult:
        cycle = self._widen(fb.counter)
        if cycle is None:
            self._note(logging.WARNING, "dup", f"controller repeated cycle {fb.counter}")
            return FrameResult(None, [])
        implausible = self.plausibility.check(cycle, fb.q_rad, fb.cycle_period_s)
        if implausible is not None:
            self._note(logging.ERROR, "implausible", f"CAN: cycle dropped, {implausible}")
            return FrameResult(None, [])
        previous = self.pending
        if previous is not None and not previous.answered:
            self.unanswered += 1
            self._note(
                logging.WARNING,
                "unanswered",
                f"cycle {previous.cycle} got no answer before cycle {cycle} arrived",
            )
        self.cycles += 1
        self.bus.on_cycle()
        self.feedback, self._last_cycle_rx_s = fb, now
        self.current_zero.update(fb.current_a, fb.servo_power)
        if fb.controller_state in _BRAKED:
            # On its brakes the arm is where it is: the next hold starts from there.
            self._holding, self._last_forwarded_q = False, None
            self._last_forward, self._ramp = None, None
        budget_s = self.config.deadline_s
        if fb.cycle_period_s > 0:
            budget_s = min(budget_s, self.config.answer_by_period_fraction * fb.cycle_period_s)
        pending = Cycle(cycle, fb.counter, now, now + budget_s, fb.q_rad)
        self.pending = pending
        self._monitor_speed(fb, cycle, now)
        q_list = fb.q_rad.tolist()
        q_cmd = q_list if self._last_sent_q is None else self._last_sent_q
        dq_cmd = self._zeros_list if self._last_sent_dq is None else self._last_sent_dq
        flags = int(fb.estop_active) * FLAG_ESTOP | int(fb.servo_power) * FLAG_SERVO_POWER
        if previous is not None and previous.cycle == cycle - 1:
            if previous.answer == COAST:
                flags |= FLAG_PREV_COAST
            elif previous.answer != COMMAND:  # a hold, or none (the controller froze)
                flags |= FLAG_PREV_HOLD
        state = JointState.pack(
            cycle,
            now,
            int(fb.controller_state),
            flags,
            fb.cycle_period_s,
            q_list,
            fb.dq_rad_s.tolist(),
            self.current_zero.correct(fb.current_a).tolist(),
            q_cmd,
            dq_cmd,
        )
        frames: list[can.Message] = []
        if self.blocked(now) is not None:
            frames = self._hold(pending, now)
            self.lost.record(False, now)
        if self._wants_servo(now):
            self._watch_standstill(fb, cycle, now)
        else:
            self._clear_latched(now)
        key = (int(fb.controller_state), flags & (FLAG_ESTOP | FLAG_SERVO_POWER))
        window = self.window.add(fb.q_rad, fb.dq_rad_s, key, state, now)
        return FrameResult(state, frames, window)

    def _monitor_speed(self, fb: CycleFeedback, cycle: int, now: float) -> None:
        """Hand guiding's speed from this cycle's measured positions, while the lifecycle
        teaches or replays and the controller servos; anything else resets the monitor (and
        clears a trip: the gateway has left the state the trip stopped)."""
        monitor = self.speed
        if monitor is None:
            return
        lc = self._lifecycle
        applies = (
            lc is not None
            and lc.state in MONITORED
            and _fresh(lc.stamp_s, self._lifecycle_rx_s, now, self.config.lifecycle_timeout_s)
        )
        if not applies:
            if monitor.trip is not None:
                log.info("speed monitor cleared: lifecycle %s", None if lc is None else lc.state)
            monitor.reset()
            return
        if fb.controller_state not in _SERVOING or fb.cycle_period_s <= 0:
            monitor.gap()
            return
        tripped = monitor.trip is not None
        trip = monitor.update(cycle, fb.q_rad, fb.cycle_period_s)
        if trip is not None and not tripped:
            self._note(logging.ERROR, "speed", f"speed monitor: {trip.message()}; holding")

    # --- time -----------------------------------------------------------------------------
    def on_tick(self, now: float) -> list[can.Message]:
        """Deadline answers, servo requests and heartbeats due at ``now``."""
        frames: list[can.Message] = []
        pending = self.pending
        if pending is not None and not pending.answered and now >= pending.answer_by_s:
            allowed = self.blocked(now) is None
            frames += self._coast(pending, now) or self._hold(pending, now)
            if allowed:
                self._record_lost(now)
        desired = self.desired_request(now)
        heartbeat_due = now >= self._next_heartbeat_s
        if heartbeat_due:
            frames.append(self.adapter.heartbeat_frame())
            self._next_heartbeat_s = _next_tick(
                self._next_heartbeat_s, self.config.heartbeat_period_s, now
            )
        if desired != self.request_sent or heartbeat_due:
            if desired == HostRequest.SERVO_ON and self.request_sent != desired:
                # A new servo-on period: nothing forwarded in it yet.
                self._holding, self._last_forwarded_q = False, None
                self._last_forward = None
            if desired != self.request_sent:
                log.info("requesting %s from the controller", desired.name)
            frames += self.adapter.request_frames(desired)
            self.request_sent = desired
        if self._reset_wanted:
            self._reset_wanted = False
            fb = self.feedback
            if fb is not None and fb.controller_state == ControllerState.FAULT:
                log.info("operator reset: asking the controller to leave FAULT (%s)", fb.fault)
                frames += self.adapter.request_frames(HostRequest.RESET_FAULT)
                self.request_sent = HostRequest.RESET_FAULT  # BRAKE follows next pass
        period = self.adapter.clock_period_s
        if period is not None and now >= self._next_clock_s:
            # Last: the answers and requests above take effect at this cycle's start.
            frames += self.adapter.clock_frames()
            self._next_clock_s = _next_tick(self._next_clock_s, period, now)
        return frames

    def next_tick_s(self) -> float:
        """The earliest time :meth:`on_tick` has something due (an answer or a heartbeat) [s].

        A change of request (a lifecycle message, a reset) arrives through a callback; the
        driver also wakes for those at least every few milliseconds.
        """
        due = min(self._next_heartbeat_s, self._next_clock_s)
        pending = self.pending
        if pending is not None and not pending.answered:
            due = min(due, pending.answer_by_s)
        if self._reset_wanted:
            return -np.inf
        return due

    def health_due(self, now: float) -> bool:
        """True once per health period (and then schedules the next)."""
        if now < self._next_health_s:
            return False
        self._next_health_s = _next_tick(self._next_health_s, self.health_period_s, now)
        return True

    def closing_frames(self) -> list[can.Message]:
        """BRAKE, then a hold for the cycle still waiting for its answer (on exit); on a
        host-clocked link, then the cycle start that makes them take effect."""
        frames = list(self.adapter.request_frames(HostRequest.BRAKE))
        self.request_sent = HostRequest.BRAKE
        if self.pending is not None:
            try:
                frames += self._hold_frames(self.pending)
            except FrameError as exc:
                self._note(logging.ERROR, "hold", f"cannot build a hold set on exit: {exc}")
        if self.adapter.clock_period_s is not None:
            # A host-clocked cycle's frames take effect at its next SYNC: without one the
            # BRAKE would wait for the drives' heartbeat watch (120 ms and 13-22 mm at
            # 120-220 mm/s on the virtual CiA 402 drives, 2026-11-28).
            frames += self.adapter.clock_frames()
        return frames

    # --- decisions ------------------------------------------------------------------------
    def desired_request(self, now: float) -> HostRequest:
        lc = self._lifecycle
        if lc is None or not _fresh(
            lc.stamp_s, self._lifecycle_rx_s, now, self.config.lifecycle_timeout_s
        ):
            return HostRequest.BRAKE
        if self.standstill.trip is not None:
            return HostRequest.BRAKE  # the drives do not hold the arm: nothing else is left
        if self.speed is not None and self.speed.trip is not None:
            # A hand that outran the limit fights a rigid hold until the controller faults on
            # its following error and cuts the power: the arm is then free for the brakes'
            # engagement time. The brakes at once instead.
            return HostRequest.BRAKE
        if self.bus.fault is not None:
            return HostRequest.BRAKE  # stopped until the operator re-arms (bus_errors.py)
        if lc.state == Lifecycle.STOPPED and (self._ramp is not None or self._ramp_due(now)):
            return HostRequest.SERVO_ON  # stop category 1: the brakes once the ramp has ended
        if lc.state in (Lifecycle.READY, *COMMANDING):
            if not self.current_zero.ready:
                zero = self.current_zero
                self._note(
                    logging.INFO,
                    "zero",
                    f"servo on waits for the current sensors' zero ({zero.samples} of "
                    f"{zero.window} cycles with the servo power off)",
                )
                return HostRequest.BRAKE
            return HostRequest.SERVO_ON
        return HostRequest.BRAKE

    def link_ok(self, now: float) -> bool:
        return (now - self._last_cycle_rx_s) < self.config.controller_timeout_s

    def blocked(self, now: float) -> str | None:
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
        fb = self.feedback
        if fb is None or fb.controller_state not in _SERVOING or not self.link_ok(now):
            return "blocked_controller"
        if self.speed is not None and self.speed.trip is not None:
            return "blocked_speed"
        if self.bus.fault is not None:
            return "blocked_bus"
        if self.lost.trip is not None:
            return "blocked_lost"
        return None

    def _record_lost(self, now: float) -> None:
        """The pending cycle was lost (lost_cycles.py): count it, and say so if it trips."""
        trip = self.lost.record(True, now)
        if trip is not None:
            self._note(
                logging.ERROR, "lost", f"lost command cycles: {trip.message()}; stopping the arm"
            )

    def _check_command(self, cmd: JointCommand, now: float) -> tuple[str, str] | None:
        """(reason, detail) if ``cmd`` must not be forwarded, else None."""
        n = self.config.joints
        if cmd.n != n:
            return "bad_message", f"{cmd.n} joints, expected {n}"
        blocked = self.blocked(now)
        if blocked is not None:
            return blocked, f"cycle {cmd.cycle}"
        pending = self.pending
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
        outside = np.maximum(self._lower - cmd.q_cmd_rad, cmd.q_cmd_rad - self._upper)
        if np.any(outside > 0.0):
            k = int(np.argmax(outside))
            return "out_of_range", (
                f"joint {k + 1}: q_cmd = {cmd.q_cmd_rad[k]:.4f} rad outside the driver's limits "
                f"[{self._lower[k]:.4f}, {self._upper[k]:.4f}] rad"
            )
        speed = np.abs(cmd.dq_cmd_rad_s)
        if np.any(speed > self._max_dq):
            k = int(np.argmax(speed - self._max_dq))
            return "out_of_range", (
                f"joint {k + 1}: |dq_cmd| = {speed[k]:.4f} rad/s > {self._max_dq[k]:g} rad/s"
            )
        return None

    def _hold_frames(self, pending: Cycle) -> list[can.Message]:
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

    def _controlled_stop(self, now: float) -> bool:
        """Forwarding is blocked by an ordinary stop, the drives to stay powered through it:
        the enabling device released, or the lifecycle gone to READY or STOPPED, with the
        lifecycle and I/O fresh, the e-stop chain closed, the controller servoing and no
        monitor tripped; or the lost-cycle rule tripped (lost_cycles.py: only the command
        source failed). Anything else is a fault, held at once."""
        lc, io, fb = self._lifecycle, self._io, self.feedback
        cfg = self.config
        if lc is None or io is None or fb is None:
            return False
        if not (
            _fresh(lc.stamp_s, self._lifecycle_rx_s, now, cfg.lifecycle_timeout_s)
            and _fresh(io.stamp_s, self._io_rx_s, now, cfg.io_timeout_s)
            and io.estop_ok
            and fb.controller_state in _SERVOING
            and self.link_ok(now)
            and (self.speed is None or self.speed.trip is None)
            and self.standstill.trip is None
            and self.bus.fault is None
        ):
            return False
        return lc.state in (Lifecycle.READY, Lifecycle.STOPPED) or (
            lc.state in COMMANDING and (not io.enabling or self.lost.trip is not None)
        )

    def _ramp_due(self, now: float) -> bool:
        """A controlled stop is about to begin: the arm was commanded moving a moment ago and
        the stop is an ordinary one, so the next cycle starts a ramp (:meth:`_ramp_for`). The
        servo request is decided between cycles too: without this, the operator's stop
        arriving between two cycles asked for the brakes before the ramp could begin (the
        fault campaign's ``operator_stop``: 135 mm/s to rest in 32 ms, not a ramp)."""
        last, pending = self._last_forward, self.pending
        if self._holding or last is None or pending is None or not np.any(last[3]):
            return False
        age = pending.cycle + 1 - last[1]  # at the cycle the ramp would begin
        return age <= RAMP_MAX_AGE_CYCLES and self._controlled_stop(now)

    def _ramp_for(self, pending: Cycle, now: float) -> StopRamp | None:
        """The controlled stop ``pending`` belongs to: the one under way, or a new one from
        the last forwarded command when a controlled stop begins while the arm was commanded;
        None (and a ramp under way ends where it got to) when the cycle is to be held."""
        ramp = self._ramp
        if ramp is not None:
            if self._controlled_stop(now):
                return ramp
            q, _, _ = ramp.at(pending.cycle)  # a fault during the ramp: hold where it is
            self._ramp, self._hold_q, self._holding = None, q, True
            return None
        last = self._last_forward
        if self._holding or last is None or not self._controlled_stop(now):
            return None
        _stamp, cycle, q, dq, period = last
        age = pending.cycle - cycle
        if period <= 0 or not 0 <= age <= RAMP_MAX_AGE_CYCLES or not np.any(dq):
            return None
        q_now = q + dq * age * period  # where the last command (or its coasting) has got to
        self._ramp = StopRamp.start(pending.cycle, q_now, dq, self._stop_decel, period)
        self._note(
            logging.INFO,
            "ramp",
            f"controlled stop: ramping to standstill in {self._ramp.duration_s * 1e3:.0f} ms",
        )
        return self._ramp

    def _hold(self, pending: Cycle, now: float) -> list[can.Message]:
        """Answer ``pending`` with the controlled stop's ramp while one runs, else with a hold
        set (none if the position cannot be encoded)."""
        ramp = self._ramp_for(pending, now)
        if ramp is not None:
            q, dq, done = ramp.at(pending.cycle)
            if not done:
                try:
                    frames = self.adapter.command_frames(pending.counter, q, dq, False)
                except FrameError as exc:
                    self._note(logging.ERROR, "ramp", f"cannot send the ramp: {exc}; holding")
                else:
                    pending.answer = RAMP
                    self.ramped += 1
                    self._last_sent_q, self._last_sent_dq = q.tolist(), dq.tolist()
                    return frames
            self._ramp, self._hold_q, self._holding = None, q, True  # hold where it ended
        try:
            frames = self._hold_frames(pending)
        except FrameError as exc:  # measured q the protocol cannot carry: nothing to hold
            self._note(logging.ERROR, "hold", f"cannot build a hold set: {exc}")
            return []
        pending.answer = HOLD
        self.held += 1
        assert self._hold_q is not None
        self._last_sent_q, self._last_sent_dq = self._hold_q.tolist(), self._zeros_list
        return frames

    def _coast(self, pending: Cycle, now: float) -> list[can.Message]:
        """Answer a cycle whose command is late with the last forwarded command, moved on by
        its own velocity, as long as that command answered one of the ``coast_max_cycles``
        cycles before this one (and, against a controller whose cycles stalled, is at most
        ``deadline_s`` plus one period more than that many old), and moved on stays within the
        following error and limits a forwarded command must meet; [] if coasting is not
        allowed. A hold after it keeps the coasted position: the controller was sent there.

        The bound counts the periods the coast spans: the command of the cycle before is one
        period plus the answer deadline old when it coasts, 12 ms at LTC-1's 8 ms, so a bound
        of ``deadline_s`` (10 ms) alone let nothing coast at that rate and every late command
        became a hold, a dead stop of an arm the hand was moving (0.2 rad/s to 0 within one
        cycle on J2, 54 A, in the stack's release test, 2026-11-29). The age bound stays: a
        controller whose cycles stalled gets a hold, not a command extrapolated over the
        stall."""
        last = self._last_forward
        max_cycles = self.config.coast_max_cycles
        if (
            self.config.lost_cycle_answer == HOLD_ANSWER
            or last is None
            or self._holding
            or pending.cycle - last[1] > max_cycles
            or now - last[0] > self.config.deadline_s + (max_cycles + 1) * last[4]
        ):
            return []
        _stamp, cycle, q, dq, period = last
        q_coast = q + dq * (pending.cycle - cycle) * period
        # what a forwarded command must meet: near the arm's measured position, in the limits
        if np.any(np.abs(q_coast - pending.q_rad) > self._max_fe) or np.any(
            (q_coast < self._lower) | (q_coast > self._upper)
        ):
            return []
        try:
            frames = self.adapter.command_frames(pending.counter, q_coast, dq, False)
        except FrameError:
            return []
        pending.answer = COAST
        self.coasted += 1
        self._last_sent_q, self._last_sent_dq = q_coast.tolist(), dq.tolist()
        self._last_forwarded_q = q_coast  # a hold that follows does not pull the arm back
        return frames

    def _wants_servo(self, now: float) -> bool:
        """The gateway's lifecycle, fresh, is one that keeps the drives powered."""
        lc = self._lifecycle
        return (
            lc is not None
            and lc.state in (Lifecycle.READY, *COMMANDING)
            and _fresh(lc.stamp_s, self._lifecycle_rx_s, now, self.config.lifecycle_timeout_s)
        )

    def _clear_latched(self, now: float) -> None:
        """The cell is stopped (STOPPED, FAULT, or a silent gateway): the standstill trip
        clears, and a bus fault once the bus has worked again (bus_errors.py); a re-arm is
        still the operator's."""
        if self.bus.fault is not None and self.bus.clear(now):
            log.info("CAN bus fault cleared: the bus works again and the cell is stopped")
        lc = self._lifecycle
        for name, latch in (("standstill monitor", self.standstill), ("lost cycles", self.lost)):
            if latch.trip is not None:
                log.info("%s cleared: lifecycle %s", name, None if lc is None else lc.state)
            latch.reset()

    def _watch_standstill(self, fb: CycleFeedback, cycle: int, now: float) -> None:
        """Monitored standstill (stop_ramp.py) while the driver holds with the servo on and
        the lifecycle wants the servo."""
        monitor = self.standstill
        if not (self._holding and self._hold_q is not None and fb.controller_state in _SERVOING):
            monitor.idle()
            return
        monitor.watch(self._hold_q, now)
        tripped = monitor.trip is not None
        trip = monitor.update(fb.q_rad, cycle, now)
        if trip is not None and not tripped:
            self._note(logging.ERROR, "standstill", f"standstill monitor: {trip.message()}; brakes")

    def _reject(self, reason: str, detail: str) -> None:
        self.rejected[reason] += 1
        level = logging.INFO if reason.startswith("blocked_") else logging.WARNING
        self._note(level, reason, f"JointCommand not forwarded ({reason}): {detail}")

    def _zero_health(self) -> dict[str, Any]:
        """The current zero's part of the health (current_zero.py), and a warning when the
        fresh zero has drifted from the commissioning's."""
        zero = self.current_zero
        drift, noise = zero.drift_a, zero.noise_a()
        if zero.drift_significant(noise):
            assert drift is not None
            self._note(
                logging.WARNING,
                "zero-drift",
                "the current sensors' zero measured now differs from the commissioning's by "
                f"{np.round(drift, 4).tolist()} A, more than noise explains: commission again "
                "(`leadthrough identify`)",
            )
        return {
            "current_zero_a": [round(float(v), 4) for v in zero.offset_a],
            "current_zero_source": zero.source,
            "current_zero_samples": zero.samples,
            "current_zero_ready": zero.ready,
            "current_zero_measured_a": [round(float(v), 4) for v in zero.measured_a],
            "current_zero_noise_a": [round(float(v), 5) for v in noise],
            "current_zero_drift_a": None if drift is None else [round(float(v), 4) for v in drift],
        }

    def _speed_health(self) -> dict[str, Any]:
        monitor = self.speed
        if monitor is None:
            return {"speed_trip": None, "speed_peak_m_s": None}
        trip = monitor.trip
        return {
            "speed_trip": None if trip is None else trip.message(),
            "speed_peak_m_s": round(monitor.peak_m_s, 4),
        }

    def health(self, now: float) -> dict[str, Any]:
        fb, stats = self.feedback, self.adapter.stats
        still = self.standstill.trip
        return {
            "controller_state": None if fb is None else fb.controller_state.name,
            "controller_fault": None if fb is None else fb.fault,
            "link_ok": self.link_ok(now),
            "servo_request": None if self.request_sent is None else self.request_sent.name,
            "cycles": self.cycles,
            "forwarded": self.forwarded,
            "held": self.held,
            "ramped": self.ramped,
            "standstill_trip": None if still is None else still.message(),
            "lost_cycles": self.lost.lost,
            "lost_cycles_trip": None if self.lost.trip is None else self.lost.trip.message(),
            "coasted": self.coasted,
            "unanswered": self.unanswered,
            "rejected": dict(self.rejected),
            "bad_frames": stats.bad_frames,
            "implausible_cycles": self.plausibility.dropped,
            "incomplete_cycles": stats.incomplete_cycles,
            "corrupt_cycles": stats.corrupt_cycles,
            "bad_inputs": self.bad_inputs,
            "lifecycle_dropped": dict(self.lifecycle_order.dropped),
            **self._speed_health(),
            **self.bus.health(),
            **self._zero_health(),
        }
