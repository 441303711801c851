"""The CiA 402 drive profile's state machine as the host drives it (drivers/can/cia402.py): the
drive states, their coding in the statusword, the device control commands of the controlword,
and the controlword that takes a drive one step towards what the host requests.

From the standard (CiA 402-2, the power drive system's finite state automaton); transition
numbers as it numbers them.
"""

from __future__ import annotations

import enum

from drivers.can.adapter import HostRequest


class DriveState(enum.Enum):
    """The CiA 402 power drive system's states."""

    NOT_READY_TO_SWITCH_ON = "not ready to switch on"
    SWITCH_ON_DISABLED = "switch on disabled"
    READY_TO_SWITCH_ON = "ready to switch on"
    SWITCHED_ON = "switched on"
    OPERATION_ENABLED = "operation enabled"
    QUICK_STOP_ACTIVE = "quick stop active"
    FAULT_REACTION_ACTIVE = "fault reaction active"
    FAULT = "fault"


S = DriveState
#: the standard's state coding of the statusword: (mask, value, state)
STATUSWORD_STATES: tuple[tuple[int, int, DriveState], ...] = (
    (0x4F, 0x00, S.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, S.SWITCH_ON_DISABLED),
    (0x6F, 0x21, S.READY_TO_SWITCH_ON),
    (0x6F, 0x23, S.SWITCHED_ON),
    (0x6F, 0x27, S.OPERATION_ENABLED),
    (0x6F, 0x07, S.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, S.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, S.FAULT),
)

#: the standard's device control commands (controlword bits 0-3 and 7)
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007  #: also "disable operation" (transition 5)
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080  #: its rising edge

#: The transitions the host drives: number → (from, to, controlword). The others are the
#: drive's own (0, 1: power-up; 12 after a quick stop; 13, 14: fault reaction).
TRANSITIONS: dict[int, tuple[DriveState, DriveState, int]] = {
    2: (S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON, CW_SHUTDOWN),
    3: (S.READY_TO_SWITCH_ON, S.SWITCHED_ON, CW_SWITCH_ON),
    4: (S.SWITCHED_ON, S.OPERATION_ENABLED, CW_ENABLE_OPERATION),
    5: (S.OPERATION_ENABLED, S.SWITCHED_ON, CW_SWITCH_ON),
    6: (S.SWITCHED_ON, S.READY_TO_SWITCH_ON, CW_SHUTDOWN),
    7: (S.READY_TO_SWITCH_ON, S.SWITCH_ON_DISABLED, CW_DISABLE_VOLTAGE),
    8: (S.OPERATION_ENABLED, S.READY_TO_SWITCH_ON, CW_SHUTDOWN),
    9: (S.OPERATION_ENABLED, S.SWITCH_ON_DISABLED, CW_DISABLE_VOLTAGE),
    10: (S.SWITCHED_ON, S.SWITCH_ON_DISABLED, CW_DISABLE_VOLTAGE),
    11: (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE, CW_QUICK_STOP),
    15: (S.FAULT, S.SWITCH_ON_DISABLED, CW_FAULT_RESET),
    16: (S.QUICK_STOP_ACTIVE, S.OPERATION_ENABLED, CW_ENABLE_OPERATION),
}
#: the transition that takes a drive one step towards operation enabled (SERVO_ON) ...
SERVO_ON_STEPS = {S.SWITCH_ON_DISABLED: 2, S.READY_TO_SWITCH_ON: 3, S.SWITCHED_ON: 4}
#: ... and towards ready to switch on, by disable operation first (BRAKE)
BRAKE_STEPS = {S.OPERATION_ENABLED: 5, S.SWITCHED_ON: 6, S.SWITCH_ON_DISABLED: 2}


def decode_state(statusword: int) -> DriveState:
    """The drive state a statusword codes (the standard's table; every value codes one)."""
    for mask, value, state in STATUSWORD_STATES:
        if statusword & mask == value:
            return state
    # 0x6F-coded values with bit 5 (quick stop) or 6 in an unusual combination: not ready.
    return S.NOT_READY_TO_SWITCH_ON


def controlword_for(state: DriveState, request: HostRequest) -> tuple[int, int | None]:
    """The controlword that moves a drive in ``state`` one step towards what ``request`` asks,
    and that step's transition number (None: none, the controlword keeps the state).

    SERVO_ON walks 2 → 3 → 4 to *operation enabled* (3 and 4 by one controlword, *switch on +
    enable operation*). BRAKE leaves it by *disable operation*
    (5: the drive holds while its brake engages) and rests in *ready to switch on* (6, 2:
    power stage off). RESET_FAULT is fault reset (15). A quick stop is never undone here
    (no 16): it runs to its end and the drive must be switched on again from the start.
    """
    if state in (S.FAULT, S.FAULT_REACTION_ACTIVE):
        if request == HostRequest.RESET_FAULT and state == S.FAULT:
            return CW_FAULT_RESET, 15
        return CW_SHUTDOWN, None
    if state == S.QUICK_STOP_ACTIVE:
        return CW_QUICK_STOP, None
    if request == HostRequest.SERVO_ON:
        step = SERVO_ON_STEPS.get(state)
        if step is None:
            return CW_ENABLE_OPERATION if state == S.OPERATION_ENABLED else CW_SHUTDOWN, None
        if step == 3:
            # "switch on + enable operation": the drive makes 3, then 4 at its next tick. Not
            # "switch on": the host reads the state one SYNC late, and "switch on" is disable
            # operation (5) to a drive that has already reached operation enabled.
            return CW_ENABLE_OPERATION, step
        return TRANSITIONS[step][2], step
    # BRAKE (and RESET_FAULT of a drive that is not in fault)
    step = BRAKE_STEPS.get(state)
    if step is None:
        return CW_SHUTDOWN, None
    return TRANSITIONS[step][2], step
