"""The operator's side of the gateway's request channel: one command, one JSON reply
(`leadthrough start|stop|status|...`, the replay, the identification run and the test
harness send theirs through it). The gateway answers in gateway/supervisor.py."""

from __future__ import annotations

import json

from gateway.bus import BusConfig, open_client
from gateway.errors import LinkTimeoutError
from gateway.messages import decode_json


def operator_request(bus: BusConfig, command: str, timeout_s: float = 3.0, **fields) -> dict:
    """Send an operator command (plus ``fields``, e.g. ``plan``) and return the JSON reply;
    ``{"ok": False, "message": why}`` when no gateway answers within ``timeout_s`` (connecting
    included)."""
    try:
        session = open_client(bus, connect_timeout_s=timeout_s)
    except LinkTimeoutError as exc:
        return {"ok": False, "message": str(exc)}
    try:
        payload = json.dumps({"command": command, **fields}).encode()
        for reply in session.get(bus.keys.request, payload=payload, timeout=timeout_s):
            if reply.ok is not None:
                return decode_json(reply.ok.payload.to_bytes(), "gateway reply")
        return {
            "ok": False,
            "message": f"no gateway answered on {bus.endpoint} within {timeout_s} s",
        }
    finally:
        session.close()
