"""CANopen facts the virtual cell's CiA 402 drives are built on, as data: object indices, NMT
states and commands, SDO abort and error codes (CiA 301); the state machine of CiA 402-2's
device control (its numbered transitions, controlword commands and statusword patterns); and
the pure functions that apply them. Written from the standards for the drive side
(:mod:`sim_bridge.cia402_drives`); nothing here comes from the product's host code.

The wire a drive of :mod:`sim_bridge.cia402_drives` speaks, per drive with node id ``n`` (all
COB-IDs are CiA 301's predefined connection set):

- NMT (COB 0x000 ``[command, n or 0]``): boot → boot-up ``0x700+n [0x00]`` → pre-operational;
  start 0x01 → operational (PDOs active), stop 0x02, pre-operational 0x80, reset node 0x81,
  reset communication 0x82 (both send the boot-up again);
- SDO server ``0x600+n`` → ``0x580+n`` (canopen), not in stopped;
- SYNC (COB from 0x1005, 0x080, 0 or 1 data bytes): in operational, the RPDOs received since
  the last SYNC take effect (synchronous transmission types 0..240; 254/255 take effect on
  arrival), and each TPDO is sent with the values sampled at this SYNC (types 1..240: every
  n-th SYNC; 0: when its data changed);
- PDOs as the host maps them by SDO, checked on write, packed and unpacked by their
  mapping (:mod:`sim_bridge.cia402_dictionary`);
- heartbeat producer ``0x700+n [state]`` every 0x1017 ms (0: off); consumer 0x1016 sub 1 =
  (producer id << 16) | time [ms]: armed by the producer's first heartbeat; a miss longer
  than the time while operational or in Operation enabled applies 0x6007
  (:mod:`sim_bridge.cia402_heartbeat`);
- EMCY ``0x80+n`` on every fault (its 0x603F code, 0x1001) and ``0x0000`` on its reset;
- the current (0x6078, and 0x6077 in its units) is the motor current of the last servo cycle
  before it is read, or with 0x2010 (manufacturer-specific) at 1 its mean over the servo cycles
  since the last SYNC, the communication cycle's mean (not stored: 0 after a reset node).
"""

from __future__ import annotations

from enum import Enum, IntEnum

# --- CiA 301 objects ----------------------------------------------------------------------
DEVICE_TYPE = 0x1000
ERROR_REGISTER = 0x1001
COB_ID_SYNC = 0x1005
COMMUNICATION_CYCLE_PERIOD = 0x1006  #: [µs]
CONSUMER_HEARTBEAT_TIME = 0x1016  #: sub 1: (producer node id << 16) | time [ms]
PRODUCER_HEARTBEAT_TIME = 0x1017  #: [ms]
RPDO_COMMUNICATION = (0x1400, 0x1401)
RPDO_MAPPING = (0x1600, 0x1601)
TPDO_COMMUNICATION = (0x1800, 0x1801)
TPDO_MAPPING = (0x1A00, 0x1A01)
# --- manufacturer-specific objects (the drive's EDS) ----------------------------------------
#: what 0x6078/0x6077 report: 0, the last servo cycle's current; 1, the mean since the last SYNC
CURRENT_AVERAGING = 0x2010
# --- CiA 402 objects ----------------------------------------------------------------------
ABORT_CONNECTION_OPTION = 0x6007
ERROR_CODE = 0x603F
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
QUICK_STOP_OPTION = 0x605A
MODES_OF_OPERATION = 0x6060
MODES_OF_OPERATION_DISPLAY = 0x6061
POSITION_ACTUAL = 0x6064  #: [increments]
FOLLOWING_ERROR_WINDOW = 0x6065  #: [increments]
VELOCITY_ACTUAL = 0x606C  #: [increments/s]
MOTOR_RATED_CURRENT = 0x6075  #: [mA]
MOTOR_RATED_TORQUE = 0x6076  #: [mN·m]
TORQUE_ACTUAL = 0x6077  #: [‰ of 0x6076]
CURRENT_ACTUAL = 0x6078  #: [‰ of 0x6075]
TARGET_POSITION = 0x607A  #: [increments]
QUICK_STOP_DECELERATION = 0x6085  #: [increments/s²]
POSITION_ENCODER_RESOLUTION = 0x608F  #: sub 1 increments per sub 2 motor revolutions
GEAR_RATIO = 0x6091  #: sub 1 motor revolutions per sub 2 shaft revolutions
VELOCITY_OFFSET = 0x60B1  #: [increments/s]
TARGET_VELOCITY = 0x60FF  #: [increments/s]

