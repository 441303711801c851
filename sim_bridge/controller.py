"""The closed vendor controller of the virtual robot, as its manual (drivers/can/PROTOCOL.md)
describes it: state machine, command validation, watchdogs and command interpolation.

It sees only CAN frames and the e-stop chain; it never sees zenoh or the gateway. It speaks
either profile of the protocol, ``[controller].can_profile``: LTC-1 on classic CAN (§2) or
LTC-1F on CAN FD (§10), through the controller-side API both protocol classes share
(``feedback_frames``, ``joint_commands``); :func:`controller_protocol` builds the right one.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field

import can
import numpy as np

from drivers.can.adapter import HostRequest
from drivers.can.ltc_fd import LtcFdProtocol
from drivers.can.ltc_frames import (
    ControllerStatus,
    FaultCode,
    Heartbeat,
    HostRequestFrame,
    JointCommandFrame,
)
from drivers.can.ltc_protocol import LtcProtocol, LtcProtocolBase
from gateway.errors import ConfigError, FrameError
from gateway.messages import ControllerState
from sim_bridge.config import ControllerSpec

log = logging.getLogger(__name__)


def controller_protocol(spec: ControllerSpec, n_joints: int) -> LtcProtocolBase:
    """The protocol ``[controller].can_profile`` names: LtcProtocol ("classic", §2) or
    LtcFdProtocol ("fd", §10), for ``n_joints`` joints."""
    if spec.can_profile == "fd":
        return LtcFdProtocol(n_joints=n_joints)
    return LtcProtocol(n_joints=n_joints)


@dataclass
class ControllerStats:
    command_sets: int = 0  #: complete valid command sets accepted
    hold_sets: int = 0  #: of which carried the hold flag
    missed_cycles: int = 0  #: EXTERNAL cycles without a complete set (total)
    late_frames: int = 0  #: command frames (JOINT_CMD or CYCLE_CMD) not for the current cycle
    bad_frames: int = 0  #: frames that failed to decode (CRC, DLC, range)
    faults: list[str] = field(default_factory=list)


class VirtualController:
    """Vendor logic. Drive it with :meth:`on_frame`, :meth:`begin_cycle` and :meth:`reference`."""

    def __init__(
        self,
        spec: ControllerSpec,
        protocol: LtcProtocolBase,
        lower_rad: np.ndarray,
        upper_rad: np.ndarray,
    ) -> None:
        if protocol.profile != spec.can_profile:
            raise ConfigError(
                f"[controller].can_profile is {spec.can_profile!r} but the controller was given "
                f"a {protocol.profile!r} protocol ({type(protocol).__name__}); build it with "
                "controller_protocol()"
            )
        self.spec = spec
        self.proto = protocol
        self.n = protocol.n_joints
        self.lower_rad = lower_rad
        self.upper_rad = upper_rad
        self.state = ControllerState.BRAKED
        self.fault = FaultCode.NONE
        self.cycle = 0
        self.missed = 0
        self.stats = ControllerStats()
        self.last_heartbeat_s: float | None = None
        self.servo_requested = False
        self.estop = False
        #: the servo last went off by a fault (stop category 0: the power cut, the brakes
        #: bite after their engagement time), not by the host's BRAKE
        self.power_cut = False
        # Command being followed: position at t_ref, velocity used to extrapolate.
        self.q_ref = np.zeros(self.n)
        self.dq_ref = np.zeros(self.n)
        self.t_ref = 0.0
        self.ref_is_hold = True
        # Frames of the set being assembled for the current cycle.
        self._pending: dict[int, JointCommandFrame] = {}
        self.complete_for_cycle: int | None = None  #: cycle whose full set has arrived
        self.complete_hold = True
        self._new_set: tuple[np.ndarray, np.ndarray, bool] | None = None
        self._new_set_in_range = True  #: its positions are within the joint range
        self._lower, self._upper = lower_rad.tolist(), upper_rad.tolist()  # (plain floats)
        #: reference updates on their way to the servo, oldest first, one per cycle: a set
        #: (q, dq, hold), or None to freeze where the extrapolation has brought it
        self._to_servo: deque[tuple[np.ndarray, np.ndarray, bool] | None] = deque()

    # --- inputs -------------------------------------------------------------------------
    def on_frame(self, msg: can.Message, wall_s: float) -> None:
        try:
            frame = self.proto.decode(msg)
        except FrameError as exc:
            self.stats.bad_frames += 1
            log.warning("rejected CAN frame: %s", exc)
            return
        if isinstance(frame, Heartbeat) and frame.node == "HOST":
            self.last_heartbeat_s = wall_s
        elif isinstance(frame, HostRequestFrame):
            self._on_request(frame.request)
        elif commands := self.proto.joint_commands(frame):
            self._on_commands(commands)

    def _on_request(self, request: HostRequest) -> None:
        if request == HostRequest.BRAKE:
            self.servo_requested = False
            if self.state in (ControllerState.HOLD, ControllerState.EXTERNAL):
                log.info("host requested BRAKE in %s: braking", self.state.name)
                self.state = ControllerState.BRAKED
                self.power_cut = False  # the brakes close while the drives still hold
        elif request == HostRequest.SERVO_ON:
            self.servo_requested = True
        elif (
            request == HostRequest.RESET_FAULT
            and self.state == ControllerState.FAULT
            and not self.estop
        ):
            self.state, self.fault = ControllerState.BRAKED, FaultCode.NONE
            self.servo_requested = False

    def _on_commands(self, commands: tuple[JointCommandFrame, ...]) -> None:
        """The joint commands of one frame: one JOINT_CMD_Jk (LTC-1) or a whole CYCLE_CMD
        (LTC-1F). §3 item 3: only the current cycle's count, the latest per joint wins, and
        the set is complete when every joint has one."""
        if commands[0].counter != self.cycle % self.proto.command_counter_modulus:
            self.stats.late_frames += 1
            return
        for frame in commands:
            self._pending[frame.joint] = frame
        if len(self._pending) == self.n:
            frames = [self._pending[j + 1] for j in range(self.n)]
            self._pending.clear()
            q = [f.q_cmd_rad for f in frames]
            hold = any(f.hold for f in frames)
            self._new_set = (np.array(q), np.array([f.dq_cmd_rad_s for f in frames]), hold)
            self._new_set_in_range = all(
                lo <= x <= hi for lo, x, hi in zip(self._lower, q, self._upper, strict=True)
            )  # NaN is not
            self.complete_for_cycle = self.cycle
            self.complete_hold = hold

    # --- cycle --------------------------------------------------------------------------
    def _enter_fault(self, code: FaultCode, why: str) -> None:
        if self.state != ControllerState.FAULT:
            log.warning("controller FAULT %s: %s", code.name, why)
            self.stats.faults.append(f"{code.name}: {why}")
        if self.servo_on:
            self.power_cut = True  # stop category 0: the brakes bite after their engagement
        self.state, self.fault = ControllerState.FAULT, code
        self.servo_requested = False

    def begin_cycle(self, now_s: float, q_rad: np.ndarray, wall_s: float) -> None:
        """Accept what arrived during the last cycle, run the watchdogs, advance the counter.
        The servo follows an accepted set ``[controller].command_delay_cycles`` cycles later.

        ``now_s`` is simulated time (command interpolation); ``wall_s`` is monotonic wall time
        (the host heartbeat is a wall-clock property, also in lock-step runs).
        """
        if self.estop:
            self._enter_fault(FaultCode.ESTOP, "e-stop chain open")
        servo_on = self.state in (ControllerState.HOLD, ControllerState.EXTERNAL)
        hb_age = None if self.last_heartbeat_s is None else wall_s - self.last_heartbeat_s
        host_alive = hb_age is not None and hb_age <= self.spec.host_heartbeat_timeout_s
        if servo_on and not host_alive:
            self._enter_fault(FaultCode.HOST_HEARTBEAT_LOST, f"no host heartbeat for {hb_age} s")
        if (
            self.state == ControllerState.BRAKED
            and self.servo_requested
            and not self.estop
            and host_alive
        ):
            self.state, self.power_cut = ControllerState.HOLD, False
            self._set_ref(q_rad, np.zeros(self.n), now_s, hold=True)
            self._to_servo.clear()
        new_set, self._new_set = self._new_set, None
        update: tuple[np.ndarray, np.ndarray, bool] | None = None
        if self.state in (ControllerState.HOLD, ControllerState.EXTERNAL):
            if new_set is not None:
                q_cmd, dq_cmd, hold = new_set
                if not self._new_set_in_range:
                    self._enter_fault(
                        FaultCode.JOINT_LIMIT, f"position command {q_cmd} outside range"
                    )
                else:
                    self.state = ControllerState.EXTERNAL
                    self.missed = 0
                    self.stats.command_sets += 1
                    self.stats.hold_sets += int(hold)
                    update = (q_cmd, np.zeros(self.n) if hold else dq_cmd, hold)
            elif self.state == ControllerState.EXTERNAL:
                self.missed += 1
                self.stats.missed_cycles += 1
                if self.missed > self.spec.max_missed_cycles:
                    self._enter_fault(
                        FaultCode.CMD_TIMEOUT, f"{self.missed} cycles without commands"
                    )
        if self.state in (ControllerState.HOLD, ControllerState.EXTERNAL):
            self._to_servo.append(update)
            if len(self._to_servo) > self.spec.command_delay_cycles:
                applied = self._to_servo.popleft()
                if applied is None:
                    if self.state == ControllerState.EXTERNAL:
                        # Nothing new: freeze where the extrapolation has brought it.
                        self._set_ref(self.reference(now_s)[0], np.zeros(self.n), now_s, True)
                else:
                    self._set_ref(applied[0], applied[1], now_s, applied[2])
        else:
            self._to_servo.clear()
        if self.state in (ControllerState.HOLD, ControllerState.EXTERNAL):
            err = np.abs(self.reference(now_s)[0] - q_rad)
            if (err > self.spec.max_following_error_rad).any():
                self._enter_fault(FaultCode.FOLLOWING_ERROR, f"following error {err.max():.4f} rad")
        self._pending.clear()
        self.cycle = (self.cycle + 1) & 0xFFFF

    def _set_ref(self, q: np.ndarray, dq: np.ndarray, t: float, hold: bool) -> None:
        self.q_ref, self.dq_ref, self.t_ref, self.ref_is_hold = q.copy(), dq.copy(), t, hold

    @property
    def servo_on(self) -> bool:
        return self.state in (ControllerState.HOLD, ControllerState.EXTERNAL)

    def reference(self, now_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Command followed by the inner loop now: position extrapolated with the velocity."""
        return self.q_ref + self.dq_ref * (now_s - self.t_ref), self.dq_ref

    def status(self) -> ControllerStatus:
        return ControllerStatus(
            cycle_counter=self.cycle,
            state=self.state,
            fault_code=self.fault,
            missed_cycles=min(self.missed, 255),
            estop_active=self.estop,
            servo_power=self.servo_on,
            cycle_period_us=round(self.spec.cycle_period_s * 1e6),
        )
