"""LTC-1F, the CAN FD profile (drivers/can/ltc_fd.py, PROTOCOL.md §10): the CRC-16, the
manual's examples and tables, the host adapter's cycles, and the virtual controller speaking it.

The codec itself is checked against cantools, message by message, in test_can_codec.py.
"""

from __future__ import annotations

import math
import re
import uuid
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from drivers.can.adapter import ADAPTER_GROUP, CycleFeedback, HostRequest
from drivers.can.ltc_fd import (
    DEFAULT_FD_DBC_PATH,
    BitRates,
    CommandSetFrame,
    CycleFeedbackFrame,
    LtcFdAdapter,
    LtcFdProtocol,
    classic_frame_bits,
    crc16_ccitt_false,
    cycle_wire_time_s,
    fd_frame_bits,
    frame_crc16,
    host_window_s,
    housekeeping_wire_time_s,
)
from drivers.can.ltc_frames import (
    ControllerStatus,
    FaultCode,
    Heartbeat,
    HostRequestFrame,
    JointCommandFrame,
    NmtState,
)
from drivers.can.ltc_protocol import LtcProtocol
from drivers.registry import load_adapter
from gateway.errors import ConfigError, FrameError
from gateway.messages import ControllerState
from sim_bridge.config import ControllerSpec
from sim_bridge.controller import VirtualController, controller_protocol

MANUAL = Path(__file__).resolve().parents[2] / "drivers" / "can" / "PROTOCOL.md"

Q = np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
DQ = np.array([0.01, 0.02, -0.03, 0.04, -0.05, 0.06])
CUR = np.array([1.0, -2.0, 3.0, -4.0, 5.0, -6.0])
LOWER, UPPER = np.full(6, -3.0), np.full(6, 3.0)


@pytest.fixture(scope="module")
def proto() -> LtcFdProtocol:
    return LtcFdProtocol(n_joints=6)


def status(counter: int = 0x1234, state: ControllerState = ControllerState.EXTERNAL):
    return ControllerStatus(counter, state, FaultCode.NONE, 0, False, True, 2000)


def copy_of(msg: can.Message, **changes: object) -> can.Message:
    fields = dict(
        arbitration_id=msg.arbitration_id,
        is_extended_id=msg.is_extended_id,
        is_fd=msg.is_fd,
        bitrate_switch=msg.bitrate_switch,
        data=bytes(msg.data),
    )
    fields.update(changes)
    return can.Message(**fields)


# --- CRC-16 ---------------------------------------------------------------------------------
def _crc16_bitwise(data: bytes) -> int:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def test_crc16_ccitt_false_check_value():
    assert crc16_ccitt_false(b"123456789") == 0x29B1  # the catalogued check value
    assert crc16_ccitt_false(b"") == 0xFFFF  # init 0xFFFF, xor-out 0


def test_crc16_agrees_with_a_bitwise_reference_and_crccheck():
    rng = np.random.default_rng(16)
    crccheck = pytest.importorskip("crccheck")
    for _ in range(200):
        data = rng.bytes(int(rng.integers(0, 64)))
        assert crc16_ccitt_false(data) == _crc16_bitwise(data)
        assert crc16_ccitt_false(data) == crccheck.crc.Crc16CcittFalse.calc(data)


# --- the manual's examples (§10.3) ----------------------------------------------------------
MANUAL_CMD = bytes.fromhex(
    "34 12 00 00 a0 86 01 3c f6 c0 f2 fc 88 13 00 00" + " 00" * 16 + " 00" * 14 + " cd 04"
)


def test_manual_example_command_set(proto):
    q, dq = [0.1, -0.2, 0, 0, 0, 0], [-0.25, 0.5, 0, 0, 0, 0]
    msg = proto.encode_command_set(0x1234, q, dq, False)
    assert (msg.arbitration_id, msg.is_fd, msg.bitrate_switch, msg.dlc) == (0x200, True, True, 48)
    assert bytes(msg.data) == MANUAL_CMD
    assert _crc16_bitwise(b"\x00\x02" + MANUAL_CMD[:46]) == 0x04CD
    held = bytes(proto.encode_command_set(0x1234, q, dq, True).data)
    assert held[2] == 0x01 and held[46:] == bytes.fromhex("21 43")


