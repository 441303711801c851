"""The locked-down bus (``gateway/bus_security.py``) over a real zenoh router: who may join and
who may put what. Each refused case shows the message does not reach a subscriber that an
allowed sender reaches on the same key."""

from __future__ import annotations

import json
import os
import time

import pytest
import zenoh

from gateway import bus_security as sec
from gateway.bus import BusConfig, open_client, open_peer, open_router
from gateway.errors import ConfigError, LinkTimeoutError

SETTLE_S = 0.4


def _write_credentials(path, identities=sec.IDENTITIES):
    return sec.write_credentials(path, identities)


@pytest.fixture
def locked(port, tmp_path):
    creds = _write_credentials(tmp_path / "bus.credentials")
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{port}", credentials_file=str(creds))
    router = open_router(bus)
    yield bus, router
    router.close()


def _receiver(bus, identity, key):
    session = open_peer(bus, identity)
    got: list[bytes] = []
    sub = session.declare_subscriber(key, lambda s: got.append(s.payload.to_bytes()))
    return session, sub, got


def _put_as(bus, identity, key, payload):
    session = open_peer(bus, identity)
    try:
        time.sleep(SETTLE_S)  # the subscription reaches the new session
        session.put(key, payload)
        time.sleep(SETTLE_S)
    finally:
        session.close()


@pytest.mark.parametrize(
    ("key_name", "allowed", "refused"),
    [
        ("joint_command", sec.CONTROL, [sec.OPERATOR, sec.CAN_DRIVER, sec.OBSERVER]),
        ("io_state", sec.MODBUS_DRIVER, [sec.CONTROL, sec.OPERATOR]),
        ("joint_state", sec.CAN_DRIVER, [sec.CONTROL, sec.MODBUS_DRIVER]),
        ("lifecycle", None, [sec.CONTROL, sec.OPERATOR, sec.CAN_DRIVER]),
    ],
)
def test_only_the_owner_of_a_key_can_put_on_it(locked, key_name, allowed, refused):
    bus, router = locked
    key = getattr(bus.keys, key_name)
    session, sub, got = _receiver(bus, sec.CAN_DRIVER, key)
    try:
        for identity in refused:
            _put_as(bus, identity, key, identity.encode())
        if allowed is not None:
            _put_as(bus, allowed, key, allowed.encode())
        else:  # the lifecycle: the gateway's own session (identity "gateway") puts it
            router.put(key, b"gateway")
            time.sleep(SETTLE_S)
        assert got == [(allowed or "gateway").encode()]
    finally:
        sub.undeclare()
        session.close()


def test_a_session_without_or_with_wrong_credentials_cannot_join(locked, tmp_path):
    bus, _ = locked
    wrong = _write_credentials(tmp_path / "wrong.credentials")  # other passwords
    with pytest.raises(LinkTimeoutError, match="refused identity"):
        open_client(
            BusConfig(endpoint=bus.endpoint, credentials_file=str(wrong)), connect_timeout_s=1.0
        )
    with pytest.raises(LinkTimeoutError):
        open_client(BusConfig(endpoint=bus.endpoint), connect_timeout_s=1.0)


def test_only_the_operator_may_query_the_gateway(locked):
    bus, router = locked
    queryable = router.declare_queryable(bus.keys.request, lambda q: q.reply(q.key_expr, b"ok"))
    try:
        answers = {}
        for identity in (sec.OPERATOR, sec.OBSERVER, sec.CONTROL):
            client = open_client(bus, connect_timeout_s=2.0, identity=identity)
            try:
                time.sleep(SETTLE_S)
                replies = client.get(bus.keys.request, payload=b"{}", timeout=1.0)
                answers[identity] = [r.ok.payload.to_bytes() for r in replies if r.ok is not None]
            finally:
                client.close()
        assert answers == {sec.OPERATOR: [b"ok"], sec.OBSERVER: [], sec.CONTROL: []}
    finally:
        queryable.undeclare()


def test_the_access_control_list_denies_by_default_and_names_every_identity():
    acl = sec.access_control(BusConfig().keys)
    assert acl["enabled"] and acl["default_permission"] == "deny"
    assert {s["id"] for s in acl["subjects"]} == set(sec.IDENTITIES)
    ingress_puts = {
        tuple(p["subjects"]): r["key_exprs"]
        for p in acl["policies"]
        for r in acl["rules"]
        if r["id"] in p["rules"] and "put" in r["messages"] and r["flows"] == ["ingress"]
    }
    assert ingress_puts[(sec.CONTROL,)][0] == "lt/cmd/joints"
    # the lifecycle comes from the gateway's session alone
    assert ingress_puts[(sec.GATEWAY,)] == ["lt/gateway/lifecycle"]
    others = [keys for who, keys in ingress_puts.items() if who != (sec.GATEWAY,)]
    assert all("lt/gateway/lifecycle" not in keys for keys in others)
    json.dumps(acl)  # zenoh takes it as JSON


@pytest.mark.parametrize(
    ("content", "mode", "message"),
    [
        ("control:" + "x" * 32 + "\n", 0o644, "readable by the service user only"),
        ("control " + "x" * 32 + "\n", 0o600, ":1: expected 'identity:password'"),
        ("# a comment\n", 0o600, ":1: expected 'identity:password'"),
        ("robot:" + "x" * 32 + "\n", 0o600, "unknown identity 'robot'"),
        ("control:short\n", 0o600, "shorter than 16"),
        ("control:" + "x" * 32 + "\ncontrol:" + "y" * 32 + "\n", 0o600, ":2: identity 'control'"),
    ],
)
def test_a_bad_credentials_file_is_refused_by_name(tmp_path, content, mode, message):
    path = tmp_path / "bus.credentials"
    path.write_text(content)
    os.chmod(path, mode)
    with pytest.raises(ConfigError, match=message):
        sec.read_credentials(path)


def test_a_missing_identity_is_refused_before_any_link(tmp_path, port):
    creds = _write_credentials(tmp_path / "c", identities=(sec.GATEWAY, sec.OPERATOR))
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{port}", credentials_file=str(creds))
    with pytest.raises(ConfigError, match="no line for"):
        open_router(bus)
    cfg = zenoh.Config()
    with pytest.raises(ConfigError, match="no line for identity 'control'"):
        sec.insert_session_credentials(cfg, creds, sec.CONTROL)
