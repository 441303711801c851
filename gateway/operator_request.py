"""The operator's side of the gateway's request channel: one command, one JSON reply
(`leadthrough start|stop|status|...`, the replay, the identification run and the test
harness send theirs through it). The gateway answers in gateway/operator_answers.py.

:func:`operator_request` opens a session for one command (a CLI's single request);
:class:`OperatorClient` keeps one for a tool that polls (the replay and identification runs
waiting on the status, the test harness): opening a zenoh session costs the tool and the
gateway (the router) a handshake and threads, and a status poll every 0.1 s through fresh
sessions took a fifth of `make demo`'s observer process and a share of the gateway's CPU,
which a slow cell PC does not have to spare (issue 45)."""

from __future__ import annotations

import json
import threading
from typing import Any

from gateway.bus import BusConfig, open_client
from gateway.errors import LinkTimeoutError
from gateway.messages import decode_json


def _no_answer(bus: BusConfig, timeout_s: float) -> dict:
    return {"ok": False, "message": f"no gateway answered on {bus.endpoint} within {timeout_s} s"}


def _send(
    session: Any, bus: BusConfig, command: str, timeout_s: float, fields: dict
) -> dict | None:
    """The gateway's reply to ``command`` over ``session``, None when none came."""
    payload = json.dumps({"command": command, **fields}).encode()
    for reply in session.get(bus.keys.request, payload=payload, timeout=timeout_s):
        if reply.ok is not None:
            return decode_json(reply.ok.payload.to_bytes(), "gateway reply")
    return None


def operator_request(bus: BusConfig, command: str, timeout_s: float = 3.0, **fields) -> dict:
    """Send an operator command (plus ``fields``, e.g. ``plan``) and return the JSON reply;
    ``{"ok": False, "message": why}`` when no gateway answers within ``timeout_s`` (connecting
    included)."""
    try:
        session = open_client(bus, connect_timeout_s=timeout_s)
    except LinkTimeoutError as exc:
        return {"ok": False, "message": str(exc)}
    try:
        reply = _send(session, bus, command, timeout_s, fields)
        return _no_answer(bus, timeout_s) if reply is None else reply
    finally:
        session.close()


class OperatorClient:
    """Operator commands over one kept session (module docstring); the same replies as
    :func:`operator_request`. A command no gateway answers drops the session, and the next
    command opens a new one (a restarted gateway is a new router). Thread-safe; close it
    when done (also as a context manager)."""

    def __init__(self, bus: BusConfig) -> None:
        self.bus = bus
        self._session: Any = None
        self._lock = threading.Lock()

    def request(self, command: str, timeout_s: float = 3.0, **fields: Any) -> dict:
        with self._lock:
            if self._session is None:
                try:
                    self._session = open_client(self.bus, connect_timeout_s=timeout_s)
                except LinkTimeoutError as exc:
                    return {"ok": False, "message": str(exc)}
            try:
                reply = _send(self._session, self.bus, command, timeout_s, fields)
            except BaseException:
                self._drop()
                raise
            if reply is None:
                self._drop()
                return _no_answer(self.bus, timeout_s)
            return reply

    def _drop(self) -> None:
        session, self._session = self._session, None
        if session is not None:
            session.close()

    def close(self) -> None:
        with self._lock:
            self._drop()

    def __enter__(self) -> OperatorClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