def test_manual_example_cycle_feedback(proto):
    q, dq, cur = [0.1, -0.2, 0, 0, 0, 0], [-0.25, 0.5, 0, 0, 0, 0], [1.5, -2.0, 0, 0, 0, 0]
    msg = proto.encode_cycle(status(), q, dq, cur)
    assert (msg.arbitration_id, msg.is_fd, msg.bitrate_switch, msg.dlc) == (0x180, True, True, 64)
    head = "34 12 02 00 00 02 d0 07 a0 86 01 3c f6 96 00 00 c0 f2 fc 88 13 38 ff 00"
    assert bytes(msg.data) == bytes.fromhex(head) + bytes(40)


def test_manual_examples_are_printed_as_the_code_computes_them():
    text = MANUAL.read_text()
    assert "00 00 00 00 00 00 00 00 00 00 00 00 00 00 cd 04     (CRC 0x04CD)" in text
    assert "34 12 00 00 a0 86 01 3c f6 c0 f2 fc 88 13 00 00" in text


# --- the DBC --------------------------------------------------------------------------------
def test_the_fd_dbc_marks_the_cycle_frames_can_fd_and_keeps_the_others_classic():
    db = cantools.database.load_file(str(DEFAULT_FD_DBC_PATH), strict=True)
    layout = {m.name: (m.frame_id, m.length, m.is_fd) for m in db.messages}
    assert layout == {
        "CYCLE_FB": (0x180, 64, True),
        "CYCLE_CMD": (0x200, 48, True),
        "HOST_REQUEST": (0x020, 8, False),
        "HEARTBEAT_CTRL": (0x701, 1, False),
        "HEARTBEAT_HOST": (0x710, 1, False),
    }


def test_requests_and_heartbeats_are_the_classic_frames_in_both_profiles(proto):
    classic = LtcProtocol(6)
    for make in (
        lambda p: p.encode_request(HostRequest.SERVO_ON, 7),
        lambda p: p.encode_heartbeat("HOST", NmtState.OPERATIONAL),
        lambda p: p.encode_heartbeat("CTRL", NmtState.PRE_OPERATIONAL),
    ):
        fd_msg, classic_msg = make(proto), make(classic)
        assert not fd_msg.is_fd and not fd_msg.bitrate_switch
        assert (fd_msg.arbitration_id, bytes(fd_msg.data)) == (
            classic_msg.arbitration_id,
            bytes(classic_msg.data),
        )
    assert proto.decode(proto.encode_request(HostRequest.RESET_FAULT, 255)) == HostRequestFrame(
        HostRequest.RESET_FAULT, 255
    )
    assert proto.decode(proto.encode_heartbeat("CTRL")) == Heartbeat("CTRL", NmtState.OPERATIONAL)


# --- round trips and refusals ---------------------------------------------------------------
@pytest.mark.parametrize(
    ("q", "dq", "cur", "counter"),
    [
        (-8.388608, -3.2768, -327.68, 0),
        (8.388607, 3.2767, 327.67, 65535),
        (0.0, 0.0, 0.0, 0x1234),
    ],
)
def test_cycle_feedback_round_trip_at_the_range_ends(proto, q, dq, cur, counter):
    msg = proto.encode_cycle(status(counter), [q] * 6, [dq] * 6, [cur] * 6)
    frame = proto.decode(msg)
    assert isinstance(frame, CycleFeedbackFrame)
    assert frame.status == status(counter)
    np.testing.assert_allclose(frame.q_rad, [q] * 6, atol=0.5e-6)
    np.testing.assert_allclose(frame.dq_rad_s, [dq] * 6, atol=0.5e-4)
    np.testing.assert_allclose(frame.current_a, [cur] * 6, atol=0.5e-2)
    assert proto.encode(frame).data == msg.data


