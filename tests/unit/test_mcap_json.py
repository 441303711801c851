"""gateway/mcap_json.py: every bus message as JSON with a JSON Schema, and back, byte for byte."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from gateway import mcap_json
from gateway.message_factories import make_joint_state
from gateway.messages import (
    ControllerState,
    IoState,
    JointCommand,
    Lifecycle,
    LifecycleMsg,
    PressureSetpoint,
    StateWindow,
    encode_json,
)

RNG = np.random.default_rng(4)


def _state(n: int = 6) -> bytes:
    v = RNG.normal(size=(5, n))
    return make_joint_state(70001, 12.5, ControllerState.EXTERNAL, 6, *v, 0.004).to_bytes()


PAYLOADS = {
    "JointState": _state(),
    "JointState7": _state(7),
    "StateWindow": StateWindow(12, 0.3, -np.ones(6), np.ones(6), _state()).to_bytes(),
    "JointCommand": JointCommand(
        9, 1.5, 1.502, RNG.normal(size=6), RNG.normal(size=6), 1.501
    ).to_bytes(),
    "IoState": IoState(3.25, 6.0, 4.5, 6.1, 4.4, True, False, True).to_bytes(),
    "PressureSetpoint": PressureSetpoint(2.0, 5.5, 3.25).to_bytes(),
    "Json": LifecycleMsg(Lifecycle.TEACHING, 7, 4.0, "enabling device held", {"x": [1]}).to_bytes(),
    "Health": encode_json({"process": "control", "cycles": 10, "nested": {"a": None}}),
}


@pytest.mark.parametrize("name", sorted(PAYLOADS))
def test_every_message_round_trips_byte_for_byte(name):
    payload = PAYLOADS[name]
    kind, data = mcap_json.to_record(payload, 123)
    assert kind != "Undecodable"
    obj = json.loads(data)  # strict JSON: no NaN literals
    assert obj["rx_monotonic_ns"] == 123
    assert mcap_json.to_payload(kind, data) == payload
    schema = json.loads(mcap_json.schema_bytes(kind))
    assert schema["title"] == mcap_json.PREFIX + kind
    assert set(schema["required"]) <= set(obj)


def test_a_joint_state_reads_as_plain_numbers():
    _kind, data = mcap_json.to_record(PAYLOADS["JointState"], 0)
    obj = json.loads(data)
    assert obj["controller_state_name"] == "EXTERNAL" and len(obj["q_rad"]) == 6
    assert all(isinstance(x, float) for x in obj["q_rad"])


@pytest.mark.parametrize(
    "payload",
    [b"garbage that is not a JointState", b"LTJS\x01", b"{not json", b"\xff\xfe", b""],
)
def test_what_no_decoder_accepts_is_kept_as_it_was_sent(payload):
    kind, data = mcap_json.to_record(payload, 5)
    assert kind == "Undecodable"
    obj = json.loads(data)
    assert base64.b64decode(obj["payload_base64"]) == payload and obj["error"]
    assert mcap_json.to_payload(kind, data) == payload


def test_non_finite_numbers_are_strings_and_come_back():
    payload = encode_json({"v": 1.0})
    kind, data = mcap_json.to_record(payload.replace(b"1.0", b"NaN"), 0)
    assert kind == "Undecodable"  # JSON with a NaN literal is not strict JSON
    cmd = JointCommand(1, 1.0, 1.0, np.array([np.inf, 0.0]), np.zeros(2), 1.0)
    kind, data = mcap_json.to_record(cmd.to_bytes(), 0)
    if kind == "JointCommand":  # (if the decoder refuses infinities it is Undecodable)
        assert json.loads(data)["q_cmd_rad"][0] == "Infinity"
    assert mcap_json.to_payload(kind, data) == cmd.to_bytes()


def test_a_record_that_does_not_fit_its_kind_is_a_message_error():
    with pytest.raises(mcap_json.MessageError, match="JointState"):
        mcap_json.to_payload("JointState", b'{"cycle": 1}')
    with pytest.raises(mcap_json.MessageError, match="unknown"):
        mcap_json.to_payload("Nope", b"{}")
