import math

import numpy as np
import pytest

from gateway.errors import MessageError
from gateway.message_factories import make_joint_command, make_joint_state
from gateway.messages import (
    ControllerState,
    IoState,
    JointCommand,
    JointState,
    Keys,
    Lifecycle,
    LifecycleMsg,
    PressureSetpoint,
)


def state() -> JointState:
    r = np.arange(6) * 0.1
    return make_joint_state(
        7, 12.5, ControllerState.EXTERNAL, 2, r, -r, r * 3, r + 0.001, r * 0, 0.004
    )


def test_joint_state_round_trip():
    st = state()
    back = JointState.from_bytes(st.to_bytes())
    assert back.cycle == 7 and back.controller_state == ControllerState.EXTERNAL
    assert back.cycle_period_s == 0.004
    np.testing.assert_array_equal(back.current_a, st.current_a)


def test_joint_state_rejects_nan_naming_the_field():
    data = bytearray(state().to_bytes())
    head = JointState._HEAD.size
    data[head + 8 * 6 + 8 * 2 : head + 8 * 6 + 8 * 3] = np.float64(math.nan).tobytes()
    with pytest.raises(MessageError, match=r"dq_rad_s\[2\]"):
        JointState.from_bytes(bytes(data))


@pytest.mark.parametrize(
    "mangle, match",
    [
        (lambda b: b[:-1], "expected"),
        (lambda b: b"XXXX" + b[4:], "magic"),
        (lambda b: b[:4] + bytes([9]) + b[5:], "version"),
        (lambda b: b[:3], "shorter"),
    ],
)
def test_joint_state_rejects_garbage(mangle, match):
    with pytest.raises(MessageError, match=match):
        JointState.from_bytes(mangle(state().to_bytes()))


def test_joint_command_round_trip_and_nan_refused_at_build():
    cmd = make_joint_command(3, 1.0, 1.001, np.zeros(6), np.ones(6))
    assert JointCommand.from_bytes(cmd.to_bytes()).dq_cmd_rad_s[5] == 1.0
    with pytest.raises(MessageError, match="q_cmd_rad"):
        make_joint_command(3, 1.0, 1.0, [0, 0, math.nan, 0, 0, 0], np.zeros(6))
    with pytest.raises(MessageError, match="expected 6"):
        make_joint_command(3, 1.0, 1.0, np.zeros(6), np.zeros(5))


def test_io_and_setpoint_round_trip_and_validation():
    io = IoState(1.0, 6.0, 4.0, 6.0, 4.0, True, True)
    assert IoState.from_bytes(io.to_bytes()) == io
    bad = IoState(1.0, math.nan, 4.0, 6.0, 4.0, True, True).to_bytes()
    with pytest.raises(MessageError, match="finite"):
        IoState.from_bytes(bad)
    sp = PressureSetpoint(2.0, 5.5, 3.5)
    assert PressureSetpoint.from_bytes(sp.to_bytes()) == sp
    marked = IoState(1.0, 6.0, 4.0, 6.0, 4.0, True, True, mark=True)
    assert IoState.from_bytes(marked.to_bytes()).mark
    # a recording from before the mark button: read as not pressed
    assert IoState.from_bytes(marked.to_bytes()[:-1]) == io
    with pytest.raises(MessageError, match="mark=2"):
        IoState.from_bytes(marked.to_bytes()[:-1] + b"\x02")


def test_lifecycle_json_round_trip_and_rejects_nan_literals():
    msg = LifecycleMsg(Lifecycle.TEACHING, 4, 10.0, "enabling held")
    back = LifecycleMsg.from_bytes(msg.to_bytes())
    assert back.state == Lifecycle.TEACHING and back.seq == 4
    with pytest.raises(MessageError, match="non-finite"):
        LifecycleMsg.from_bytes(b'{"state":"ready","seq":1,"stamp_s":NaN}')
    with pytest.raises(MessageError, match="state"):
        LifecycleMsg.from_bytes(b'{"state":"flying","seq":1,"stamp_s":1}')


def test_keys_refuse_wildcards():
    with pytest.raises(MessageError):
        Keys("lt/*")
    assert Keys("cell7").joint_state == "cell7/state/joints"


def test_joint_command_pack_equals_the_dataclass_encoding_and_refuses_nan():
    q, dq = [0.1, -0.2, 0.3], [0.01, 0.0, -0.5]
    ref = JointCommand(9, 1.5, 1.6, np.array(q), np.array(dq), 1.55).to_bytes()
    assert JointCommand.pack(9, 1.5, 1.6, q, dq, 1.55) == ref
    assert JointCommand.from_bytes(ref).state_rx_stamp_s == 1.55
    with pytest.raises(MessageError, match=r"dq_cmd_rad_s\[1\] is nan"):
        JointCommand.pack(9, 1.5, 1.6, q, [0.0, float("nan"), 0.0])
    with pytest.raises(MessageError, match="stamps"):
        JointCommand.pack(9, float("inf"), 1.6, q, dq)


def test_joint_state_pack_equals_the_dataclass_encoding():
    rng = np.random.default_rng(3)
    q, dq, i, qc, dqc = rng.normal(size=(5, 6))
    ref = JointState(70001, 12.5, ControllerState.EXTERNAL, 6, q, dq, i, qc, dqc, 0.004)
    fast = JointState.pack(70001, 12.5, 2, 6, 0.004, *(v.tolist() for v in (q, dq, i, qc, dqc)))
    assert fast == ref.to_bytes()
