"""The virtual cell's CiA 402 drive state machine against the standard (CiA 402-2 device
control: the state machine, controlword commands, statusword patterns), transition by
transition: controlword in, state and statusword out. The expected values are restated here
from the standard, not taken from the drive module's tables, so a wrong table there fails
here."""

from __future__ import annotations

import itertools

import can
import pytest
from canopen.sdo import SdoAbortedError

from sim_bridge.cia402_drives import Cia402Drive
from sim_bridge.cia402_parameters import AxisParameters, DriveLimits
from sim_bridge.cia402_profile import DriveState, next_state, state_of, statusword

S = DriveState
AXIS = AxisParameters.for_joint(
    gear_ratio=147.0, rated_current_a=21.0, torque_constant_nm_per_a=46.21, encoder_bits=20
)
PERIOD_S = 0.002  #: the servo cycle of these tests [s]

# CiA 402-2: device control commands (bit 7, 3, 2, 1, 0)
SHUTDOWN, SWITCH_ON, ENABLE = 0x06, 0x07, 0x0F
DISABLE_VOLTAGE, QUICK_STOP, DISABLE_OPERATION, FAULT_RESET = 0x00, 0x02, 0x07, 0x80

# CiA 402-2: (mask, value) of the statusword in each state
STATUSWORD_PATTERN = {
    S.NOT_READY_TO_SWITCH_ON: (0x4F, 0x00),
    S.SWITCH_ON_DISABLED: (0x4F, 0x40),
    S.READY_TO_SWITCH_ON: (0x6F, 0x21),
    S.SWITCHED_ON: (0x6F, 0x23),
    S.OPERATION_ENABLED: (0x6F, 0x27),
    S.QUICK_STOP_ACTIVE: (0x6F, 0x07),
    S.FAULT_REACTION_ACTIVE: (0x4F, 0x0F),
    S.FAULT: (0x4F, 0x08),
}