# --- CiA 301 services ---------------------------------------------------------------------
NMT_COB_ID = 0x000
EMCY_BASE = 0x080
SDO_RX_BASE = 0x600
HEARTBEAT_BASE = 0x700
PDO_NOT_VALID = 1 << 31
PDO_COB_ID_MASK = 0x7FF
SYNC_COB_ID_MASK = 0x7FF
SYNC_GENERATES = 1 << 30  #: 0x1005 bit 30: this node would be the SYNC producer


class NmtState(IntEnum):
    """NMT states as the heartbeat's state byte carries them (CiA 301 NMT error control)."""

    INITIALISING = 0x00  #: (the boot-up message)
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


class NmtCommand(IntEnum):
    """NMT command specifiers (CiA 301 NMT services)."""

    START = 0x01
    STOP = 0x02
    ENTER_PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


class SdoAbort(IntEnum):
    """SDO abort codes (CiA 301 SDO abort transfer) the drive's checks give."""

    UNSUPPORTED_ACCESS = 0x06010000
    NOT_MAPPABLE = 0x06040041
    MAPPING_TOO_LONG = 0x06040042
    PARAMETER_INCOMPATIBLE = 0x06040043
    VALUE_RANGE_EXCEEDED = 0x06090030


class ErrorCode(IntEnum):
    """0x603F and EMCY error codes (CiA 301 emergency error codes; CiA 402-2 drive error codes)."""

    NONE = 0x0000
    PARAMETER = 0x6320  #: parameter error: operation enabled, or a mode by PDO, not 8 or 9
    HEARTBEAT = 0x8130  #: life guard or heartbeat error (0x6007 = 1)
    PDO_LENGTH = 0x8210  #: PDO not processed due to length error (EMCY only)
    FOLLOWING_ERROR = 0x8611  #: position control: following error
    SYNC = 0x8700  #: sync controller: SYNC missing in Operation enabled
    EXTERNAL = 0x9000  #: external error: the cell's e-stop chain opened (safe torque off)


#: error register 0x1001 bits (CiA 301 object 0x1001)
ERROR_REGISTER_GENERIC = 0x01
ERROR_REGISTER_COMMUNICATION = 0x10
ERROR_REGISTER_PROFILE = 0x20
COMMUNICATION_ERRORS = (ErrorCode.HEARTBEAT, ErrorCode.SYNC, ErrorCode.PDO_LENGTH)


class Mode(IntEnum):
    """Modes of operation 0x6060 this drive supports (CiA 402-2 object 0x6060)."""

    CYCLIC_SYNCHRONOUS_POSITION = 8
    CYCLIC_SYNCHRONOUS_VELOCITY = 9


#: 0x6502: bit 7 csp, bit 8 csv (CiA 402-2 object 0x6502)
SUPPORTED_DRIVE_MODES = (1 << 7) | (1 << 8)


class AbortConnectionOption(IntEnum):
    """0x6007: what the drive does when its host connection is lost (CiA 402-2 object 0x6007)."""

    NO_ACTION = 0
    FAULT = 1
    DISABLE_VOLTAGE = 2
    QUICK_STOP = 3


