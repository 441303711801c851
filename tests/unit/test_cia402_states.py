"""The host's side of the CiA 402 state machine (drivers/can/cia402_states.py) against the
standard's tables, written out here as the standard prints them: the statusword's state coding
(x: any value) and the device control commands with their transition numbers."""

from __future__ import annotations

import itertools

import pytest

from drivers.can.adapter import HostRequest
from drivers.can.cia402_states import (
    CW_SHUTDOWN,
    TRANSITIONS,
    DriveState,
    controlword_for,
    decode_state,
)

S = DriveState
#: CiA 402 statusword state coding, bits 6..0 (bit 6 switch on disabled, 5 quick stop,
#: 3 fault, 2 operation enabled, 1 switched on, 0 ready to switch on; bit 4 voltage enabled
#: and bits 7..15 are "x")
STATE_CODING = {
    S.NOT_READY_TO_SWITCH_ON: "0xx0000",
    S.SWITCH_ON_DISABLED: "1xx0000",
    S.READY_TO_SWITCH_ON: "01x0001",
    S.SWITCHED_ON: "01x0011",
    S.OPERATION_ENABLED: "01x0111",
    S.QUICK_STOP_ACTIVE: "00x0111",
    S.FAULT_REACTION_ACTIVE: "0xx1111",
    S.FAULT: "0xx1000",
}
#: device control commands: controlword bits 7, 3..0 (x: any), and the transitions they cause
COMMANDS = {
    "shutdown": ("0x110", (2, 6, 8)),
    "switch on": ("00111", (3,)),
    "disable voltage": ("0xx0x", (7, 9, 10, 12)),
    "quick stop": ("0x01x", (7, 10, 11)),
    "disable operation": ("00111", (5,)),
    "enable operation": ("01111", (4, 16)),
    "fault reset": ("1xxxx", (15,)),  # its rising edge
}


def _expand(pattern: str) -> list[int]:
    xs = [i for i, c in enumerate(pattern) if c == "x"]
    out = []
    for bits in itertools.product("01", repeat=len(xs)):
        chars = list(pattern)
        for i, b in zip(xs, bits, strict=True):
            chars[i] = b
        out.append(int("".join(chars), 2))
    return out


@pytest.mark.parametrize("state", list(STATE_CODING))
def test_every_statusword_of_a_state_decodes_to_it(state):
    for low in _expand(STATE_CODING[state]):
        # bit 4 (voltage enabled) and bits 7..15 are free in every coding
        for voltage, high in itertools.product((0, 1 << 4), (0, 1 << 9, 0xFF80)):
            word = low | voltage | high
            assert decode_state(word) == state, f"statusword 0x{word:04X}"


def _matches(controlword: int, pattern: str) -> bool:
    bits = [(controlword >> 7) & 1] + [(controlword >> b) & 1 for b in (3, 2, 1, 0)]
    return all(p == "x" or int(p) == b for p, b in zip(pattern, bits, strict=True))


def test_each_transition_the_host_drives_uses_the_standards_command():
    for number, (_, _, controlword) in TRANSITIONS.items():
        names = [n for n, (pattern, nums) in COMMANDS.items() if number in nums]
        assert names, f"transition {number} has no command in the standard's table"
        assert any(_matches(controlword, COMMANDS[n][0]) for n in names), (
            f"transition {number}: controlword 0x{controlword:04X} is not {names}"
        )


def test_servo_on_walks_2_3_4_and_stays_enabled():
    state, path = S.SWITCH_ON_DISABLED, []
    after = {2: S.READY_TO_SWITCH_ON, 3: S.SWITCHED_ON, 4: S.OPERATION_ENABLED}
    for _ in range(5):
        cw, step = controlword_for(state, HostRequest.SERVO_ON)
        if step is None:
            assert state == S.OPERATION_ENABLED and _matches(cw, COMMANDS["enable operation"][0])
            break
        assert TRANSITIONS[step][0] == state
        if step == 3:  # switch on + enable operation: the drive makes 3 and 4 (see below)
            assert _matches(cw, COMMANDS["enable operation"][0])
        path.append(step)
        state = after[step]
    assert path == [2, 3, 4]


def test_brake_leaves_operation_by_disable_operation_then_rests_with_the_power_stage_off():
    cw, step = controlword_for(S.OPERATION_ENABLED, HostRequest.BRAKE)
    assert step == 5 and _matches(cw, COMMANDS["disable operation"][0])
    assert controlword_for(S.SWITCHED_ON, HostRequest.BRAKE)[1] == 6
    assert controlword_for(S.SWITCH_ON_DISABLED, HostRequest.BRAKE)[1] == 2
    cw, step = controlword_for(S.READY_TO_SWITCH_ON, HostRequest.BRAKE)
    assert step is None and _matches(cw, COMMANDS["shutdown"][0])  # stays: power stage off


