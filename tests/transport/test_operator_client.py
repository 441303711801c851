"""An operator session kept across commands (gateway/operator_request.OperatorClient): the
replies of a fresh session per command, one session for all of them, and a gateway that went
away answered as "no gateway" once, its successor reached by the next command."""

from __future__ import annotations

import json

from gateway.bus import BusConfig, open_router
from gateway.operator_request import OperatorClient, operator_request


def _gateway(bus: BusConfig, seen: list[str]):
    """A router answering each request with its command and how many it has seen."""
    session = open_router(bus)

    def answer(query) -> None:
        command = json.loads(query.payload.to_bytes())["command"]
        seen.append(command)
        reply = {"ok": True, "message": command, "seen": len(seen)}
        query.reply(query.key_expr, json.dumps(reply).encode())

    queryable = session.declare_queryable(bus.keys.request, answer)
    return session, queryable


def test_commands_over_one_kept_session_get_the_replies_a_fresh_session_gets(port):
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{port}")
    seen: list[str] = []
    session, queryable = _gateway(bus, seen)
    try:
        assert operator_request(bus, "status", 2.0)["message"] == "status"
        with OperatorClient(bus) as client:
            first = client.request("status", 2.0)
            kept = client._session
            replies = [client.request("start", 2.0, plan={"x": 1}) for _ in range(5)]
            assert client._session is kept  # one session for every command
        assert first == {"ok": True, "message": "status", "seen": 2}
        assert [r["seen"] for r in replies] == [3, 4, 5, 6, 7]
        assert client._session is None  # closed with the block
    finally:
        queryable.undeclare()
        session.close()


def test_a_gateway_gone_is_no_answer_and_its_successor_answers_the_next_command(port):
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{port}")
    seen: list[str] = []
    session, queryable = _gateway(bus, seen)
    with OperatorClient(bus) as client:
        try:
            assert client.request("status", 2.0)["ok"] is True
        finally:
            queryable.undeclare()
            session.close()
        gone = client.request("status", 1.0)
        assert gone["ok"] is False and "no gateway" in gone["message"]
        assert client._session is None  # dropped: the next command opens a new one
        session, queryable = _gateway(bus, seen)
        try:
            assert client.request("stop", 5.0) == {"ok": True, "message": "stop", "seen": 2}
        finally:
            queryable.undeclare()
            session.close()