@pytest.mark.parametrize("counter", [0, 255, 256, 0xABCD, 65535])
@pytest.mark.parametrize("hold", [False, True])
def test_command_set_round_trip_keeps_all_16_counter_bits(proto, counter, hold):
    frame = proto.decode(proto.encode_command_set(counter, Q, DQ, hold))
    assert isinstance(frame, CommandSetFrame)
    assert (frame.counter, frame.hold) == (counter, hold)
    np.testing.assert_allclose(frame.q_cmd_rad, Q, atol=0.5e-6)
    np.testing.assert_allclose(frame.dq_cmd_rad_s, DQ, atol=0.5e-4)
    commands = proto.joint_commands(frame)
    assert [c.joint for c in commands] == [1, 2, 3, 4, 5, 6]
    assert all(c.counter == counter and c.hold == hold for c in commands)


def test_a_smaller_arm_sends_zeros_for_missing_joints_and_ignores_them_on_reception(proto):
    three = LtcFdProtocol(n_joints=3)
    data = bytes(three.encode_command_set(9, Q[:3], DQ[:3], False).data)
    assert data[19:46] == bytes(27)  # joints 4..6 and the unused bytes
    six_joint_set = proto.encode_command_set(9, Q, DQ, False)
    frame = three.decode(six_joint_set)
    assert len(frame.q_cmd_rad) == 3 and len(three.joint_commands(frame)) == 3
    cycle = three.decode(proto.encode_cycle(status(), Q, DQ, CUR))
    np.testing.assert_allclose(cycle.q_rad, Q[:3], atol=0.5e-6)
    with pytest.raises(FrameError, match="CYCLE_CMD positions needs 3 values, got 6"):
        three.encode_command_set(9, Q, DQ, False)


@pytest.mark.parametrize(
    ("call", "signal", "value"),
    [
        (
            lambda p: p.encode_command_set(0, [0, 0, 8.4, 0, 0, 0], DQ, False),
            "position_cmd_j3",
            "8.4",
        ),
        (
            lambda p: p.encode_command_set(0, Q, [0, 0, 0, 0, 0, math.nan], False),
            "velocity_cmd_j6",
            "nan",
        ),
        (lambda p: p.encode_command_set(65536, Q, DQ, False), "counter", "65536"),
        (lambda p: p.encode_cycle(status(), Q, DQ, [0, 400, 0, 0, 0, 0]), "current_j2", "400"),
        (
            lambda p: p.encode_cycle(status()._replace(cycle_period_us=99), Q, DQ, CUR),
            "cycle_period_us",
            "99",
        ),
    ],
)
def test_values_outside_the_range_are_refused_naming_frame_signal_and_value(
    proto, call, signal, value
):
    with pytest.raises(FrameError) as info:
        call(proto)
    text = str(info.value)
    assert text.startswith("CYCLE_") and signal in text and value in text


def test_decode_refuses_a_bad_crc_naming_both_values(proto):
    msg = proto.encode_command_set(5, Q, DQ, False)
    data = bytearray(msg.data)
    data[10] ^= 0x04  # one bit flipped in transit
    with pytest.raises(
        FrameError, match=r"CYCLE_CMD \(0x200\): CRC 0x.... does not match 0x.... .* bytes 0\.\.45"
    ):
        proto.decode(copy_of(msg, data=bytes(data)))


@pytest.mark.parametrize(
    ("changes", "complaint"),
    [
        ({"is_fd": False, "bitrate_switch": False}, "classic CAN frame; LTC-1F sends it as CAN FD"),
        ({"data": bytes(48)}, "DLC 48 with 48 data bytes, expected 64"),
        ({"is_extended_id": True}, "extended 29-bit id 0x00000180"),
    ],
)
def test_decode_refuses_cycle_frames_of_the_wrong_format(proto, changes, complaint):
    msg = proto.encode_cycle(status(), Q, DQ, CUR)
    with pytest.raises(FrameError, match=re.escape(complaint)):
        proto.decode(copy_of(msg, **changes))