def test_fault_needs_an_explicit_reset_and_a_quick_stop_is_never_undone():
    for request in (HostRequest.SERVO_ON, HostRequest.BRAKE):
        cw, step = controlword_for(S.FAULT, request)
        assert step is None and not cw & 0x80  # no fault reset without RESET_FAULT
        assert controlword_for(S.FAULT_REACTION_ACTIVE, request)[1] is None
        cw, step = controlword_for(S.QUICK_STOP_ACTIVE, request)
        assert step is None and _matches(cw, COMMANDS["quick stop"][0])  # not 16
    cw, step = controlword_for(S.FAULT, HostRequest.RESET_FAULT)
    assert step == 15 and _matches(cw, COMMANDS["fault reset"][0])
    assert TRANSITIONS[15][1] == S.SWITCH_ON_DISABLED


#: the standard's transitions by command, as a drive makes them: (state, command) → state.
#: "enable operation" in ready to switch on is the standard's "switch on + enable operation":
#: transition 3, then 4 at the drive's next tick.
DRIVE = {
    (S.SWITCH_ON_DISABLED, "shutdown"): S.READY_TO_SWITCH_ON,  # 2
    (S.READY_TO_SWITCH_ON, "switch on"): S.SWITCHED_ON,  # 3
    (S.READY_TO_SWITCH_ON, "enable operation"): S.SWITCHED_ON,  # 3, then 4
    (S.SWITCHED_ON, "enable operation"): S.OPERATION_ENABLED,  # 4
    (S.OPERATION_ENABLED, "disable operation"): S.SWITCHED_ON,  # 5
    (S.SWITCHED_ON, "shutdown"): S.READY_TO_SWITCH_ON,  # 6
    (S.OPERATION_ENABLED, "shutdown"): S.READY_TO_SWITCH_ON,  # 8
}
TICKS_PER_SYNC = 4  #: the drive's servo ticks in one SYNC period (2 ms ticks, 8 ms SYNC)


def _command(state: DriveState, controlword: int) -> str | None:
    """The device control command ``controlword`` is in ``state`` (bits 0-3 of 0x07 are
    "switch on" in general and "disable operation" in operation enabled)."""
    names = [n for n, (pattern, _) in COMMANDS.items() if _matches(controlword, pattern)]
    if "disable operation" in names and state != S.OPERATION_ENABLED:
        names.remove("disable operation")
    if "switch on" in names and state == S.OPERATION_ENABLED:
        names.remove("switch on")
    return next((n for n in names if (state, n) in DRIVE), None)


def _walk(requests: list[HostRequest]) -> list[tuple[HostRequest, DriveState]]:
    """A drive on a synchronous link, one request per SYNC period: at each SYNC it reports
    its state (TPDO1) and then takes the last controlword received before that SYNC (RPDO1);
    it ticks TICKS_PER_SYNC times per period. The host answers each report at once with the
    controlword ``controlword_for`` gives for what it read, and sends one more when the
    request changes (the request's own RPDO1s), from the same reading: its view is always
    one SYNC old. Returns (request, the drive's state) at every tick."""
    state, latched, reading, pending = S.SWITCH_ON_DISABLED, CW_NONE, S.SWITCH_ON_DISABLED, None
    request, seen = None, []
    for wanted in requests:
        reading = state  # the TPDO1 sampled at this SYNC
        latched = pending if pending is not None else latched  # then the RPDO1 applies
        pending = controlword_for(reading, request or wanted)[0]  # the cycle's answer
        if wanted != request:  # the request changes between two SYNCs
            request = wanted
            pending = controlword_for(reading, request)[0]
        for _ in range(TICKS_PER_SYNC):
            command = _command(state, latched)
            if command is not None:
                state = DRIVE[state, command]
            seen.append((request, state))
    return seen


CW_NONE = CW_SHUTDOWN  #: what the drive holds before the host's first RPDO1


def _trace(seen: list[tuple[HostRequest, DriveState]]) -> str:
    return " ".join(f"{r.name[0]}:{s.name[:4]}" for r, s in seen[:: TICKS_PER_SYNC // 2])


@pytest.mark.parametrize("off_for", range(0, 6))
@pytest.mark.parametrize("on_for", range(1, 8))
def test_a_stop_and_start_read_one_sync_late_never_takes_an_enabled_drive_out(on_for, off_for):
    """SERVO_ON, then BRAKE for ``off_for`` SYNCs (0: within one period), then SERVO_ON again,
    each at a SYNC boundary: whatever state the host's one-SYNC-old reading shows, the walk
    never moves a drive out of operation enabled while SERVO_ON is the request (the demo's
    stop and start 74 ms apart on the CiA 402 cell: 0x0F from ready to switch on took the
    drive through 3 and 4 within a period, the host still read *ready* and sent *switch on*,
    which is disable operation in operation enabled: the drive left it, the host latched a
    drop-out, 2026-11-30), and the walk ends in operation enabled."""
    on, off = HostRequest.SERVO_ON, HostRequest.BRAKE
    requests = [on] * on_for + [off] * off_for + [on] * 12
    seen = _walk(requests)
    for (req, before), (req_now, after) in itertools.pairwise(seen):
        if req == req_now == on and before == S.OPERATION_ENABLED:
            assert after == S.OPERATION_ENABLED, f"left operation enabled: {_trace(seen)}"
    assert seen[-1] == (on, S.OPERATION_ENABLED)
