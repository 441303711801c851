"""The virtual cell's joint drives as CANopen CiA 402 servo drives: one node per joint.

What a drive vendor ships, written from the standards (CiA 301 communication, CiA 402 drive
profile) and the drive's EDS (``deploy/cia402/leadthrough_drive.eds``), not from the product:
nothing here imports the product's CiA 402 host code. ``canopen``'s :class:`~canopen.LocalNode`
holds each drive's object dictionary and serves SDO (:mod:`sim_bridge.cia402_dictionary`);
NMT, SYNC, PDOs, heartbeats, EMCY and the CiA 402 state machine are done here, because
canopen 2.4.1's local node neither transmits TPDOs on SYNC nor stores received RPDOs in its
dictionary, and its NMT slave and heartbeat producer run timer threads this single-threaded
cell loop cannot have. The protocol's facts, the state machine's table and the wire (NMT, SDO,
SYNC, PDOs, heartbeats, EMCY, per COB-ID) are :mod:`sim_bridge.cia402_profile`.

Units: the drive's own, per its parameters (:mod:`sim_bridge.cia402_parameters`). The drives
of every joint are :mod:`sim_bridge.cia402_drive_set`.

The motion (CiA 402's cyclic synchronous modes 8 and 9): the inner PI velocity loop of
eq. (19) is the plant's; this drive gives it a reference (q_ref, dq_ref) at t_ref that it
extrapolates, q_ref + dq_ref (t − t_ref), like the LTC controller. CSP (8): at each SYNC
q_ref = target position 0x607A, dq_ref = velocity offset 0x60B1; a SYNC without a new target
freezes the reference where it has come (dq_ref = 0). CSV (9): dq_ref = target velocity
0x60FF, q_ref integrates it. The reference takes effect at the first servo cycle after the
SYNC that latched it (:meth:`Cia402Drive.step`).
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable
from pathlib import Path

import can
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError

from sim_bridge import cia402_profile as profile
from sim_bridge.cia402_dictionary import EDS_PATH, DriveDictionary, PdoConfig
from sim_bridge.cia402_heartbeat import Heartbeats
from sim_bridge.cia402_parameters import AxisParameters, DriveLimits
from sim_bridge.cia402_profile import (
    COMMUNICATION_ERRORS,
    EMCY_BASE,
    ERROR_REGISTER_COMMUNICATION,
    ERROR_REGISTER_GENERIC,
    ERROR_REGISTER_PROFILE,
    HEARTBEAT_BASE,
    POWERED_STATES,
    QUICK_STOP_TO_SWITCH_ON_DISABLED,
    SDO_RX_BASE,
    SUPPORTED_QUICK_STOP_OPTIONS,
    SYNC_COB_ID_MASK,
    SYNC_GENERATES,
    TRANSITIONS,
    AbortConnectionOption,
    Command,
    DriveState,
    ErrorCode,
    Mode,
    NmtCommand,
    NmtState,
    SdoAbort,
    next_state,
    statusword,
)

log = logging.getLogger(__name__)
#: a host that moved a drive's setpoint within this many SYNCs commands the arm (the truth
#: log's "teaching"); one that repeats the same target holds it
MOVED_WITHIN_SYNCS = 1


# --- one drive ------------------------------------------------------------------------------
class Cia402Drive:
    """One joint's drive. :meth:`boot` it (power on), feed it frames (:meth:`on_nmt`,
    :meth:`on_frame`), :meth:`step` it once per servo cycle with the joint's position, give it
    the joint's measurements (:meth:`sample`) and take the reference the plant's inner loop
    follows (:meth:`reference`). ``send`` puts a frame on the segment.

    Clocks: ``wall_s`` is monotonic wall time [s] (the host heartbeat, as on a real drive);
    ``now_s`` simulated time [s] (the reference, the sync watchdog); ``stamp_s`` a received
    frame's arrival stamp (the latency figure).
    """

    #: standstill: |dq| under this with a zero reference velocity [rad/s]
    STANDSTILL_RAD_S = 0.01
    #: a quick stop whose reference has stopped completes after this even if the joint has
    #: not settled within the standstill window [s]
    QUICK_STOP_SETTLE_S = 0.5

    def __init__(
        self,
        node_id: int,
        axis: AxisParameters,
        limits: DriveLimits,
        send: Callable[[can.Message], None],
        eds: Path = EDS_PATH,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id {node_id} not in 1..127")
        self.node_id = node_id
        self.axis = axis
        self.limits = limits
        self._od = DriveDictionary(node_id, send, self._on_read, self._on_write, eds)
        self._heartbeats = Heartbeats()  #: producer (0x1017) and consumer (0x1016)
        self.node = self._od.node
        #: the parameters stored in the drive's memory: a reset node restores them
        self._stored: dict[tuple[int, int], int] = {
            **axis.objects(),
            (profile.FOLLOWING_ERROR_WINDOW, 0): round(
                limits.max_following_error_rad * axis.increments_per_rad
            ),
        }
        self._live: dict[int, Callable[[], int]] = {
            profile.STATUSWORD: lambda: self.statusword,
            profile.MODES_OF_OPERATION_DISPLAY: lambda: int(self.mode or 0),
            profile.ERROR_CODE: lambda: int(self.error_code),
            profile.ERROR_REGISTER: self._error_register,
            profile.POSITION_ACTUAL: lambda: self.axis.increments(self.q_rad),
            profile.VELOCITY_ACTUAL: lambda: self.axis.increments(self.dq_rad_s),
            profile.CURRENT_ACTUAL: lambda: self.axis.per_mille(self.current_a),
            profile.TORQUE_ACTUAL: lambda: self.axis.per_mille(self.current_a),
        }
        self.booted = False
        self.nmt_state = NmtState.INITIALISING
        self.state = DriveState.NOT_READY_TO_SWITCH_ON
        self.error_code = ErrorCode.NONE
        self.mode: Mode | None = None  #: the accepted mode, 0x6061
        self.controlword = 0
        self.faults: list[str] = []  #: every fault, with its cause
        self.transitions: list[int] = []  #: transition numbers taken, oldest first
        self.power_cut = False  #: the power last went off by a fault (stop category 0)
        self.bad_frames = 0  #: PDOs shorter than their mapping (not processed)
        self.rpdo_stamp_s: float | None = None  #: the last RPDO's arrival since the last SYNC
        #: measurements: joint position [rad], velocity [rad/s], motor current [A]
        self.q_rad = self.dq_rad_s = self.current_a = 0.0
        #: the servo cycles' currents since the last SYNC: their sum [A] and count (0x2010)
        self._current_sum_a, self._current_samples = 0.0, 0
        self._current_averaging = False  #: 0x2010 is 1
        self._q_step = 0.0  #: the joint's position at the last step [rad]
        #: the reference: q_ref [rad] at t_ref [s], extrapolated with dq_ref [rad/s]
        self.q_ref_rad = self.dq_ref_rad_s = self.t_ref_s = 0.0
        self._estop = False
        self._following_error = False

    def boot(self) -> None:
        """Power on: transition 0, then boot-up (``0x700+id [0x00]``) and pre-operational."""
        self.booted = True
        self._reset_application()
        self._reset_communication()

    # --- object dictionary ------------------------------------------------------------------
    def read(self, index: int, subindex: int = 0) -> int:
        """An object's value as an SDO upload would give it."""
        return self._od.read(index, subindex)

    def write(self, index: int, subindex: int, value: int) -> None:
        """Write an object as an SDO download would (its checks included: SdoAbortedError)."""
        self._od.write(index, subindex, value)

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> int | None:
        live = self._live.get(index)
        return live() if live is not None else None

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        """Check and apply a write (SDO or RPDO) before the dictionary stores it."""
        value = od.decode_raw(data)
        if index == profile.CONTROLWORD:
            self.controlword = value
        elif index == profile.MODES_OF_OPERATION:
            if value not in tuple(Mode):
                raise SdoAbortedError(SdoAbort.VALUE_RANGE_EXCEEDED)
            self.mode = Mode(value)
        elif index == profile.TARGET_POSITION:
            self._target_inc, self._target_written = value, True
        elif index == profile.VELOCITY_OFFSET:
            self._velocity_offset_inc = value
        elif index == profile.TARGET_VELOCITY:
            self._target_velocity_inc = value
        elif index == profile.QUICK_STOP_OPTION:
            if value not in SUPPORTED_QUICK_STOP_OPTIONS:
                raise SdoAbortedError(SdoAbort.VALUE_RANGE_EXCEEDED)
            self._quick_stop_option = value
        elif index == profile.ABORT_CONNECTION_OPTION:
            if value not in tuple(AbortConnectionOption):
                raise SdoAbortedError(SdoAbort.VALUE_RANGE_EXCEEDED)
            self._abort_option = AbortConnectionOption(value)
        elif index == profile.QUICK_STOP_DECELERATION:
            if value <= 0:
                raise SdoAbortedError(SdoAbort.VALUE_RANGE_EXCEEDED)
            self._quick_stop_decel_inc = value
        elif index == profile.COMMUNICATION_CYCLE_PERIOD:
            self._cycle_period_s = value * 1e-6
        elif index == profile.CURRENT_AVERAGING:
            if value not in (0, 1):
                raise SdoAbortedError(SdoAbort.VALUE_RANGE_EXCEEDED)
            self._current_averaging = bool(value)
        elif index == profile.COB_ID_SYNC:
            if value & (SYNC_GENERATES | 1 << 29):  # the SYNC producer, or a 29-bit id
                raise SdoAbortedError(SdoAbort.VALUE_RANGE_EXCEEDED)
            self.sync_cob_id = value & SYNC_COB_ID_MASK
        elif index == profile.PRODUCER_HEARTBEAT_TIME:
            self._heartbeats.set_producer(value)
        elif index == profile.CONSUMER_HEARTBEAT_TIME and subindex == 1:
            self._heartbeats.set_consumer(value)
        elif (
            index
            in profile.RPDO_COMMUNICATION
            + profile.TPDO_COMMUNICATION
            + profile.RPDO_MAPPING
            + profile.TPDO_MAPPING
        ):
            self._od.check_pdo_write(index, subindex, value)
            self._od.invalidate_pdos()

    def _load_settings(self) -> None:
        """The values the drive works with, from its dictionary (after a reset)."""
        self.controlword = self.read(profile.CONTROLWORD)
        self._previous_controlword = self.controlword
        mode = self.read(profile.MODES_OF_OPERATION)
        self.mode = Mode(mode) if mode in tuple(Mode) else None
        self._target_inc = self.read(profile.TARGET_POSITION)
        self._velocity_offset_inc = self.read(profile.VELOCITY_OFFSET)
        self._target_velocity_inc = self.read(profile.TARGET_VELOCITY)
        self._quick_stop_option = self.read(profile.QUICK_STOP_OPTION)
        self._quick_stop_decel_inc = self.read(profile.QUICK_STOP_DECELERATION)
        self._abort_option = AbortConnectionOption(self.read(profile.ABORT_CONNECTION_OPTION))
        self._cycle_period_s = self.read(profile.COMMUNICATION_CYCLE_PERIOD) * 1e-6
        self._current_averaging = bool(self.read(profile.CURRENT_AVERAGING))

    def pdo_config(self, comm_index: int) -> PdoConfig:
        """A PDO as its objects now configure it (``comm_index`` 0x1400.. or 0x1800..)."""
        return self._od.pdo_config(comm_index)

    def _refused(self, why: str) -> None:
        """A value an RPDO carried was refused: a fault (a PDO cannot be answered by abort)."""
        self._fault(ErrorCode.PARAMETER, why)

    # --- resets -----------------------------------------------------------------------------
    def _reset_application(self) -> None:
        """Power-on or NMT reset node: the application's objects (0x2000 and up) back to
        their stored values or defaults, the state machine restarted (transition 0)."""
        self._od.clear_application()
        for (index, subindex), value in self._stored.items():
            self._od.store(index, subindex, value)
        self._load_settings()
        self.error_code = ErrorCode.NONE
        self.state = DriveState.NOT_READY_TO_SWITCH_ON
        self.transitions.append(0)
        self._quick_stopped_s: float | None = None  #: when the quick stop ramp reached 0
        self._following_error = False
        self._target_written = self._fresh_target = False
        self._synced = False  #: a SYNC came since the last step
        #: the setpoint (target, velocity offset, target velocity) of the last SYNC, and the
        #: SYNC at which it last moved (or carried a velocity)
        self._last_setpoint: tuple[int, int, int] | None = None
        self._setpoint_moved_sync = -(10**9)
        self._last_sync_s: float | None = None
        self.dq_ref_rad_s = 0.0

    def _reset_communication(self) -> None:
        """NMT reset communication (and the end of every reset): the communication objects
        (0x1000-0x1FFF) back to their defaults, then boot-up and pre-operational."""
        self._od.clear_communication()
        self.sync_cob_id = self.read(profile.COB_ID_SYNC) & SYNC_COB_ID_MASK
        self._cycle_period_s = self.read(profile.COMMUNICATION_CYCLE_PERIOD) * 1e-6
        self._sync_count = 0
        self._tpdo_last: dict[int, bytes] = {}
        self._rpdo_latched: dict[int, bytes] = {}
        self.rpdo_stamp_s = None
        self._heartbeats.set_producer(self.read(profile.PRODUCER_HEARTBEAT_TIME))
        self._heartbeats.set_consumer(self.read(profile.CONSUMER_HEARTBEAT_TIME, 1))
        self.nmt_state = NmtState.INITIALISING
        self._send(HEARTBEAT_BASE + self.node_id, bytes([NmtState.INITIALISING]))  # boot-up
        self.nmt_state = NmtState.PRE_OPERATIONAL

    # --- frames -----------------------------------------------------------------------------
    def _send(self, cob_id: int, data: bytes) -> None:
        self._od.send(cob_id, data)

    def on_nmt(self, data: bytes) -> None:
        """An NMT command frame (COB 0x000)."""
        if not self.booted or len(data) != 2 or data[1] not in (0, self.node_id):
            return
        command = data[0]
        if command == NmtCommand.START:
            self.nmt_state = NmtState.OPERATIONAL
        elif command in (NmtCommand.STOP, NmtCommand.ENTER_PRE_OPERATIONAL):
            if self.nmt_state == NmtState.OPERATIONAL and self.powered:
                self._connection_lost(f"NMT command 0x{command:02X} left operational")
            stop = command == NmtCommand.STOP
            self.nmt_state = NmtState.STOPPED if stop else NmtState.PRE_OPERATIONAL
            self._rpdo_latched.clear()  # PDOs received in operational die with it
        elif command == NmtCommand.RESET_NODE:
            powered = self.powered
            self._reset_application()
            if powered:
                self._power_off(cut=True)  # the application restarts: its power stage drops
            self._reset_communication()
        elif command == NmtCommand.RESET_COMMUNICATION:
            if self.powered:
                self._connection_lost("NMT reset communication")
            self._reset_communication()

    def on_frame(
        self, can_id: int, data: bytes, wall_s: float, now_s: float, stamp_s: float
    ) -> None:
        """A frame other than NMT (COB 0x000), received at monotonic ``wall_s`` (stamped
        ``stamp_s``), at simulated time ``now_s``."""
        nmt = self.nmt_state
        if not self.booted:
            return
        self._heartbeats.received(can_id, wall_s)
        if nmt == NmtState.STOPPED:
            return  # only NMT and heartbeats in stopped
        if can_id == SDO_RX_BASE + self.node_id:
            self.node.sdo.on_request(can_id, data, stamp_s)
        elif can_id == self.sync_cob_id:
            self.on_sync(now_s)
        elif nmt == NmtState.OPERATIONAL and (pdo := self._od.pdos()[0].get(can_id)) is not None:
            self._on_rpdo(pdo, data, stamp_s)

    def _on_rpdo(self, pdo: PdoConfig, data: bytes, stamp_s: float) -> None:
        if len(data) < pdo.length_bytes:
            # CiA 301: a PDO shorter than its mapping is not processed
            self.bad_frames += 1
            self._emcy(ErrorCode.PDO_LENGTH)
            return
        self.rpdo_stamp_s = stamp_s
        if pdo.transmission_type <= 240:
            self._rpdo_latched[pdo.cob_id] = bytes(data)  # takes effect at the next SYNC
        else:
            self._od.unpack(pdo, data, self._refused)

    @property
    def cycle_period_s(self) -> float:
        """The communication cycle period the host configured (0x1006) [s]; 0 if none."""
        return self._cycle_period_s

    @property
    def setpoint_moving(self) -> bool:
        """The host moved this drive's setpoint within :data:`MOVED_WITHIN_SYNCS` SYNCs."""
        return self._sync_count - self._setpoint_moved_sync <= MOVED_WITHIN_SYNCS

    def on_sync(self, now_s: float) -> None:
        """A SYNC: send the TPDOs sampled now, then the RPDOs received since the last SYNC take
        effect (on the motion at the next :meth:`step`)."""
        self._last_sync_s = now_s
        if self._current_averaging and self._current_samples:
            self.current_a = self._current_sum_a / self._current_samples
        self._current_sum_a, self._current_samples = 0.0, 0
        if self.nmt_state != NmtState.OPERATIONAL:
            return
        self._sync_count += 1
        rpdos, tpdos = self._od.pdos()
        for pdo in tpdos:
            kind = pdo.transmission_type
            if kind and self._sync_count % kind:
                continue
            data = self._od.pack(pdo)
            if kind == 0 and self._tpdo_last.get(pdo.cob_id) == data:
                continue  # acyclic synchronous: sent at a SYNC when its data changed
            self._tpdo_last[pdo.cob_id] = data
            self._send(pdo.cob_id, data)
        for cob_id, data in self._rpdo_latched.items():
            if (pdo := rpdos.get(cob_id)) is not None:
                self._od.unpack(pdo, data, self._refused)
        self._rpdo_latched.clear()
        setpoint = (self._target_inc, self._velocity_offset_inc, self._target_velocity_inc)
        if setpoint != self._last_setpoint or any(setpoint[1:]):
            self._setpoint_moved_sync = self._sync_count
        self._last_setpoint = setpoint
        self._fresh_target = self._fresh_target or self._target_written
        self._target_written = False
        self._synced = True

    def heartbeat(self, wall_s: float) -> None:
        """Send the producer heartbeat (0x1017) when it is due."""
        if self.booted and self._heartbeats.due(wall_s):
            self._send(HEARTBEAT_BASE + self.node_id, bytes([self.nmt_state]))
            self._heartbeats.sent(wall_s)

    def _emcy(self, code: ErrorCode) -> None:
        if self.nmt_state in (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL):
            data = struct.pack("<HB5x", code, self._error_register())
            self._send(EMCY_BASE + self.node_id, data)

    # --- state ------------------------------------------------------------------------------
    @property
    def powered(self) -> bool:
        """The power stage drives the motor, its brake released."""
        return self.state in POWERED_STATES

    @property
    def statusword(self) -> int:
        st = self.state
        standstill = (
            self.powered
            and self.dq_ref_rad_s == 0.0
            and abs(self.dq_rad_s) <= self.STANDSTILL_RAD_S
        )
        return statusword(
            st,
            voltage_enabled=not self._estop,
            warning=self._following_error,
            target_reached=standstill,
            follows_command=st == DriveState.OPERATION_ENABLED,
            following_error=self._following_error and self.mode == Mode.CYCLIC_SYNCHRONOUS_POSITION,
        )

    def _error_register(self) -> int:
        if self.error_code == ErrorCode.NONE:
            return 0
        bits = ERROR_REGISTER_GENERIC
        if self.error_code in COMMUNICATION_ERRORS:
            bits |= ERROR_REGISTER_COMMUNICATION
        elif self.error_code in (ErrorCode.FOLLOWING_ERROR, ErrorCode.PARAMETER):
            bits |= ERROR_REGISTER_PROFILE
        return bits

    def _enter(self, state: DriveState, transition: int, now_s: float) -> None:
        was_powered = self.powered
        self.state = state
        self.transitions.append(transition)
        if self.powered and not was_powered:  # 4 or 16
            self.power_cut = False
            q = self._q_step if transition == 4 else self.reference_position(now_s)
            self._set_reference(q, 0.0, now_s)
            self._last_sync_s = now_s  # the sync watchdog starts now
        elif was_powered and not self.powered:
            self._power_off(cut=state == DriveState.FAULT_REACTION_ACTIVE)
        if state == DriveState.QUICK_STOP_ACTIVE:
            self._quick_stopped_s = None
        elif transition == 15:
            self.power_cut = False  # the cut is over: the brakes hold

    def _power_off(self, cut: bool) -> None:
        """The power stage goes off: on a fault at once (``cut``, stop category 0: the brake
        bites after its engagement time), else it holds while its brake closes."""
        self.power_cut = cut
        self.dq_ref_rad_s = 0.0

    def _fault(self, code: ErrorCode, why: str, now_s: float | None = None) -> None:
        """Transition 13: the fault reaction (stop category 0, the power cut at once)."""
        if self.state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
            return
        message = f"node {self.node_id}: 0x{code:04X} {code.name}: {why}"
        log.warning("drive fault, %s", message)
        self.faults.append(message)
        self.error_code = code
        self._enter(DriveState.FAULT_REACTION_ACTIVE, 13, self.t_ref_s if now_s is None else now_s)
        self._emcy(code)

    def _connection_lost(self, why: str) -> None:
        """Apply 0x6007, the abort connection option code (CiA 402)."""
        option = self._abort_option
        log.warning("node %d: %s: abort connection option %s", self.node_id, why, option.name)
        if option == AbortConnectionOption.FAULT:
            self._fault(ErrorCode.HEARTBEAT, why)
        elif option != AbortConnectionOption.NO_ACTION:
            disable = option == AbortConnectionOption.DISABLE_VOLTAGE
            command = Command.DISABLE_VOLTAGE if disable else Command.QUICK_STOP
            if (found := TRANSITIONS.get((self.state, command))) is not None:
                self._enter(*found, self.t_ref_s)

    def _set_reference(self, q_rad: float, dq_rad_s: float, t_s: float) -> None:
        self.q_ref_rad, self.dq_ref_rad_s, self.t_ref_s = q_rad, dq_rad_s, t_s

    def reference_position(self, now_s: float) -> float:
        """The position the reference has reached at ``now_s`` [rad]."""
        return self.q_ref_rad + self.dq_ref_rad_s * (now_s - self.t_ref_s)

    def reference(self, now_s: float) -> tuple[float, float] | None:
        """(q_ref [rad], dq_ref [rad/s]) for the inner loop from ``now_s``; None unpowered."""
        if not self.powered:
            return None
        return self.reference_position(now_s), self.dq_ref_rad_s

    def sample(self, q_rad: float, dq_rad_s: float, current_a: float) -> None:
        """The joint's measurements as the drive's encoder and current sensor have them."""
        self.q_rad, self.dq_rad_s = q_rad, dq_rad_s
        self._current_sum_a += current_a
        self._current_samples += 1
        if not self._current_averaging:
            self.current_a = current_a

    # --- the servo cycle --------------------------------------------------------------------
    def step(self, now_s: float, q_rad: float, wall_s: float, estop: bool = False) -> None:
        """One servo cycle at simulated time ``now_s`` with the joint at ``q_rad``: automatic
        transitions, monitoring, the controlword, then the reference."""
        if not self.booted:
            return
        self._estop, self._q_step = estop, q_rad
        if self.state == DriveState.NOT_READY_TO_SWITCH_ON:
            self._enter(DriveState.SWITCH_ON_DISABLED, 1, now_s)  # self-test passed
        elif self.state == DriveState.FAULT_REACTION_ACTIVE:
            self._enter(DriveState.FAULT, 14, now_s)  # the power is off: reaction done
        if estop:
            self._fault(ErrorCode.EXTERNAL, "e-stop chain open", now_s)
        self._watch_host(wall_s)
        self._watch_sync(now_s)
        found = next_state(
            self.state,
            self.controlword,
            self._previous_controlword,
            self._quick_stop_option,
            fault_present=estop,
        )
        self._previous_controlword = self.controlword
        if found is not None:
            if found[1] == 15:
                self.error_code = ErrorCode.NONE
                self._following_error = False
                self._emcy(ErrorCode.NONE)
            if found[0] == DriveState.OPERATION_ENABLED and self.mode is None:
                self._fault(ErrorCode.PARAMETER, "operation enabled with no mode", now_s)
            else:
                self._enter(*found, now_s)
        synced, self._synced = self._synced, False
        if self.state == DriveState.OPERATION_ENABLED and synced:
            self._follow(now_s)
        elif self.state == DriveState.QUICK_STOP_ACTIVE:
            self._quick_stop(now_s)
        if synced:
            self._fresh_target = False
        if self.powered:
            error = abs(self.reference_position(now_s) - q_rad)
            self._following_error = error > self.limits.max_following_error_rad
            if self._following_error:
                self._fault(ErrorCode.FOLLOWING_ERROR, f"following error {error:.4f} rad", now_s)

    def _follow(self, now_s: float) -> None:
        """The RPDOs of the SYNC(s) since the last step, in the mode selected."""
        if self.mode == Mode.CYCLIC_SYNCHRONOUS_POSITION:
            if self._fresh_target:
                q = self.axis.rad(self._target_inc)
                self._set_reference(q, self.axis.rad(self._velocity_offset_inc), now_s)
            else:  # no new target: freeze where the extrapolation has brought it
                self._set_reference(self.reference_position(now_s), 0.0, now_s)
        else:
            q = self.reference_position(now_s)
            self._set_reference(q, self.axis.rad(self._target_velocity_inc), now_s)

    def _quick_stop(self, now_s: float) -> None:
        """Slow down on the quick stop ramp 0x6085; at standstill, with option code 1..4, go
        to Switch on disabled (transition 12), the brake closing while the drive holds."""
        q = self.reference_position(now_s)
        decel_rad_s2 = self.axis.rad(self._quick_stop_decel_inc)
        dq = self.dq_ref_rad_s
        if dq:
            slower = abs(dq) - decel_rad_s2 * max(now_s - self.t_ref_s, 0.0)
            dq = math.copysign(max(slower, 0.0), dq)
        self._set_reference(q, dq, now_s)
        if dq:
            return
        if self._quick_stopped_s is None:
            self._quick_stopped_s = now_s
        settled = abs(self.dq_rad_s) <= self.STANDSTILL_RAD_S
        timed_out = now_s - self._quick_stopped_s >= self.QUICK_STOP_SETTLE_S
        to_disabled = self._quick_stop_option in QUICK_STOP_TO_SWITCH_ON_DISABLED
        if (settled or timed_out) and to_disabled:
            self._enter(DriveState.SWITCH_ON_DISABLED, 12, now_s)

    def _watch_host(self, wall_s: float) -> None:
        """The consumer heartbeat (0x1016): a miss disarms it until the next heartbeat."""
        why = self._heartbeats.missed(wall_s)
        if why is not None and (
            self.nmt_state == NmtState.OPERATIONAL or self.state == DriveState.OPERATION_ENABLED
        ):
            self._connection_lost(why)

    def _watch_sync(self, now_s: float) -> None:
        period_s = self._cycle_period_s
        if self.state != DriveState.OPERATION_ENABLED or period_s <= 0:
            return
        last = now_s if self._last_sync_s is None else self._last_sync_s
        if now_s - last > self.limits.sync_timeout_cycles * period_s:
            self._fault(ErrorCode.SYNC, f"no SYNC for {now_s - last:.3f} s", now_s)