def test_decode_refuses_a_request_sent_as_can_fd(proto):
    msg = proto.encode_request(HostRequest.BRAKE, 0)
    with pytest.raises(
        FrameError, match=r"HOST_REQUEST .*CAN FD frame; LTC-1F sends it as classic"
    ):
        proto.decode(copy_of(msg, is_fd=True))


# --- the host adapter -----------------------------------------------------------------------
def test_the_registry_finds_the_fd_adapter_by_name():
    cls = load_adapter(ADAPTER_GROUP, "ltc_fd")
    assert cls is LtcFdAdapter
    adapter = cls(n_joints=6)
    assert (adapter.name, adapter.counter_modulus, adapter.max_joints) == ("ltc_fd", 65536, 6)


def test_one_valid_cycle_frame_is_one_complete_cycle(proto):
    adapter = LtcFdAdapter(6)
    cycle = adapter.feed(proto.encode_cycle(status(0xBEEF), Q, DQ, CUR))
    assert isinstance(cycle, CycleFeedback)
    assert cycle.counter == 0xBEEF
    np.testing.assert_allclose(cycle.q_rad, Q, atol=0.5e-6)
    np.testing.assert_allclose(cycle.dq_rad_s, DQ, atol=0.5e-4)
    np.testing.assert_allclose(cycle.current_a, CUR, atol=0.5e-2)
    assert cycle.controller_state == ControllerState.EXTERNAL
    assert (cycle.servo_power, cycle.estop_active, cycle.fault) == (True, False, "NONE")
    assert cycle.cycle_period_s == pytest.approx(0.002)
    assert adapter.is_cycle_frame(proto.encode_cycle(status(), Q, DQ, CUR))
    assert adapter.stats.cycles == 1 and adapter.stats.bad_frames == 0


def _out_of_range_state(msg: can.Message) -> can.Message:
    data = bytearray(msg.data)
    data[2] = 9  # state 9: no such state
    return copy_of(msg, data=bytes(data))


@pytest.mark.parametrize(
    ("corrupt", "complaint"),
    [
        (lambda m: copy_of(m, data=bytes(m.data[:48])), "DLC 48"),
        (lambda m: copy_of(m, is_fd=False, bitrate_switch=False), "classic CAN frame"),
        (lambda m: copy_of(m, is_extended_id=True), "extended 29-bit id"),
        (
            lambda m: can.Message(arbitration_id=0x180, is_extended_id=False, is_remote_frame=True),
            "remote (RTR) frame",
        ),
        (_out_of_range_state, "state = 9"),
    ],
    ids=["short", "classic", "extended", "remote", "bad_state"],
)
def test_a_bad_cycle_frame_is_counted_and_its_cycle_dropped(proto, corrupt, complaint):
    adapter = LtcFdAdapter(6)
    assert adapter.feed(corrupt(proto.encode_cycle(status(1), Q, DQ, CUR))) is None
    stats = adapter.stats
    assert (stats.bad_frames, stats.corrupt_cycles, stats.cycles) == (1, 1, 0)
    assert "CYCLE_FB (0x180)" in stats.last_error and complaint in stats.last_error
    assert adapter.feed(proto.encode_cycle(status(2), Q, DQ, CUR)).counter == 2  # next is fine


def test_other_frames_neither_make_nor_break_a_cycle(proto):
    adapter = LtcFdAdapter(6)
    bad_crc = bytearray(proto.encode_command_set(1, Q, DQ, False).data)
    bad_crc[47] ^= 0xFF  # another host's set, damaged
    frames = [
        can.Message(arbitration_id=0x555, is_extended_id=False, data=b"\1\2"),
        proto.encode_heartbeat("CTRL"),
        copy_of(proto.encode_command_set(1, Q, DQ, False), data=bytes(bad_crc)),
        proto.encode_cycle(status(3), Q, DQ, CUR),
    ]
    assert [c.counter for c in map(adapter.feed, frames) if c is not None] == [3]
    stats = adapter.stats
    assert (stats.unknown_frames, stats.bad_frames, stats.corrupt_cycles) == (1, 1, 0)
    assert "CYCLE_CMD (0x200): CRC" in stats.last_error


