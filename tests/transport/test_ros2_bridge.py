"""`leadthrough ros2` (gateway/ros2.py) between the cell's bus and a second zenoh router standing
for a ROS 2 system's rmw_zenohd: what a ROS 2 node would see there, decoded with an independent
CDR implementation (mcap-ros2-support's dynamic decoder, from the message definitions written
out here) and rmw_zenoh's key, token and attachment layouts spelled out literally."""

from __future__ import annotations

import math
import struct
import time

import numpy as np
import pytest
import zenoh
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

from gateway.bus import BusConfig, open_client, open_router
from gateway.errors import LinkTimeoutError
from gateway.message_factories import make_joint_command, make_joint_state
from gateway.messages import ControllerState
from gateway.ros2 import Ros2Bridge, Ros2Config
from sim_bridge.harness import free_port

KEY = (
    "0/joint_states/sensor_msgs::msg::dds_::JointState_/"
    "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
)
COMMAND_KEY = KEY.replace("0/joint_states/", "0/joint_commands/")
#: sensor_msgs/msg/JointState as a ROS 2 bag's MCAP stores it (ros2msg, dependencies appended)
JOINT_STATE_MSG = """std_msgs/Header header
string[] name
float64[] position
float64[] velocity
float64[] effort
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


@pytest.fixture
def ros_router():
    """A second router: the ROS 2 system's network."""
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{free_port()}")
    session = open_router(bus)
    yield bus
    session.close()


def _decoder():
    schema = Schema(id=1, name="sensor_msgs/msg/JointState", encoding="ros2msg",
                    data=JOINT_STATE_MSG.encode())  # fmt: skip
    return DecoderFactory().decoder_for("cdr", schema)


def test_a_ros_2_node_sees_joint_states_and_commands(router, ros_router):
    cfg = Ros2Config(endpoint=ros_router.endpoint, rate_hz=0.0, joint_names=tuple("abcdef"))
    bridge = Ros2Bridge(router, cfg)
    ros = open_client(ros_router)
    cell = open_client(router)
    got: list[tuple[str, bytes, bytes]] = []

    def on_sample(s: zenoh.Sample) -> None:
        att = s.attachment.to_bytes() if s.attachment is not None else b""
        got.append((str(s.key_expr), s.payload.to_bytes(), att))

    subs = [ros.declare_subscriber(k, on_sample) for k in (KEY, COMMAND_KEY)]
    try:
        bridge.start()
        time.sleep(0.5)  # subscriptions propagate through both routers
        tokens = [str(r.ok.key_expr) for r in ros.liveliness().get("@ros2_lv/0/**", timeout=2.0)]
        zid = tokens[0].split("/")[2]
        assert f"@ros2_lv/0/{zid}/0/0/NN/%/%/leadthrough" in tokens
        mp = [t for t in tokens if "/MP/" in t and "%joint_states" in t]
        assert len(mp) == 1
        assert mp[0].endswith(
            "/MP/%/%/leadthrough/%joint_states/sensor_msgs::msg::dds_::JointState_/"
            + KEY.rsplit("/", 1)[1]
            + "/::,10:,:,:,,"
        )
        rng = np.random.default_rng(3)
        sent = []
        for cycle in range(1, 6):
            q, dq = rng.uniform(-2, 2, 6), rng.uniform(-1, 1, 6)
            st = make_joint_state(cycle, time.monotonic(), ControllerState.EXTERNAL, 2, q, dq,
                                  np.ones(6), q, dq * 0, 0.008)  # fmt: skip
            cell.put(router.keys.joint_state, st.to_bytes())
            cmd = make_joint_command(cycle, st.stamp_s, time.monotonic(), q + 0.01, dq)
            cell.put(router.keys.joint_command, cmd.to_bytes())
            sent.append((q, dq))
            time.sleep(0.02)
        cell.put(router.keys.joint_state, b"LTJS garbage")  # refused, not bridged
        # the garbage is refused after the ten sane messages were bridged: wait for both (on a
        # loaded machine the ten had arrived and the refusal was not yet counted)
        deadline = time.monotonic() + 5.0
        while (len(got) < 10 or bridge.counts.refused < 1) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        for s in subs:
            s.undeclare()
        cell.close()
        ros.close()
        bridge.stop()
    states = [g for g in got if g[0] == KEY]
    commands = [g for g in got if g[0] == COMMAND_KEY]
    assert len(states) == 5 and len(commands) == 5
    decode = _decoder()
    now_s = time.time()
    for k, (_, payload, att) in enumerate(states):
        msg = decode(payload)
        q, dq = sent[k]
        assert list(msg.name) == list("abcdef")
        np.testing.assert_array_equal(msg.position, q)
        np.testing.assert_array_equal(msg.velocity, dq)
        assert len(msg.effort) == 0
        stamp_s = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        assert abs(stamp_s - now_s) < 30.0  # wall clock, not monotonic
        seq, source_ns = struct.unpack_from("<qq", att)
        assert seq == k + 1 and abs(source_ns * 1e-9 - now_s) < 30.0
        assert att[16] == 16 and len(att) == 33  # the 16-byte GID as a sequence
    np.testing.assert_array_equal(decode(commands[0][1]).position, sent[0][0] + 0.01)
    assert states[0][2][17:] != commands[0][2][17:]  # one GID per publisher
    c = bridge.counts
    assert c.published == {"/joint_states": 5, "/joint_commands": 5} and c.refused == 1


def test_the_rate_limit_and_a_missing_ros_router(router, ros_router):
    bridge = Ros2Bridge(router, Ros2Config(endpoint=ros_router.endpoint, rate_hz=5.0,
                                           commands=False))  # fmt: skip
    cell = open_client(router)
    try:
        bridge.start()
        time.sleep(0.3)
        t_end = time.monotonic() + 1.0
        sent: list[float] = []
        while time.monotonic() < t_end:
            sent.append(time.monotonic())
            st = make_joint_state(len(sent), sent[-1], ControllerState.EXTERNAL, 2,
                                  np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6),
                                  np.zeros(6), 0.008)  # fmt: skip
            cell.put(router.keys.joint_state, st.to_bytes())
            time.sleep(0.008)  # ~120 states in the second on an idle machine
    finally:
        cell.close()
        bridge.stop()
        elapsed_s = time.monotonic() - sent[0] if sent else 0.0
    published = bridge.counts.published["/joint_states"]
    # 5 Hz: at most one per 0.2 s of the time states could come in, the first opening it
    assert published <= math.floor(5.0 * elapsed_s) + 1, (published, elapsed_s)
    # and one per 0.2 s in which states came in: the limiter's rule run on the send times (a
    # sender starved on a loaded machine sent few, each of them due), one less for a state
    # that arrived late enough to shift a window
    due, last = 0, -math.inf
    for t in sent:
        if t - last >= 0.2:
            due, last = due + 1, t
    assert published >= due - 1, (published, due, len(sent))
    dead = Ros2Bridge(router, Ros2Config(endpoint=f"tcp/127.0.0.1:{free_port()}"), 0.5)
    with pytest.raises(LinkTimeoutError, match=r"ROS 2 system at \[ros2\].endpoint"):
        dead.start()