# CiA 402-2's state machine: transition → (from, controlword, to), for the transitions a
# controlword causes (a second controlword where the standard names two commands)
COMMANDED = [
    (2, S.SWITCH_ON_DISABLED, SHUTDOWN, S.READY_TO_SWITCH_ON),
    (3, S.READY_TO_SWITCH_ON, SWITCH_ON, S.SWITCHED_ON),
    (4, S.SWITCHED_ON, ENABLE, S.OPERATION_ENABLED),
    (5, S.OPERATION_ENABLED, DISABLE_OPERATION, S.SWITCHED_ON),
    (6, S.SWITCHED_ON, SHUTDOWN, S.READY_TO_SWITCH_ON),
    (7, S.READY_TO_SWITCH_ON, DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    (7, S.READY_TO_SWITCH_ON, QUICK_STOP, S.SWITCH_ON_DISABLED),
    (8, S.OPERATION_ENABLED, SHUTDOWN, S.READY_TO_SWITCH_ON),
    (9, S.OPERATION_ENABLED, DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    (10, S.SWITCHED_ON, DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    (10, S.SWITCHED_ON, QUICK_STOP, S.SWITCH_ON_DISABLED),
    (11, S.OPERATION_ENABLED, QUICK_STOP, S.QUICK_STOP_ACTIVE),
    (12, S.QUICK_STOP_ACTIVE, DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),
    (16, S.QUICK_STOP_ACTIVE, ENABLE, S.OPERATION_ENABLED),
]


@pytest.mark.parametrize(("number", "from_state", "controlword", "to_state"), COMMANDED)
def test_each_commanded_transition_follows_the_standards_table(
    number, from_state, controlword, to_state
):
    # quick stop option code 6 (stay in quick stop active) where 16 needs it
    option = 6 if number == 16 else 2
    assert next_state(from_state, controlword, controlword, option) == (to_state, number)
    # bits the command ignores do not change it (the x of the command table), bit 7 clear
    for extra in (0x10, 0x20, 0x40, 0x100):
        assert next_state(from_state, controlword | extra, 0, option) == (to_state, number)


def test_no_command_moves_a_state_it_has_no_transition_for():
    commanded = {(f, cw) for _, f, cw, _ in COMMANDED}
    for state in (S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON, S.SWITCHED_ON,
                  S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE):  # fmt: skip
        for cw in (SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE, QUICK_STOP):
            found = next_state(state, cw, cw, 2)
            # "switch on + enable operation" from ready to switch on is transition 3
            if (state, cw) == (S.READY_TO_SWITCH_ON, ENABLE):
                assert found == (S.SWITCHED_ON, 3)
            elif (state, cw) not in commanded or (state, cw) == (S.QUICK_STOP_ACTIVE, ENABLE):
                assert found is None, (state.name, hex(cw))


def test_enable_operation_from_quick_stop_needs_an_option_code_that_stays_there():
    for option in (1, 2, 3, 4):
        assert next_state(S.QUICK_STOP_ACTIVE, ENABLE, ENABLE, option) is None
    for option in (5, 6, 7, 8):
        assert next_state(S.QUICK_STOP_ACTIVE, ENABLE, ENABLE, option) == (
            S.OPERATION_ENABLED,
            16,
        )


def test_fault_reset_is_the_rising_edge_of_bit_7_and_only_without_the_fault():
    assert next_state(S.FAULT, FAULT_RESET, 0x00, 2) == (S.SWITCH_ON_DISABLED, 15)
    assert next_state(S.FAULT, FAULT_RESET | ENABLE, ENABLE, 2) == (S.SWITCH_ON_DISABLED, 15)
    assert next_state(S.FAULT, FAULT_RESET, FAULT_RESET, 2) is None  # held, not an edge
    assert next_state(S.FAULT, ENABLE, 0x00, 2) is None
    assert next_state(S.FAULT, FAULT_RESET, 0x00, 2, fault_present=True) is None
    # bit 7 set is a fault reset, no other command (the others have bit 7 = 0)
    assert next_state(S.SWITCH_ON_DISABLED, FAULT_RESET | SHUTDOWN, 0, 2) is None


@pytest.mark.parametrize("state", list(DriveState))
def test_the_statusword_shows_each_state_as_table_30_says(state):
    mask, value = STATUSWORD_PATTERN[state]
    word = statusword(state)
    assert word & mask == value
    assert word & (1 << 9), "remote: the controlword on CAN is the drive's command input"
    assert state_of(word) == state
    # the other states' patterns do not match it
    assert [s for s, (m, v) in STATUSWORD_PATTERN.items() if word & m == v] == [state]


# --- one drive walked through every transition ---------------------------------------------
class Bench:
    """A drive on no bus: frames it sends are kept; time steps one servo cycle per step."""

    def __init__(self, **limits: float) -> None:
        self.sent: list[can.Message] = []
        self.drive = Cia402Drive(3, AXIS, DriveLimits(**limits), self.sent.append)
        self.t_s = 0.0
        self.q_rad = 0.25

    def boot(self) -> None:
        self.drive.boot()

    def step(self, controlword: int | None = None, dq_rad_s: float = 0.0, sync: bool = False):
        d = self.drive
        if controlword is not None:
            d.write(0x6040, 0, controlword)
        if sync:
            d.on_sync(self.t_s)
        d.sample(self.q_rad, dq_rad_s, 0.0)
        d.step(self.t_s, self.q_rad, wall_s=self.t_s)
        self.t_s += PERIOD_S
        # the joint follows the reference exactly (the plant's loop is not under test here)
        if (ref := d.reference(self.t_s)) is not None:
            self.q_rad = ref[0]

    def expect(self, state: DriveState, transition: int | None = None) -> None:
        d = self.drive
        assert d.state == state, f"{d.state.name} != {state.name}, taken {d.transitions}"
        if transition is not None:
            assert d.transitions[-1] == transition, d.transitions
        mask, value = STATUSWORD_PATTERN[state]
        word = d.read(0x6041)  # as the host reads it by SDO
        assert word & mask == value, f"statusword 0x{word:04X} in {state.name}"
        assert d.powered == (state in (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE))


def enabled_bench(option: int = 2, mode: int = 8) -> Bench:
    b = Bench()
    b.boot()
    b.drive.write(0x6060, 0, mode)
    b.drive.write(0x605A, 0, option)
    b.step()
    for cw in (SHUTDOWN, SWITCH_ON, ENABLE):
        b.step(cw)
    b.expect(S.OPERATION_ENABLED, 4)
    return b


def test_a_drive_walks_every_transition_from_power_on():
    b = Bench()
    b.boot()
    b.expect(S.NOT_READY_TO_SWITCH_ON, 0)
    b.drive.write(0x6060, 0, 8)
    b.step()
    b.expect(S.SWITCH_ON_DISABLED, 1)
    walk = [
        (SHUTDOWN, S.READY_TO_SWITCH_ON, 2),
        (SWITCH_ON, S.SWITCHED_ON, 3),
        (ENABLE, S.OPERATION_ENABLED, 4),
        (DISABLE_OPERATION, S.SWITCHED_ON, 5),
        (SHUTDOWN, S.READY_TO_SWITCH_ON, 6),
        (DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED, 7),
        (SHUTDOWN, S.READY_TO_SWITCH_ON, 2),
        (QUICK_STOP, S.SWITCH_ON_DISABLED, 7),
        (SHUTDOWN, S.READY_TO_SWITCH_ON, 2),
        (ENABLE, S.SWITCHED_ON, 3),  # switch on + enable operation: 3 ...
        (ENABLE, S.OPERATION_ENABLED, 4),  # ... then 4
        (SHUTDOWN, S.READY_TO_SWITCH_ON, 8),
        (ENABLE, S.SWITCHED_ON, 3),
        (ENABLE, S.OPERATION_ENABLED, 4),
        (DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED, 9),
        (SHUTDOWN, S.READY_TO_SWITCH_ON, 2),
        (SWITCH_ON, S.SWITCHED_ON, 3),
        (DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED, 10),
        (SHUTDOWN, S.READY_TO_SWITCH_ON, 2),
        (SWITCH_ON, S.SWITCHED_ON, 3),
        (QUICK_STOP, S.SWITCH_ON_DISABLED, 10),
    ]
    for controlword, state, transition in walk:
        b.step(controlword)
        b.expect(state, transition)
    b.step(SWITCH_ON)  # from switch on disabled: no transition
    b.expect(S.SWITCH_ON_DISABLED, 10)


def test_quick_stop_with_option_6_stays_and_returns_to_operation_enabled_by_16_or_off_by_12():
    b = enabled_bench(option=6)
    b.step(QUICK_STOP | 0x08)  # quick stop: bit 2 clear, the others as they were
    b.expect(S.QUICK_STOP_ACTIVE, 11)
    for _ in range(300):
        b.step()
    b.expect(S.QUICK_STOP_ACTIVE, 11)  # option 6: stays, holding
    b.step(ENABLE)
    b.expect(S.OPERATION_ENABLED, 16)
    b.step(QUICK_STOP)
    b.expect(S.QUICK_STOP_ACTIVE, 11)
    b.step(DISABLE_VOLTAGE)
    b.expect(S.SWITCH_ON_DISABLED, 12)
    assert not b.drive.power_cut, "the brake closes while the drive holds"


def test_quick_stop_ramps_down_on_0x6085_then_goes_to_switch_on_disabled_with_brakes():
    b = enabled_bench(option=2, mode=9)
    d = b.drive
    increments_per_rad = AXIS.increments_per_rad
    d.on_nmt(bytes([0x01, 3]))  # operational: the SYNC applies the target velocity
    d.write(0x60FF, 0, round(0.5 * increments_per_rad))  # 0.5 rad/s
    d.write(0x6085, 0, round(5.0 * increments_per_rad))  # 5 rad/s²: 0.1 s to stop
    b.step(sync=True)
    assert d.dq_ref_rad_s == pytest.approx(0.5, rel=1e-6)
    b.step(QUICK_STOP)
    b.expect(S.QUICK_STOP_ACTIVE, 11)
    speeds = []
    while d.state == S.QUICK_STOP_ACTIVE and len(speeds) < 200:
        speeds.append(d.dq_ref_rad_s)
        b.step(QUICK_STOP, dq_rad_s=d.dq_ref_rad_s, sync=True)
    # the reference slows at 5 rad/s² (one cycle's worth per step) and the SYNCs' target
    # velocity no longer applies
    steps = [a - b_ for a, b_ in itertools.pairwise(speeds) if b_ > 0]
    assert steps and all(s == pytest.approx(5.0 * PERIOD_S, rel=1e-6) for s in steps)
    assert 0.09 <= len(speeds) * PERIOD_S <= 0.12
    b.expect(S.SWITCH_ON_DISABLED, 12)
    assert d.reference(b.t_s) is None and not d.power_cut


def test_a_following_error_faults_through_13_and_14_and_a_reset_clears_it_by_15():
    b = enabled_bench()
    d = b.drive
    assert d.read(0x6065) == round(0.05 * AXIS.increments_per_rad)
    d.sample(b.q_rad, 0.0, 0.0)
    d.step(b.t_s, b.q_rad + 0.06, wall_s=b.t_s)  # the joint 0.06 rad from the reference
    b.expect(S.FAULT_REACTION_ACTIVE, 13)
    assert d.read(0x603F) == 0x8611 and d.read(0x1001) & 0x01
    assert d.power_cut, "stop category 0: the power is cut at once"
    b.step()
    b.expect(S.FAULT, 14)
    b.step(ENABLE)  # no way out but a fault reset
    b.expect(S.FAULT, 14)
    b.step(FAULT_RESET)
    b.expect(S.SWITCH_ON_DISABLED, 15)
    assert d.read(0x603F) == 0 and d.read(0x1001) == 0
    b.step(FAULT_RESET)  # held: nothing more
    b.expect(S.SWITCH_ON_DISABLED, 15)


def test_the_e_stop_faults_and_a_reset_is_refused_while_the_chain_is_open():
    b = enabled_bench()
    d = b.drive
    d.step(b.t_s, b.q_rad, wall_s=b.t_s, estop=True)
    b.expect(S.FAULT_REACTION_ACTIVE, 13)
    assert d.read(0x603F) == 0x9000 and not d.read(0x6041) & (1 << 4)  # no voltage
    d.step(b.t_s, b.q_rad, wall_s=b.t_s, estop=True)
    b.expect(S.FAULT, 14)
    d.write(0x6040, 0, FAULT_RESET)
    d.step(b.t_s, b.q_rad, wall_s=b.t_s, estop=True)
    b.expect(S.FAULT, 14)
    d.write(0x6040, 0, 0)
    b.step()
    b.step(FAULT_RESET)
    b.expect(S.SWITCH_ON_DISABLED, 15)


@pytest.mark.parametrize("mode", [0, 1, 3, 6, 7, 10, -1])
def test_an_unsupported_mode_is_refused_with_value_range_exceeded(mode):
    b = Bench()
    b.boot()
    with pytest.raises(SdoAbortedError) as err:
        b.drive.write(0x6060, 0, mode)
    assert err.value.code == 0x06090030
    assert b.drive.read(0x6061) == 0  # the display shows no mode accepted
    b.drive.write(0x6060, 0, 9)
    assert b.drive.read(0x6061) == 9


def test_an_unsupported_mode_is_refused_on_the_wire_by_sdo_abort():
    b = Bench()
    b.boot()
    # expedited download of 0x6060:00 = 1 (profile position) to node 3
    request = bytes([0x2F, 0x60, 0x60, 0x00, 0x01, 0, 0, 0])
    b.sent.clear()
    b.drive.on_frame(0x603, request, wall_s=0.0, now_s=0.0, stamp_s=0.0)
    [reply] = b.sent
    assert reply.arbitration_id == 0x583
    assert reply.data[0] == 0x80 and bytes(reply.data[1:4]) == bytes([0x60, 0x60, 0x00])
    assert int.from_bytes(reply.data[4:8], "little") == 0x06090030


def test_enabling_operation_with_no_mode_selected_faults_with_a_parameter_error():
    b = Bench()
    b.boot()
    b.step()
    for cw in (SHUTDOWN, SWITCH_ON, ENABLE):
        b.step(cw)
    b.expect(S.FAULT_REACTION_ACTIVE, 13)
    assert b.drive.read(0x603F) == 0x6320