def test_command_frames_are_one_can_fd_frame_with_bit_rate_switch():
    adapter = LtcFdAdapter(6)
    [msg] = adapter.command_frames(0x12AB, Q, DQ, hold=False)
    assert (msg.arbitration_id, msg.is_fd, msg.bitrate_switch) == (0x200, True, True)
    assert (msg.dlc, len(msg.data), msg.is_extended_id) == (48, 48, False)
    frame = adapter.protocol.decode(msg)
    assert (frame.counter, frame.hold) == (0x12AB, False)
    np.testing.assert_allclose(frame.q_cmd_rad, Q, atol=0.5e-6)
    [held] = adapter.command_frames(0x1_0005, Q, np.zeros(6), hold=True)
    frame = adapter.protocol.decode(held)
    assert (frame.counter, frame.hold, frame.dq_cmd_rad_s) == (5, True, (0.0,) * 6)


def test_command_frames_refuse_bad_sets():
    adapter = LtcFdAdapter(6)
    with pytest.raises(FrameError, match="CYCLE_CMD needs 6 positions and velocities, got 5"):
        adapter.command_frames(1, Q[:5], DQ[:5], False)
    q = Q.copy()
    q[2] = np.inf
    with pytest.raises(FrameError, match=r"CYCLE_CMD \(0x200\): position_cmd_j3 = inf rad"):
        adapter.command_frames(1, q, DQ, False)


def test_requests_roll_their_counter_and_the_heartbeat_is_classic():
    adapter = LtcFdAdapter(6)
    counters = [
        adapter.protocol.decode(adapter.request_frames(HostRequest.SERVO_ON)[0]).counter
        for _ in range(257)
    ]
    assert counters[:2] == [0, 1] and counters[255:] == [255, 0]
    beat = adapter.heartbeat_frame()
    assert not beat.is_fd and adapter.protocol.decode(beat) == Heartbeat(
        "HOST", NmtState.OPERATIONAL
    )


# --- the virtual controller on either profile -----------------------------------------------
def make_controller(profile: str, n_joints: int = 6) -> VirtualController:
    # The frames are under test: each set applies at the boundary that accepts it (the
    # command delay has its own tests, test_sim_controller_delay.py).
    spec = ControllerSpec(can_profile=profile, command_delay_cycles=0)
    return VirtualController(spec, controller_protocol(spec, n_joints), LOWER, UPPER)


def servo_on(ctrl: VirtualController) -> None:
    """Heartbeat + SERVO_ON, then one cycle: the controller holds (T1)."""
    ctrl.on_frame(ctrl.proto.encode_heartbeat("HOST"), wall_s=0.0)
    ctrl.on_frame(ctrl.proto.encode_request(HostRequest.SERVO_ON, 0), wall_s=0.0)
    ctrl.begin_cycle(0.0, np.zeros(ctrl.n), wall_s=0.0)
    assert ctrl.state == ControllerState.HOLD


def test_controller_protocol_follows_the_configured_profile():
    assert type(controller_protocol(ControllerSpec(), 6)) is LtcProtocol
    assert type(controller_protocol(ControllerSpec(can_profile="fd"), 4)) is LtcFdProtocol
    with pytest.raises(ConfigError, match=r"\[controller\]\.can_profile: 'fdx' is neither"):
        ControllerSpec(can_profile="fdx")
    with pytest.raises(ConfigError, match=r"can_profile is 'fd' but .* 'classic' protocol"):
        VirtualController(ControllerSpec(can_profile="fd"), LtcProtocol(6), LOWER, UPPER)


