"""Self-describing recordings (issue 11): every bus message as a JSON object with a JSON Schema.

A recording's channels carry ``message_encoding = "json"`` and a schema of encoding
``jsonschema`` named after the message (``leadthrough.JointState`` ...), so Foxglove, PlotJuggler
or any JSON reader opens and plots it without this project's code (``q_rad[0]`` of
``lt/state/joints`` is joint 1's position). The recorder's monotonic receive time stays inside
each message (``rx_monotonic_ns``); the MCAP log time is wall-clock.

:func:`to_record` turns a bus payload into ``(schema name, JSON bytes)``; :func:`to_payload`
turns it back into the bus payload, byte for byte what the bus carried for a valid message (the
project's readers keep working on the bus's own messages). A payload no decoder accepts (a
publisher's garbage) is kept as ``leadthrough.Undecodable`` with its bytes in base64 and why.

Non-finite numbers, which strict JSON has no literal for, are the strings ``"NaN"``,
``"Infinity"`` and ``"-Infinity"``.
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from gateway.errors import MessageError
from gateway.messages import (
    ControllerState,
    IoState,
    JointCommand,
    JointState,
    Lifecycle,
    PressureSetpoint,
    StateWindow,
)

SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"
PREFIX = "leadthrough."

_NUMBER: dict[str, Any] = {
    "type": ["number", "string"],
    "pattern": "^(NaN|-?Infinity)$",
}
_INT: dict[str, Any] = {"type": "integer"}
_BOOL: dict[str, Any] = {"type": "boolean"}
_STR: dict[str, Any] = {"type": "string"}
_VECTOR: dict[str, Any] = {"type": "array", "items": _NUMBER}
_RX = {"rx_monotonic_ns": {**_INT, "description": "recorder's CLOCK_MONOTONIC at receipt [ns]"}}


def _num(x: float) -> float | str:
    x = float(x)
    if math.isfinite(x):
        return x
    return "NaN" if math.isnan(x) else ("Infinity" if x > 0 else "-Infinity")


def _vec(a: np.ndarray) -> list[float | str]:
    return [_num(x) for x in np.asarray(a, dtype=float).tolist()]


def _arr(v: list[Any]) -> np.ndarray:
    return np.array([float(x) for x in v], dtype=float)


def _schema(title: str, description: str, props: dict[str, Any]) -> dict[str, Any]:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": PREFIX + title,
        "description": description,
        "type": "object",
        "properties": {**props, **_RX},
        "required": sorted(props),
    }


_JOINT_STATE_PROPS: dict[str, Any] = {
    "cycle": _INT,
    "stamp_s": {**_NUMBER, "description": "CAN driver's monotonic time of the cycle [s]"},
    "controller_state": _INT,
    "controller_state_name": _STR,
    "flags": _INT,
    "cycle_period_s": _NUMBER,
    "q_rad": _VECTOR,
    "dq_rad_s": _VECTOR,
    "current_a": _VECTOR,
    "q_cmd_rad": _VECTOR,
    "dq_cmd_rad_s": _VECTOR,
}


def _joint_state_json(s: JointState) -> dict[str, Any]:
    try:
        name = ControllerState(s.controller_state).name
    except ValueError:
        name = str(int(s.controller_state))
    return {
        "cycle": int(s.cycle),
        "stamp_s": _num(s.stamp_s),
        "controller_state": int(s.controller_state),
        "controller_state_name": name,
        "flags": int(s.flags),
        "cycle_period_s": _num(s.cycle_period_s),
        "q_rad": _vec(s.q_rad),
        "dq_rad_s": _vec(s.dq_rad_s),
        "current_a": _vec(s.current_a),
        "q_cmd_rad": _vec(s.q_cmd_rad),
        "dq_cmd_rad_s": _vec(s.dq_cmd_rad_s),
    }


def _joint_state_bytes(o: dict[str, Any]) -> bytes:
    return JointState.pack(
        int(o["cycle"]),
        float(o["stamp_s"]),
        int(o["controller_state"]),
        int(o["flags"]),
        float(o["cycle_period_s"]),
        *(_arr(o[k]).tolist() for k in ("q_rad", "dq_rad_s", "current_a", "q_cmd_rad")),
        _arr(o["dq_cmd_rad_s"]).tolist(),
    )


@dataclass(frozen=True)
class Kind:
    """One message type: its schema, and its payload ↔ JSON object."""

    schema: dict[str, Any]
    to_json: Callable[[bytes], dict[str, Any]]  #: raises MessageError for a bad payload
    to_bytes: Callable[[dict[str, Any]], bytes]


def _window_json(p: bytes) -> dict[str, Any]:
    w = StateWindow.from_bytes(p)
    return {
        "states": int(w.states),
        "max_speed_rad_s": _num(w.max_speed_rad_s),
        "q_lo_rad": _vec(w.q_lo_rad),
        "q_hi_rad": _vec(w.q_hi_rad),
        "newest": _joint_state_json(JointState.from_bytes(w.newest)),
    }


def _window_bytes(o: dict[str, Any]) -> bytes:
    newest = _joint_state_bytes(o["newest"])
    w = StateWindow(
        int(o["states"]), float(o["max_speed_rad_s"]), _arr(o["q_lo_rad"]), _arr(o["q_hi_rad"]),
        newest,
    )  # fmt: skip
    return w.to_bytes()


def _command_json(p: bytes) -> dict[str, Any]:
    c = JointCommand.from_bytes(p)
    return {
        "cycle": int(c.cycle),
        "state_stamp_s": _num(c.state_stamp_s),
        "sent_stamp_s": _num(c.sent_stamp_s),
        "state_rx_stamp_s": _num(c.state_rx_stamp_s),
        "q_cmd_rad": _vec(c.q_cmd_rad),
        "dq_cmd_rad_s": _vec(c.dq_cmd_rad_s),
    }


def _command_bytes(o: dict[str, Any]) -> bytes:
    c = JointCommand(
        int(o["cycle"]), float(o["state_stamp_s"]), float(o["sent_stamp_s"]),
        _arr(o["q_cmd_rad"]), _arr(o["dq_cmd_rad_s"]), float(o["state_rx_stamp_s"]),
    )  # fmt: skip
    return c.to_bytes()


def _io_json(p: bytes) -> dict[str, Any]:
    s = IoState.from_bytes(p)
    return {
        "stamp_s": _num(s.stamp_s),
        "p2_bar": _num(s.p2_bar),
        "p3_bar": _num(s.p3_bar),
        "p2_set_bar": _num(s.p2_set_bar),
        "p3_set_bar": _num(s.p3_set_bar),
        "enabling": bool(s.enabling),
        "estop_ok": bool(s.estop_ok),
        "mark": bool(s.mark),
    }


def _io_bytes(o: dict[str, Any]) -> bytes:
    s = IoState(
        float(o["stamp_s"]), float(o["p2_bar"]), float(o["p3_bar"]), float(o["p2_set_bar"]),
        float(o["p3_set_bar"]), bool(o["enabling"]), bool(o["estop_ok"]), bool(o["mark"]),
    )  # fmt: skip
    return s.to_bytes()


def _setpoint_json(p: bytes) -> dict[str, Any]:
    s = PressureSetpoint.from_bytes(p)
    return {"stamp_s": _num(s.stamp_s), "p2_set_bar": _num(s.p2_set_bar),
            "p3_set_bar": _num(s.p3_set_bar)}  # fmt: skip


def _setpoint_bytes(o: dict[str, Any]) -> bytes:
    s = PressureSetpoint(float(o["stamp_s"]), float(o["p2_set_bar"]), float(o["p3_set_bar"]))
    return s.to_bytes()


def _json_json(p: bytes) -> dict[str, Any]:
    try:
        return {"message": json.loads(p)}
    except (ValueError, UnicodeDecodeError) as exc:
        raise MessageError(f"not JSON: {exc}") from None


def _json_bytes(o: dict[str, Any]) -> bytes:
    return json.dumps(o["message"], separators=(",", ":")).encode()


def _undecodable_json(p: bytes) -> dict[str, Any]:
    return {"payload_base64": base64.b64encode(p).decode("ascii")}


def _undecodable_bytes(o: dict[str, Any]) -> bytes:
    return base64.b64decode(o["payload_base64"])


_VECTOR_COMMAND = {"q_cmd_rad": _VECTOR, "dq_cmd_rad_s": _VECTOR}
KINDS: dict[str, Kind] = {
    "JointState": Kind(
        _schema("JointState", "one controller cycle of joint feedback", _JOINT_STATE_PROPS),
        lambda p: _joint_state_json(JointState.from_bytes(p)),
        _joint_state_bytes,
    ),
    "StateWindow": Kind(
        _schema(
            "StateWindow",
            "a window of controller cycles: count, fastest joint, position bounds, newest",
            {
                "states": _INT,
                "max_speed_rad_s": _NUMBER,
                "q_lo_rad": _VECTOR,
                "q_hi_rad": _VECTOR,
                "newest": {"type": "object", "properties": _JOINT_STATE_PROPS},
            },
        ),
        _window_json,
        _window_bytes,
    ),
    "JointCommand": Kind(
        _schema(
            "JointCommand",
            "position/velocity command computed from one JointState (eq. 21)",
            {
                "cycle": _INT,
                "state_stamp_s": _NUMBER,
                "sent_stamp_s": _NUMBER,
                "state_rx_stamp_s": _NUMBER,
                **_VECTOR_COMMAND,
            },
        ),
        _command_json,
        _command_bytes,
    ),
    "IoState": Kind(
        _schema(
            "IoState",
            "cylinder pressures [bar], valve set-points read back, safety inputs",
            {
                "stamp_s": _NUMBER,
                "p2_bar": _NUMBER,
                "p3_bar": _NUMBER,
                "p2_set_bar": _NUMBER,
                "p3_set_bar": _NUMBER,
                "enabling": _BOOL,
                "estop_ok": _BOOL,
                "mark": _BOOL,
            },
        ),
        _io_json,
        _io_bytes,
    ),
    "PressureSetpoint": Kind(
        _schema(
            "PressureSetpoint",
            "cylinder pressure set-points for the proportional valves [bar]",
            {"stamp_s": _NUMBER, "p2_set_bar": _NUMBER, "p3_set_bar": _NUMBER},
        ),
        _setpoint_json,
        _setpoint_bytes,
    ),
    "Json": Kind(
        _schema(
            "Json",
            "a JSON message of the bus (lifecycle, health, operator requests and replies), "
            "as it was sent, under 'message'",
            {
                "message": {
                    "description": f"lifecycle states: {[s.name.lower() for s in Lifecycle]}"
                }
            },
        ),
        _json_json,
        _json_bytes,
    ),
    "Undecodable": Kind(
        _schema(
            "Undecodable",
            "a payload no decoder of this project accepted, kept as it was sent",
            {"payload_base64": _STR, "error": _STR},
        ),
        _undecodable_json,
        _undecodable_bytes,
    ),
}
_BY_MAGIC = {
    JointState.MAGIC: "JointState",
    StateWindow.MAGIC: "StateWindow",
    JointCommand.MAGIC: "JointCommand",
    IoState.MAGIC: "IoState",
    PressureSetpoint.MAGIC: "PressureSetpoint",
}


def schema_bytes(name: str) -> bytes:
    """The JSON Schema of kind ``name`` (a key of :data:`KINDS`), as MCAP stores it."""
    return json.dumps(KINDS[name].schema, indent=1).encode()


def to_record(payload: bytes, rx_monotonic_ns: int) -> tuple[str, bytes]:
    """(kind name, JSON message bytes) of one bus payload."""
    name = _BY_MAGIC.get(bytes(payload[:4]), "Json")
    try:
        obj = KINDS[name].to_json(payload)
        obj["rx_monotonic_ns"] = int(rx_monotonic_ns)
        return name, json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()
    except (MessageError, ValueError, KeyError, TypeError, RecursionError) as exc:
        obj = {**_undecodable_json(payload), "error": f"{PREFIX}{name}: {exc}"}
        obj["rx_monotonic_ns"] = int(rx_monotonic_ns)
        return "Undecodable", json.dumps(obj, separators=(",", ":")).encode()


def to_payload(name: str, data: bytes) -> bytes:
    """The bus payload of a recorded message of kind ``name``.

    :raises MessageError: the message does not fit its kind.
    """
    kind = KINDS.get(name)
    if kind is None:
        raise MessageError(f"unknown recorded message kind {name!r}")
    try:
        return kind.to_bytes(json.loads(data))
    except (ValueError, KeyError, TypeError) as exc:
        raise MessageError(f"recorded {PREFIX}{name} message unreadable: {exc!r}") from None
