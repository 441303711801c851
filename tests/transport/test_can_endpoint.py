"""SocketcandServerBus against python-can's own socketcand client and raw TCP sockets."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import can
import pytest
from conftest_can import wait_for

from sim_bridge.can_endpoint import SocketcandServerBus


@pytest.fixture
def server() -> Iterator[SocketcandServerBus]:
    bus = SocketcandServerBus(port=0)
    yield bus
    bus.shutdown()


@pytest.fixture
def connect(server: SocketcandServerBus) -> Iterator[callable]:
    clients: list[can.BusABC] = []

    def make(channel: str = "vcan0") -> can.BusABC:
        bus = can.Bus(
            interface="socketcand",
            channel=channel,
            host="127.0.0.1",
            port=server.port,
            tcp_tune=True,
        )
        clients.append(bus)
        return bus

    yield make
    for bus in clients:
        bus.shutdown()


def raw_client(server: SocketcandServerBus) -> socket.socket:
    """A bare TCP client through the handshake, each reply checked as a separate message."""
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=2.0)
    assert sock.recv(256) == b"< hi >"
    sock.sendall(b"< open vcan0 >")
    assert sock.recv(256) == b"< ok >"
    sock.sendall(b"< rawmode >")
    assert sock.recv(256) == b"< ok >"
    return sock


def msg(can_id: int, data: bytes, extended: bool = False) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=extended)


def recv_all(bus: can.BusABC, n: int, timeout_s: float = 2.0) -> list[can.Message]:
    out: list[can.Message] = []
    deadline = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < deadline:
        m = bus.recv(0.05)
        if m is not None:
            out.append(m)
    return out


def test_frames_reach_every_other_node_in_order_and_never_echo(server, connect):
    a, b, c = connect(), connect(), connect()
    assert server.wait_for_clients(3, 2.0)
    frames = [msg(0x201, i.to_bytes(2, "little") + bytes(6)) for i in range(300)]
    for f in frames:
        a.send(f)
    for receiver in (b, c, server):
        got = recv_all(receiver, 300)
        assert [bytes(m.data) for m in got] == [bytes(f.data) for f in frames]
        assert all(m.arbitration_id == 0x201 and not m.is_extended_id for m in got)
    assert a.recv(0.1) is None, "a sender does not receive its own frames"
    server.send(msg(0x181, b"\x01\x02\x03"))
    for receiver in (a, b, c):
        [m] = recv_all(receiver, 1)
        assert (m.arbitration_id, bytes(m.data)) == (0x181, b"\x01\x02\x03")
    assert server.recv(0.1) is None, "the server does not receive its own frames"


def test_extended_ids_and_empty_frames(server, connect):
    a = connect()
    assert server.wait_for_clients(1, 2.0)
    server.send(msg(0x1ABCDEF0, b"", extended=True))
    [m] = recv_all(a, 1)
    assert m.is_extended_id and m.arbitration_id == 0x1ABCDEF0 and m.dlc == 0
    a.send(msg(0x18FF0001, b"\xff" * 8, extended=True))
    m = server.recv(2.0)
    assert m is not None and m.is_extended_id and bytes(m.data) == b"\xff" * 8


def test_handshake_survives_traffic_during_connect(server, connect):
    stop = threading.Event()

    def spam() -> None:
        while not stop.is_set():
            server.send(msg(0x181, bytes(8)))
            time.sleep(0.0005)

    spammer = threading.Thread(target=spam)
    spammer.start()
    try:
        clients = [connect() for _ in range(5)]  # would raise CanError on a merged reply
    finally:
        stop.set()
        spammer.join()
    server.send(msg(0x182, b"\x01"))  # a marker after the spam: every client gets it
    for i, c in enumerate(clients):
        deadline = time.monotonic() + 2.0
        n = 0
        while (m := c.recv(0.5)) is not None and m.arbitration_id != 0x182:
            n += 1
            assert time.monotonic() < deadline
        assert m is not None, f"client {i} got {n} frames and no marker"


def test_malformed_lines_are_dropped_and_the_server_carries_on(server, connect, caplog):
    listener = connect()
    sock = raw_client(server)
    assert server.wait_for_clients(2, 2.0)
    garbage = [
        b"hello",
        b"< send >",
        b"< send 201 9 0 0 0 0 0 0 0 0 0 >",  # 9 bytes
        b"< send ZZZ 1 00 >",
        b"< send 800 1 00 >",  # 11-bit id too big
        b"< send 201 2 00 >",  # fewer bytes than LEN
        b"< send 201 1 1FF >",
        b"< bcmmode >",
        b"<<< >",
        b"< \xff\xfe >",
    ]
    with sock:
        for line in garbage:
            sock.sendall(line)
        sock.sendall(b"< send 123 2 a b >")
        m = server.recv(2.0)
        assert m is not None and (m.arbitration_id, bytes(m.data)) == (0x123, b"\x0a\x0b")
        [forwarded] = recv_all(listener, 1)
        assert forwarded.arbitration_id == 0x123
    assert "malformed" in caplog.text
    assert server.recv(0.05) is None


def test_an_element_split_across_segments_is_reassembled(server):
    with raw_client(server) as sock:
        sock.sendall(b"< send 12")
        time.sleep(0.05)
        sock.sendall(b"3 1 7 >")
        m = server.recv(2.0)
    assert m is not None and (m.arbitration_id, bytes(m.data)) == (0x123, b"\x07")


def test_wrong_channel_is_refused(server, connect):
    with pytest.raises(can.CanError, match="could not open bus"):
        connect(channel="can7")
    wait_for(lambda: server.client_count == 0 and True, what="the refused client gone")
    assert connect().recv(0.05) is None  # the server still serves


def test_disconnects_are_handled(server, connect):
    a = connect()
    sock = raw_client(server)
    assert server.wait_for_clients(2, 2.0)
    sock.sendall(b"< send 12")  # disconnect in the middle of an element
    sock.close()
    wait_for(lambda: server.client_count == 1, what="the raw client dropped")
    server.send(msg(0x181, b"\x05"))
    [m] = recv_all(a, 1)
    assert bytes(m.data) == b"\x05"
    a.shutdown()
    wait_for(lambda: server.client_count == 0, what="the python-can client dropped")
    server.send(msg(0x181, b"\x06"))  # nobody listening: fine


def test_a_client_that_stops_reading_is_dropped_without_blocking_senders(server):
    server.MAX_BACKLOG_BYTES = 64 * 1024
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", server.port))
    with sock:
        assert sock.recv(256) == b"< hi >"
        sock.sendall(b"< open vcan0 >")
        assert sock.recv(256) == b"< ok >"
        sock.sendall(b"< rawmode >")
        assert sock.recv(256) == b"< ok >"
        assert server.wait_for_clients(1, 2.0)
        t0 = time.monotonic()
        frame = msg(0x181, bytes(8))
        for _ in range(120_000):  # ~6 MB: more than the kernel's socket buffers take
            server.send(frame)
        assert time.monotonic() - t0 < 10.0
        wait_for(lambda: server.client_count == 0, what="the stuck client dropped")


def test_frames_it_cannot_carry_are_refused(server):
    with pytest.raises(can.CanOperationError, match="data frames only"):
        server.send(can.Message(arbitration_id=0x181, is_remote_frame=True, dlc=8))
    with pytest.raises(can.CanOperationError, match="data frames only"):
        server.send(can.Message(is_error_frame=True))
    with pytest.raises(can.CanOperationError, match="out of range"):
        server.send(msg(0x800, b""))


def test_shutdown_closes_every_client(connect, server):
    a = connect()
    sock = raw_client(server)
    assert server.wait_for_clients(2, 2.0)
    server.shutdown()
    with sock:
        sock.settimeout(2.0)
        assert sock.recv(256) == b""  # EOF
    assert a.recv(0.1) is None
    with pytest.raises(can.CanOperationError):
        server.send(msg(0x181, b""))
    server.shutdown()  # idempotent


def test_port_in_use_is_an_initialization_error(server):
    with pytest.raises(can.CanInitializationError, match=str(server.port)):
        SocketcandServerBus(port=server.port)