@pytest.mark.parametrize(
    ("profile", "ids"),
    [("classic", [0x181, 0x182, 0x183, 0x184, 0x185, 0x186, 0x010]), ("fd", [0x180])],
)
def test_feedback_frames_are_the_profiles_frames_in_sending_order(profile, ids):
    proto = controller_protocol(ControllerSpec(can_profile=profile), 6)
    frames = proto.feedback_frames(status(0x0102), Q, DQ, CUR)
    assert [f.arbitration_id for f in frames] == ids
    assert all(f.is_fd == (profile == "fd") for f in frames)
    host = LtcFdAdapter(6) if profile == "fd" else load_adapter(ADAPTER_GROUP, "ltc_dbc")(6)
    [cycle] = [c for c in map(host.feed, frames) if c is not None]
    assert cycle.counter == 0x0102
    np.testing.assert_allclose(cycle.q_rad, Q, atol=0.5e-6)


@pytest.fixture
def fd_buses():
    """Host and controller ends of one in-process CAN FD segment (python-can ``virtual``)."""
    channel = f"ltc-fd-{uuid.uuid4()}"
    opened = []
    try:
        for _ in range(2):
            opened.append(
                can.Bus(interface="virtual", channel=channel, protocol=can.CanProtocol.CAN_FD)
            )
        yield opened[0], opened[1]
    finally:
        for bus in opened:
            bus.shutdown()


def test_controller_applies_an_fd_command_set_received_over_a_can_fd_bus(fd_buses):
    host_bus, ctrl_bus = fd_buses
    host, ctrl = LtcFdAdapter(6), make_controller("fd")

    def deliver(frames: list[can.Message], sender: can.BusABC, receiver: can.BusABC) -> list:
        for frame in frames:
            sender.send(frame)
        return [receiver.recv(timeout=1.0) for _ in frames]

    for msg in deliver(
        [host.heartbeat_frame(), *host.request_frames(HostRequest.SERVO_ON)], host_bus, ctrl_bus
    ):
        ctrl.on_frame(msg, wall_s=0.0)
    ctrl.begin_cycle(0.0, np.zeros(6), wall_s=0.0)
    assert ctrl.state == ControllerState.HOLD
    [fb] = deliver(ctrl.proto.feedback_frames(ctrl.status(), Q, DQ, CUR), ctrl_bus, host_bus)
    assert fb.is_fd and fb.bitrate_switch
    cycle = host.feed(fb)
    assert cycle is not None and cycle.counter == ctrl.cycle == 1
    [cmd] = deliver(host.command_frames(cycle.counter, Q, DQ, False), host_bus, ctrl_bus)
    ctrl.on_frame(cmd, wall_s=0.001)
    assert ctrl.complete_for_cycle == 1 and ctrl.stats.late_frames == 0
    ctrl.begin_cycle(0.004, Q, wall_s=0.004)
    assert ctrl.state == ControllerState.EXTERNAL and ctrl.stats.command_sets == 1
    q_ref, dq_ref = ctrl.reference(0.004)
    np.testing.assert_allclose(q_ref, Q, atol=0.5e-6)
    np.testing.assert_allclose(dq_ref, DQ, atol=0.5e-4)


def test_controller_ignores_a_late_fd_set_and_rejects_a_corrupt_one():
    ctrl, proto = make_controller("fd"), LtcFdProtocol(6)
    servo_on(ctrl)
    late = proto.encode_command_set((ctrl.cycle - 1) & 0xFFFF, Q, DQ, False)
    ctrl.on_frame(late, wall_s=0.0)
    # a set for 256 cycles ago has the current cycle's low byte: LTC-1F still sees it as late
    ctrl.on_frame(proto.encode_command_set(ctrl.cycle + 256, Q, DQ, False), wall_s=0.0)
    assert ctrl.stats.late_frames == 2 and ctrl.complete_for_cycle is None
    data = bytearray(proto.encode_command_set(ctrl.cycle, Q, DQ, False).data)
    data[5] ^= 0x10
    ctrl.on_frame(copy_of(late, data=bytes(data)), wall_s=0.0)
    classic = copy_of(proto.encode_command_set(ctrl.cycle, Q, DQ, False), is_fd=False)
    ctrl.on_frame(classic, wall_s=0.0)
    assert ctrl.stats.bad_frames == 2 and ctrl.complete_for_cycle is None
    ctrl.begin_cycle(0.004, np.zeros(6), wall_s=0.004)
    assert ctrl.state == ControllerState.HOLD and ctrl.stats.command_sets == 0