#: 0x605A values supported: 2 slows down on the quick stop ramp then goes to Switch on
#: disabled; 6 slows down on it and stays in Quick stop active (CiA 402-2 object 0x605A)
QUICK_STOP_TO_SWITCH_ON_DISABLED = (1, 2, 3, 4)
QUICK_STOP_STAYS = (5, 6, 7, 8)
SUPPORTED_QUICK_STOP_OPTIONS = (2, 6)


# --- the CiA 402 state machine (CiA 402-2 device control) --------------------------
class DriveState(IntEnum):
    NOT_READY_TO_SWITCH_ON = 0
    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7


class Command(Enum):
    """Device control commands of the controlword's bits 0-3 with bit 7 clear (CiA 402-2)."""

    SHUTDOWN = "shutdown"  #: 0xxx x110
    SWITCH_ON = "switch on"  #: 0xxx 0111, also "disable operation"
    ENABLE_OPERATION = "enable operation"  #: 0xxx 1111, also "switch on + enable operation"
    DISABLE_VOLTAGE = "disable voltage"  #: 0xxx xx0x
    QUICK_STOP = "quick stop"  #: 0xxx x01x


#: controlword bits
CW_FAULT_RESET = 1 << 7
CW_HALT = 1 << 8

_S, _C = DriveState, Command
#: (state, command) → (next state, transition number in CiA 402-2's state machine). Transitions 0, 1
#: (automatic after power-on), 12 after a completed quick stop, 13 and 14 (fault, fault
#: reaction done) and 15 (fault reset) are events, not commands: see :func:`next_state`.
TRANSITIONS: dict[tuple[DriveState, Command], tuple[DriveState, int]] = {
    (_S.SWITCH_ON_DISABLED, _C.SHUTDOWN): (_S.READY_TO_SWITCH_ON, 2),
    (_S.READY_TO_SWITCH_ON, _C.SWITCH_ON): (_S.SWITCHED_ON, 3),
    # "switch on + enable operation" from Ready to switch on: 3, then 4 at the next tick
    (_S.READY_TO_SWITCH_ON, _C.ENABLE_OPERATION): (_S.SWITCHED_ON, 3),
    (_S.SWITCHED_ON, _C.ENABLE_OPERATION): (_S.OPERATION_ENABLED, 4),
    (_S.OPERATION_ENABLED, _C.SWITCH_ON): (_S.SWITCHED_ON, 5),  # disable operation
    (_S.SWITCHED_ON, _C.SHUTDOWN): (_S.READY_TO_SWITCH_ON, 6),
    (_S.READY_TO_SWITCH_ON, _C.DISABLE_VOLTAGE): (_S.SWITCH_ON_DISABLED, 7),
    (_S.READY_TO_SWITCH_ON, _C.QUICK_STOP): (_S.SWITCH_ON_DISABLED, 7),
    (_S.OPERATION_ENABLED, _C.SHUTDOWN): (_S.READY_TO_SWITCH_ON, 8),
    (_S.OPERATION_ENABLED, _C.DISABLE_VOLTAGE): (_S.SWITCH_ON_DISABLED, 9),
    (_S.SWITCHED_ON, _C.DISABLE_VOLTAGE): (_S.SWITCH_ON_DISABLED, 10),
    (_S.SWITCHED_ON, _C.QUICK_STOP): (_S.SWITCH_ON_DISABLED, 10),
    (_S.OPERATION_ENABLED, _C.QUICK_STOP): (_S.QUICK_STOP_ACTIVE, 11),
    (_S.QUICK_STOP_ACTIVE, _C.DISABLE_VOLTAGE): (_S.SWITCH_ON_DISABLED, 12),
    # only with a quick stop option code 5..8 (the drive stays in Quick stop active)
    (_S.QUICK_STOP_ACTIVE, _C.ENABLE_OPERATION): (_S.OPERATION_ENABLED, 16),
}

