"""The ROS 2 bridge's names, tokens and attachment (gateway/ros2.py), against rmw_zenoh's
conventions written out literally here (rmw_zenoh_cpp's liveliness_utils.cpp and
attachment_helpers.cpp, and `ros2 topic info --verbose` on Jazzy for the type hash)."""

from __future__ import annotations

import struct

import pytest

from gateway import ros2
from gateway.errors import ConfigError

#: `ros2 topic info /joint_states --verbose` on ROS 2 Jazzy prints this hash
JAZZY_JOINT_STATE_HASH = "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"


def test_the_joint_state_type_hash_is_the_one_ros_2_jazzy_prints():
    assert ros2.JointStateCdr().type_hash == JAZZY_JOINT_STATE_HASH


def test_data_key_of_joint_states():
    key = ros2.topic_key(0, "/joint_states", "sensor_msgs/msg/JointState", "RIHS01_x")
    assert key == "0/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_x"
    key = ros2.topic_key(7, "/cell1/joint_states", "sensor_msgs/msg/JointState", "RIHS01_x")
    assert key == "7/cell1/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_x"


def test_node_and_publisher_tokens_have_rmw_zenohs_layout():
    node = ros2.node_token(0, "abc", 0, "", "leadthrough")
    assert node == "@ros2_lv/0/abc/0/0/NN/%/%/leadthrough"
    pub = ros2.publisher_token(
        0, "abc", 0, 11, "", "joint_state_publisher", "/joint_states",
        "sensor_msgs/msg/JointState", "RIHS01_a13ee3",
    )  # fmt: skip
    # a token of ROS 2's own joint_state_publisher, as rmw_zenoh declares it
    expect = (
        "@ros2_lv/0/abc/0/11/MP/%/%/joint_state_publisher/%joint_states/"
        "sensor_msgs::msg::dds_::JointState_/RIHS01_a13ee3/::,10:,:,:,,"
    )
    assert pub == expect
    parts = pub.split("/")
    assert len(parts) == 13 and all(parts)  # rmw_zenoh refuses a token with an empty part
    ns = ros2.publisher_token(3, "z", 0, 1, "/cell1", "lt", "/cell1/joint_states", "a/msg/B", "H")
    assert ns.split("/")[7:10] == ["%cell1", "lt", "%cell1%joint_states"]


def test_attachment_is_two_int64_and_a_16_byte_sequence():
    gid = bytes(range(16))
    raw = ros2.attachment(5, 1_700_000_000_123_456_789, gid)
    # zenoh's serializer: little-endian int64s, a sequence as a LEB128 length then its bytes
    assert raw == struct.pack("<qq", 5, 1_700_000_000_123_456_789) + b"\x10" + gid
    with pytest.raises(ValueError, match="16 bytes"):
        ros2.attachment(1, 2, b"short")


def test_config_defaults_and_refusals():
    cfg = ros2.ros2_config_from({}, "cell.toml")
    assert cfg.names(6) == [f"joint_{i}" for i in range(1, 7)]
    assert cfg.topic("joint_states") == "/joint_states"
    named = ros2.ros2_config_from({"ros2": {"joint_names": ["a", "b"]}}, "cell.toml")
    with pytest.raises(ConfigError, match=r"\[ros2\].joint_names: 2 names for an arm of 6"):
        named.names(6)
    bad = [
        ({"domain_id": 300}, "domain_id"),
        ({"namespace": "cell1"}, "namespace"),
        ({"node_name": "9x"}, "node_name"),
        ({"joint_names": ["a", "a"]}, "given twice"),
        ({"joint_names": ["j-1"]}, "not ROS names"),
        ({"rate_hz": -1.0}, "rate_hz"),
        ({"colour": "red"}, "unknown key"),
    ]
    for section, what in bad:
        with pytest.raises(ConfigError, match=what):
            ros2.ros2_config_from({"ros2": section}, "cell.toml")
