"""LTC-1 codec (drivers/can/ltc_protocol.py, ltc_frames.py) and the LTC adapter's cycle assembly
(drivers/can/ltc.py): pure functions."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest

from drivers.can.adapter import CycleFeedback, HostRequest
from drivers.can.ltc import LtcAdapter
from drivers.can.ltc_frames import (
    ControllerStatus,
    FaultCode,
    Heartbeat,
    HostRequestFrame,
    JointCommandFrame,
    JointFeedback,
    NmtState,
    crc8_sae_j1850,
)
from drivers.can.ltc_protocol import LtcProtocol
from gateway.errors import ConfigError, FrameError
from gateway.messages import ControllerState

Q_MIN, Q_MAX = -8.388608, 8.388607  # rad, s24 × 1e-6
DQ_MIN, DQ_MAX = -3.2768, 3.2767  # rad/s, s16 × 1e-4
I_MIN, I_MAX = -327.68, 327.67  # A, s16 × 0.01


@pytest.fixture(scope="module")
def proto() -> LtcProtocol:
    return LtcProtocol(n_joints=6)


def with_data(msg: can.Message, data: bytes, **changes: object) -> can.Message:
    fields = {
        "arbitration_id": msg.arbitration_id,
        "is_extended_id": msg.is_extended_id,
        "data": data,
        "dlc": len(data),
    }
    fields.update(changes)
    return can.Message(**fields)


# --- CRC ------------------------------------------------------------------------------------
def test_crc8_sae_j1850_check_value():
    assert crc8_sae_j1850(b"123456789") == 0x4B  # the catalogued check value
    assert crc8_sae_j1850(b"") == 0x00  # init 0xFF xor-out 0xFF


def test_crc_agrees_with_crccheck():
    crccheck = pytest.importorskip("crccheck")
    rng = np.random.default_rng(7)
    for _ in range(50):
        data = rng.integers(0, 256, size=9, dtype=np.uint8).tobytes()
        assert crc8_sae_j1850(data) == crccheck.crc.Crc8SaeJ1850.calc(data)


def test_manual_example_frame(proto):
    """The worked example of PROTOCOL.md §4."""
    msg = proto.encode_command(1, 0.1, -0.25, False, 0x2A)
    assert msg.arbitration_id == 0x201 and not msg.is_extended_id
    assert bytes(msg.data) == bytes.fromhex("a086013cf6002a4f")
    request = proto.encode_request(HostRequest.SERVO_ON, 7)
    assert (request.arbitration_id, bytes(request.data)) == (
        0x020,
        bytes.fromhex("01070000000000d2"),
    )


# --- round trips ----------------------------------------------------------------------------
@pytest.mark.parametrize("joint", range(1, 7))
@pytest.mark.parametrize(
    ("q", "dq", "current", "counter"),
    [
        (Q_MIN, DQ_MIN, I_MIN, 0),
        (Q_MAX, DQ_MAX, I_MAX, 255),
        (0.0, 0.0, 0.0, 128),
        (1e-6, -1e-4, 0.01, 1),
    ],
)
def test_feedback_round_trip_at_the_range_ends(proto, joint, q, dq, current, counter):
    msg = proto.encode_feedback(joint, q, dq, current, counter)
    assert msg.arbitration_id == 0x180 + joint and msg.dlc == 8 and not msg.is_extended_id
    fb = proto.decode(msg)
    assert isinstance(fb, JointFeedback)
    assert (fb.joint, fb.counter) == (joint, counter)
    assert fb.q_rad == pytest.approx(q, abs=0.5e-6)
    assert fb.dq_rad_s == pytest.approx(dq, abs=0.5e-4)
    assert fb.current_a == pytest.approx(current, abs=0.5e-2)


@pytest.mark.parametrize("state", list(ControllerState))
@pytest.mark.parametrize("fault", list(FaultCode))
def test_status_round_trip_every_state_and_fault(proto, state, fault):
    status = ControllerStatus(65535, state, fault, 255, True, False, 65535)
    assert proto.decode(proto.encode_status(status)) == status
    low = ControllerStatus(0, state, fault, 0, False, True, 100)
    assert proto.decode(proto.encode_status(low)) == low


@pytest.mark.parametrize("joint", range(1, 7))
@pytest.mark.parametrize(
    ("q", "dq", "hold", "counter"),
    [(Q_MIN, DQ_MIN, True, 0), (Q_MAX, DQ_MAX, False, 255), (-1e-6, 1e-4, True, 77)],
)
def test_command_round_trip_with_crc(proto, joint, q, dq, hold, counter):
    msg = proto.encode_command(joint, q, dq, hold, counter)
    assert msg.arbitration_id == 0x200 + joint
    ids = bytes((msg.arbitration_id & 0xFF, msg.arbitration_id >> 8))
    assert msg.data[7] == crc8_sae_j1850(ids + bytes(msg.data[:7]))
    cmd = proto.decode(msg)
    assert isinstance(cmd, JointCommandFrame)
    assert (cmd.joint, cmd.hold, cmd.counter) == (joint, hold, counter)
    assert cmd.q_cmd_rad == pytest.approx(q, abs=0.5e-6)
    assert cmd.dq_cmd_rad_s == pytest.approx(dq, abs=0.5e-4)


@pytest.mark.parametrize("request_", list(HostRequest))
@pytest.mark.parametrize("counter", [0, 255])
def test_request_round_trip(proto, request_, counter):
    assert proto.decode(proto.encode_request(request_, counter)) == HostRequestFrame(
        request_, counter
    )


@pytest.mark.parametrize("node", ["CTRL", "HOST"])
@pytest.mark.parametrize("nmt", list(NmtState))
def test_heartbeat_round_trip(proto, node, nmt):
    msg = proto.encode_heartbeat(node, nmt)
    assert msg.dlc == 1 and msg.arbitration_id == {"CTRL": 0x701, "HOST": 0x710}[node]
    assert proto.decode(msg) == Heartbeat(node, nmt)


def test_generic_encode_is_the_inverse_of_decode(proto):
    frames = [
        JointFeedback(2, 0.5, -0.25, 1.5, 9),
        ControllerStatus(1234, ControllerState.HOLD, FaultCode.NONE, 3, False, True, 4000),
        JointCommandFrame(6, -0.5, 0.25, False, 9),
        HostRequestFrame(HostRequest.BRAKE, 200),
        Heartbeat("HOST", NmtState.OPERATIONAL),
    ]
    for frame in frames:
        assert proto.decode(proto.encode(frame)) == frame


def test_unknown_ids_decode_to_none(proto):
    assert (
        proto.decode(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\0" * 8))
        is None
    )
    assert (
        proto.decode(can.Message(arbitration_id=0x18FF0001, is_extended_id=True, data=b"")) is None
    )


# --- encode refuses, never clamps -----------------------------------------------------------
@pytest.mark.parametrize(
    ("call", "signal", "value"),
    [
        (lambda p: p.encode_command(1, math.nan, 0.0, False, 0), "position_cmd", "nan"),
        (lambda p: p.encode_command(1, math.inf, 0.0, False, 0), "position_cmd", "inf"),
        (lambda p: p.encode_command(1, 8.3886071, 0.0, False, 0), "position_cmd", "8.3886071"),
        (lambda p: p.encode_command(2, -8.3886081, 0.0, False, 0), "position_cmd", "-8.3886081"),
        (lambda p: p.encode_command(3, 0.0, 3.27671, False, 0), "velocity_cmd", "3.27671"),
        (lambda p: p.encode_command(3, 0.0, -math.inf, False, 0), "velocity_cmd", "-inf"),
        (lambda p: p.encode_command(4, 0.0, 0.0, False, 256), "counter", "256"),
        (lambda p: p.encode_command(4, 0.0, 0.0, False, -1), "counter", "-1"),
        (lambda p: p.encode_feedback(5, 0.0, math.nan, 0.0, 0), "velocity", "nan"),
        (lambda p: p.encode_feedback(5, 0.0, 0.0, 327.675, 0), "current", "327.675"),
        (lambda p: p.encode_feedback(5, 9.0, 0.0, 0.0, 0), "position", "9.0"),
        (lambda p: p.encode_request(HostRequest.BRAKE, 1.5), "counter", "1.5"),
        (lambda p: p.encode_request(3, 0), "request", "3"),
        (lambda p: p.encode_heartbeat("HOST", 3), "nmt_state", "3"),
        (
            lambda p: p.encode_status(
                ControllerStatus(0, ControllerState.HOLD, FaultCode.NONE, 0, False, True, 99)
            ),
            "cycle_period_us",
            "99",
        ),
        (
            lambda p: p.encode_status(ControllerStatus(0, 4, FaultCode.NONE, 0, False, True, 4000)),
            "state",
            "4",
        ),
        (
            lambda p: p.encode_status(
                ControllerStatus(65536, ControllerState.HOLD, FaultCode.NONE, 0, False, True, 4000)
            ),
            "cycle_counter",
            "65536",
        ),
    ],
)
def test_out_of_range_values_are_refused_naming_signal_and_value(proto, call, signal, value):
    with pytest.raises(FrameError) as info:
        call(proto)
    assert signal in str(info.value) and value in str(info.value)


def test_bad_joint_and_node_are_refused(proto):
    with pytest.raises(FrameError, match="joint 7"):
        proto.encode_command(7, 0.0, 0.0, False, 0)
    with pytest.raises(FrameError, match="joint 0"):
        proto.encode_feedback(0, 0.0, 0.0, 0.0, 0)
    with pytest.raises(FrameError, match="'CTRL' or 'HOST'"):
        proto.encode_heartbeat("PLC", NmtState.OPERATIONAL)
    three = LtcProtocol(n_joints=3)
    with pytest.raises(FrameError, match=r"joint 4 outside 1\.\.3"):
        three.encode_command(4, 0.0, 0.0, False, 0)


@pytest.mark.parametrize("n", [0, 7, True])
def test_joint_count_outside_the_dbc_is_a_config_error(n):
    with pytest.raises(ConfigError):
        LtcProtocol(n_joints=n)


# --- decode refuses -------------------------------------------------------------------------
def test_wrong_dlc_is_refused_naming_the_frame(proto):
    msg = proto.encode_feedback(3, 0.1, 0.0, 0.0, 1)
    with pytest.raises(FrameError, match=r"JOINT_FB_J3 \(0x183\): DLC 7 .* expected 8"):
        proto.decode(with_data(msg, bytes(msg.data[:7])))
    hb = proto.encode_heartbeat("CTRL", NmtState.OPERATIONAL)
    with pytest.raises(FrameError, match=r"HEARTBEAT_CTRL .*DLC 2"):
        proto.decode(with_data(hb, bytes(hb.data) + b"\0"))


def test_bad_crc_is_refused(proto):
    msg = proto.encode_command(2, 0.25, 0.0, False, 5)
    data = bytearray(msg.data)
    data[0] ^= 0x01  # one bit flipped in transit
    with pytest.raises(FrameError, match=r"JOINT_CMD_J2 \(0x202\): CRC 0x.. does not match"):
        proto.decode(with_data(msg, bytes(data)))
    data = bytearray(msg.data)
    data[7] ^= 0xFF
    with pytest.raises(FrameError, match="CRC"):
        proto.decode(with_data(msg, bytes(data)))
    # the same payload under another joint's id fails: the id is part of the CRC
    with pytest.raises(FrameError, match="JOINT_CMD_J3"):
        proto.decode(with_data(msg, bytes(msg.data), arbitration_id=0x203))


@pytest.mark.parametrize(
    ("byte", "value", "signal"),
    [(2, 4, "state"), (3, 7, "fault_code")],
)
def test_unknown_status_enum_is_refused(proto, byte, value, signal):
    status = ControllerStatus(1, ControllerState.HOLD, FaultCode.NONE, 0, False, True, 4000)
    data = bytearray(proto.encode_status(status).data)
    data[byte] = value
    msg = can.Message(arbitration_id=0x010, is_extended_id=False, data=bytes(data))
    with pytest.raises(FrameError, match=f"CTRL_STATUS .*{signal} = {value}"):
        proto.decode(msg)


def test_unknown_request_and_nmt_values_are_refused(proto):
    data = bytearray(b"\x03\x00\x00\x00\x00\x00\x00\x00")
    data[7] = crc8_sae_j1850(b"\x20\x00" + bytes(data[:7]))  # valid CRC, bad request
    with pytest.raises(FrameError, match=r"HOST_REQUEST .*request = 3"):
        proto.decode(can.Message(arbitration_id=0x020, is_extended_id=False, data=bytes(data)))
    with pytest.raises(FrameError, match=r"HEARTBEAT_HOST .*nmt_state = 1"):
        proto.decode(can.Message(arbitration_id=0x710, is_extended_id=False, data=b"\x01"))
    with pytest.raises(FrameError, match=r"HEARTBEAT_CTRL .*nmt_state = 200"):
        proto.decode(can.Message(arbitration_id=0x701, is_extended_id=False, data=b"\xc8"))


def test_status_value_outside_the_dbc_range_is_refused(proto):
    status = ControllerStatus(1, ControllerState.HOLD, FaultCode.NONE, 0, False, True, 4000)
    data = bytearray(proto.encode_status(status).data)
    data[6:8] = (50).to_bytes(2, "little")  # cycle_period_us 50 < 100
    with pytest.raises(FrameError, match="cycle_period_us = 50"):
        proto.decode(can.Message(arbitration_id=0x010, is_extended_id=False, data=bytes(data)))


def test_extended_remote_error_and_fd_frames_are_refused(proto):
    msg = proto.encode_feedback(1, 0.0, 0.0, 0.0, 0)
    with pytest.raises(FrameError, match=r"JOINT_FB_J1 .*extended 29-bit id 0x00000181"):
        proto.decode(with_data(msg, bytes(msg.data), is_extended_id=True))
    with pytest.raises(FrameError, match=r"JOINT_FB_J1 .*remote"):
        proto.decode(
            can.Message(arbitration_id=0x181, is_extended_id=False, is_remote_frame=True, dlc=8)
        )
    with pytest.raises(FrameError, match="error frame"):
        proto.decode(can.Message(arbitration_id=0x4, is_error_frame=True, data=b"\0"))
    with pytest.raises(FrameError, match="CAN FD"):
        proto.decode(with_data(msg, bytes(msg.data), is_fd=True))


# --- the adapter: cycle assembly ------------------------------------------------------------
Q = np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
DQ = np.array([0.01, 0.02, -0.03, 0.04, -0.05, 0.06])
CUR = np.array([1.0, -2.0, 3.0, -4.0, 5.0, -6.0])


def cycle_frames(
    proto: LtcProtocol,
    counter: int,
    *,
    skip: int | None = None,
    state: ControllerState = ControllerState.EXTERNAL,
) -> list[can.Message]:
    frames = [
        proto.encode_feedback(k + 1, Q[k], DQ[k], CUR[k], counter & 0xFF)
        for k in range(6)
        if k + 1 != skip
    ]
    status = ControllerStatus(counter, state, FaultCode.NONE, 0, False, True, 4000)
    return [*frames, proto.encode_status(status)]


def feed_all(adapter: LtcAdapter, frames: list[can.Message]) -> list[CycleFeedback]:
    return [c for c in (adapter.feed(f) for f in frames) if c is not None]


def test_a_complete_cycle_is_returned_when_its_status_arrives(proto):
    adapter = LtcAdapter(6)
    frames = cycle_frames(proto, 0x1234)
    assert all(adapter.feed(f) is None for f in frames[:-1])
    cycle = adapter.feed(frames[-1])
    assert isinstance(cycle, CycleFeedback)
    assert cycle.counter == 0x1234
    np.testing.assert_allclose(cycle.q_rad, Q, atol=0.5e-6)
    np.testing.assert_allclose(cycle.dq_rad_s, DQ, atol=0.5e-4)
    np.testing.assert_allclose(cycle.current_a, CUR, atol=0.5e-2)
    assert cycle.controller_state == ControllerState.EXTERNAL
    assert (cycle.servo_power, cycle.estop_active, cycle.fault) == (True, False, "NONE")
    assert cycle.cycle_period_s == pytest.approx(0.004)
    assert adapter.stats.cycles == 1 and adapter.stats.bad_frames == 0


def test_a_missing_joint_frame_drops_the_cycle_and_is_counted(proto):
    adapter = LtcAdapter(6)
    assert feed_all(adapter, cycle_frames(proto, 10, skip=4)) == []
    assert adapter.stats.incomplete_cycles == 1
    assert "joint(s) [4]" in adapter.stats.last_error
    assert len(feed_all(adapter, cycle_frames(proto, 11))) == 1  # the next one is fine


def test_feedback_from_another_cycle_does_not_complete_one(proto):
    adapter = LtcAdapter(6)
    frames = cycle_frames(proto, 20)
    frames[2] = proto.encode_feedback(3, Q[2], DQ[2], CUR[2], 19)  # stale J3 frame
    assert feed_all(adapter, frames) == []
    assert adapter.stats.incomplete_cycles == 1


def test_a_corrupt_frame_drops_its_cycle_and_is_counted(proto):
    adapter = LtcAdapter(6)
    frames = cycle_frames(proto, 30)
    frames[2] = with_data(frames[2], bytes(frames[2].data[:6]))  # J3 with DLC 6
    assert feed_all(adapter, frames) == []
    assert adapter.stats.bad_frames == 1 and adapter.stats.corrupt_cycles == 1
    assert "JOINT_FB_J3" in adapter.stats.last_error
    assert len(feed_all(adapter, cycle_frames(proto, 31))) == 1


def test_a_corrupt_status_frame_loses_the_cycle(proto):
    adapter = LtcAdapter(6)
    frames = cycle_frames(proto, 40)
    frames[-1] = with_data(frames[-1], bytes(frames[-1].data[:5]))
    assert feed_all(adapter, frames) == []
    assert adapter.stats.bad_frames == 1 and adapter.stats.corrupt_cycles == 1
    # the next cycle starts clean
    assert [c.counter for c in feed_all(adapter, cycle_frames(proto, 41))] == [41]


def test_unrelated_frames_neither_help_nor_hurt(proto):
    adapter = LtcAdapter(6)
    foreign = can.Message(arbitration_id=0x555, is_extended_id=False, data=b"\1\2")
    bad_host_frame = with_data(proto.encode_request(HostRequest.BRAKE, 0), b"\0" * 8)  # bad CRC
    frames = cycle_frames(proto, 50)
    frames[3:3] = [foreign, proto.encode_heartbeat("CTRL", NmtState.OPERATIONAL), bad_host_frame]
    assert [c.counter for c in feed_all(adapter, frames)] == [50]
    assert adapter.stats.unknown_frames == 1 and adapter.stats.bad_frames == 1


def test_a_smaller_arm_ignores_extra_joints(proto):
    adapter = LtcAdapter(4)
    [cycle] = feed_all(adapter, cycle_frames(proto, 60))
    np.testing.assert_allclose(cycle.q_rad, Q[:4], atol=0.5e-6)


def test_command_frames_answer_the_cycle_by_its_low_byte():
    adapter = LtcAdapter(6)
    frames = adapter.command_frames(0x12AB, Q, DQ, hold=False)
    decoded = [adapter.protocol.decode(f) for f in frames]
    assert [f.arbitration_id for f in frames] == [0x201 + k for k in range(6)]
    assert all(isinstance(d, JointCommandFrame) and d.counter == 0xAB for d in decoded)
    assert all(not d.hold for d in decoded)
    np.testing.assert_allclose([d.q_cmd_rad for d in decoded], Q, atol=0.5e-6)
    holds = [adapter.protocol.decode(f) for f in adapter.command_frames(7, Q, np.zeros(6), True)]
    assert all(d.hold and d.dq_cmd_rad_s == 0.0 for d in holds)


def test_command_frames_refuse_bad_sets():
    adapter = LtcAdapter(6)
    with pytest.raises(FrameError, match="needs 6"):
        adapter.command_frames(1, Q[:5], DQ[:5], False)
    q = Q.copy()
    q[2] = np.nan
    with pytest.raises(FrameError, match=r"JOINT_CMD_J3.*position_cmd = nan"):
        adapter.command_frames(1, q, DQ, False)


def test_request_counter_rolls_and_heartbeat_is_operational():
    adapter = LtcAdapter(6)
    counters = [
        adapter.protocol.decode(adapter.request_frames(HostRequest.BRAKE)[0]).counter
        for _ in range(258)
    ]
    assert counters[:3] == [0, 1, 2] and counters[255:] == [255, 0, 1]
    assert adapter.protocol.decode(adapter.heartbeat_frame()) == Heartbeat(
        "HOST", NmtState.OPERATIONAL
    )