#: statusword bits 0-6 of each state (CiA 402-2); bit 5 "quick stop" is 1 when it is NOT active
STATE_BITS: dict[DriveState, int] = {
    _S.NOT_READY_TO_SWITCH_ON: 0x00,
    _S.SWITCH_ON_DISABLED: 0x40,
    _S.READY_TO_SWITCH_ON: 0x21,
    _S.SWITCHED_ON: 0x23,
    _S.OPERATION_ENABLED: 0x27,
    _S.QUICK_STOP_ACTIVE: 0x07,
    _S.FAULT_REACTION_ACTIVE: 0x0F,
    _S.FAULT: 0x08,
}
#: the masks that tell the states apart in a statusword (CiA 402-2)
STATE_MASKS: dict[DriveState, int] = {
    s: 0x4F
    if s
    in (
        _S.NOT_READY_TO_SWITCH_ON,
        _S.SWITCH_ON_DISABLED,
        _S.FAULT_REACTION_ACTIVE,
        _S.FAULT,
    )
    else 0x6F
    for s in DriveState
}
SW_VOLTAGE_ENABLED = 1 << 4
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_FOLLOWS_COMMAND = 1 << 12  #: csp/csv: the drive follows the command value
SW_FOLLOWING_ERROR = 1 << 13  #: csp: the position is out of the following error window
#: states in which the power stage drives the motor and the brake is released
POWERED_STATES = (_S.OPERATION_ENABLED, _S.QUICK_STOP_ACTIVE)


def decode_controlword(controlword: int) -> Command | None:
    """The device control command of ``controlword`` (CiA 402-2); None with bit 7 (fault reset)
    set, whose rising edge alone acts (transition 15)."""
    if controlword & CW_FAULT_RESET:
        return None
    if not controlword & 0x02:
        return Command.DISABLE_VOLTAGE
    if not controlword & 0x04:
        return Command.QUICK_STOP
    if not controlword & 0x01:
        return Command.SHUTDOWN
    return Command.ENABLE_OPERATION if controlword & 0x08 else Command.SWITCH_ON


def next_state(
    state: DriveState,
    controlword: int,
    previous_controlword: int,
    quick_stop_option: int,
    fault_present: bool = False,
) -> tuple[DriveState, int] | None:
    """The transition ``controlword`` asks of a drive in ``state``: (next state, transition
    number), or None. Fault reset (15) is the rising edge of bit 7 in Fault, refused while the
    fault's cause is still there (``fault_present``); 16 only with a quick stop option code
    that stays in Quick stop active."""
    if state == DriveState.FAULT:
        rising = controlword & CW_FAULT_RESET and not previous_controlword & CW_FAULT_RESET
        if rising and not fault_present:
            return DriveState.SWITCH_ON_DISABLED, 15
        return None
    command = decode_controlword(controlword)
    if command is None:
        return None
    found = TRANSITIONS.get((state, command))
    if found is not None and found[1] == 16 and quick_stop_option not in QUICK_STOP_STAYS:
        return None
    return found


def statusword(
    state: DriveState,
    *,
    voltage_enabled: bool = True,
    warning: bool = False,
    target_reached: bool = False,
    follows_command: bool = False,
    following_error: bool = False,
) -> int:
    """0x6041 for a drive in ``state`` (CiA 402-2 object 0x6041). Bit 9 (remote) is always
    set: the controlword on CAN is the drive's only command input."""
    word = STATE_BITS[state] | SW_REMOTE
    word |= SW_VOLTAGE_ENABLED if voltage_enabled else 0
    word |= SW_WARNING if warning else 0
    word |= SW_TARGET_REACHED if target_reached else 0
    word |= SW_FOLLOWS_COMMAND if follows_command else 0
    word |= SW_FOLLOWING_ERROR if following_error else 0
    return word


def state_of(word: int) -> DriveState | None:
    """The state a statusword shows (CiA 402-2), or None for a pattern that is none."""
    for state, bits in STATE_BITS.items():
        if word & STATE_MASKS[state] == bits:
            return state
    return None