def test_classic_controller_still_assembles_a_set_joint_by_joint():
    ctrl, proto = make_controller("classic"), LtcProtocol(6)
    servo_on(ctrl)
    frames = [proto.encode_command(k + 1, Q[k], DQ[k], k == 3, ctrl.cycle & 0xFF) for k in range(6)]
    for frame in frames[:5]:
        ctrl.on_frame(frame, wall_s=0.0)
    assert ctrl.complete_for_cycle is None
    ctrl.on_frame(frames[5], wall_s=0.0)
    assert ctrl.complete_for_cycle == ctrl.cycle and ctrl.complete_hold  # joint 4 asked to hold
    assert isinstance(proto.joint_commands(proto.decode(frames[0]))[0], JointCommandFrame)


# --- wire time (§10.5) ----------------------------------------------------------------------
def test_frame_lengths_follow_the_worst_case_formulas():
    assert classic_frame_bits(8) == 135 and classic_frame_bits(1) == 65
    assert classic_frame_bits(8, worst_case=False) == 111
    assert fd_frame_bits(64) == (34, 678) and fd_frame_bits(48) == (34, 518)
    assert fd_frame_bits(64, worst_case=False) == (30, 549)
    assert fd_frame_bits(8) == (34, 5 + 64 + (85 // 4 - 4) + 4 + 17 + 6)  # CRC-17 to 16 bytes
    with pytest.raises(ConfigError, match="not a CAN FD payload length"):
        fd_frame_bits(56)


def test_cycle_wire_times_are_those_of_the_manual():
    assert cycle_wire_time_s("classic") == pytest.approx(1755e-6)
    assert cycle_wire_time_s("classic", worst_case=False) == pytest.approx(1443e-6)
    assert cycle_wire_time_s("fd") == pytest.approx(307.2e-6)
    assert cycle_wire_time_s("fd", rates=BitRates(1e6, 2e6)) == pytest.approx(666e-6)
    assert housekeeping_wire_time_s() == pytest.approx(265e-6)
    text = MANUAL.read_text()
    assert "| LTC-1 | 1 Mbit/s | 13 (7 + 6, 8 bytes each) | 1755 µs | 1443 µs |" in text
    assert "| LTC-1F | 1 / 5 Mbit/s | 2 | 307.2 µs | 254 µs |" in text


def test_the_manuals_rate_table_is_what_the_functions_compute():
    rows = re.findall(
        r"^\| (\d+ k?Hz) \(.*?\) \| (.*?) \| (.*?) \| (.*?) \|$", MANUAL.read_text(), re.M
    )
    assert [r[0] for r in rows] == ["100 Hz", "250 Hz", "500 Hz", "1 kHz"]
    columns = [("classic", BitRates()), ("fd", BitRates(1e6, 2e6)), ("fd", BitRates(1e6, 5e6))]
    for rate, *cells in rows:
        period_s = 1e-3 if rate == "1 kHz" else 1.0 / int(rate.split()[0])
        for (profile, rates), cell in zip(columns, cells, strict=True):
            window_s = host_window_s(profile, period_s, rates=rates)
            load = (
                cycle_wire_time_s(profile, rates=rates)
                + housekeeping_wire_time_s(rates) * period_s / 0.1
            ) / period_s
            window, load_text = cell.rsplit(", ", 1)
            assert load_text.removeprefix("load ") == f"{round(100 * load)} %"
            if window_s > 0:
                assert window == f"{round(window_s * 1e6)} µs"
            else:
                assert window.startswith("none")
    assert frame_crc16(0x200, MANUAL_CMD[:46]) == 0x04CD
