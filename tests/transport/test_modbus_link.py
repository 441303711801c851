"""ModbusLink against the virtual I/O module and against misbehaving raw TCP peers."""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator

import pytest

from drivers.modbus.client import ModbusLink, ModbusLinkError, ModbusTimeoutError
from gateway.errors import LinkTimeoutError, ModbusReplyError
from sim_bridge.modbus_server import VirtualIoServer


@pytest.fixture
def server() -> Iterator[VirtualIoServer]:
    srv = VirtualIoServer("127.0.0.1", 0, device_id=1, p2_set_bar=1.5, p3_set_bar=2.0)
    srv.start()
    try:
        yield srv
    finally:
        srv.stop()


@pytest.fixture
def link(server: VirtualIoServer) -> Iterator[ModbusLink]:
    lk = ModbusLink("127.0.0.1", server.port, device_id=1, timeout_s=0.2)
    lk.connect()
    try:
        yield lk
    finally:
        lk.close()


def test_protocol_address_0_is_the_first_value_of_each_table(server, link):
    server.set_inputs(1.5, 3.25, True, False)
    assert link.read_input_registers(0, 3) == [0x3FC0, 0x0000, 3250]
    assert link.read_input_registers(2, 1) == [3250]
    # holding registers: int32 mbar, low word first; initial 1.5 bar and 2.0 bar
    assert link.read_holding_registers(0, 4) == [1500, 0, 2000, 0]
    assert link.read_discrete_inputs(0, 2) == [True, False]
    assert link.read_discrete_inputs(1, 1) == [False]
    assert link.read_coils(0, 1) == [False]


def test_written_setpoints_are_decoded_by_the_module(server, link):
    link.write_registers(0, [4200, 0, 0xFFFF, 0xFFFF])  # 4.2 bar, -1 mbar
    assert server.setpoints() == (4.2, -0.001)
    link.write_registers(2, [5125, 0])  # a partial write keeps the other set-point
    assert server.setpoints() == (4.2, 5.125)
    assert link.read_holding_registers(0, 4) == [4200, 0, 5125, 0]
    link.write_coil(0, True)
    assert link.read_coils(0, 1) == [True]


def test_unmapped_address_is_an_exception_response(link):
    with pytest.raises(
        ModbusReplyError,
        match=r"read_input_registers\(address=2, count=5\).*2 \(ILLEGAL DATA ADDRESS\)",
    ) as err:
        link.read_input_registers(2, 5)
    assert not isinstance(err.value, ModbusLinkError)
    assert link.connected  # an exception response leaves the link usable
    assert link.read_input_registers(0, 1) is not None


def test_other_device_id_is_refused(server):
    # The refusal is what is tested, not how soon it comes: pymodbus answers an unknown device
    # from its broad exception handler (logging a formatted traceback), and on a loaded 2-core
    # machine that once took longer than 0.2 s (make test: "no reply within 0.2 s"). A server
    # that never answers still fails here, with "no reply within 2 s".
    with (
        ModbusLink("127.0.0.1", server.port, device_id=7, timeout_s=2.0) as other,
        pytest.raises(ModbusReplyError, match="exception response 4"),
    ):
        other.read_input_registers(0, 1)


def test_not_connected_and_refused_raise_link_errors(server):
    lk = ModbusLink("127.0.0.1", server.port, timeout_s=0.2)
    with pytest.raises(ModbusLinkError, match="not connected"):
        lk.read_coils(0, 1)
    port = server.port
    server.stop()
    with pytest.raises(ModbusLinkError, match="connect failed"):
        lk.connect()
    lk.close()
    assert port


def test_dropped_connection_raises_link_error_and_closes(server, link):
    server.stop()
    with pytest.raises(ModbusLinkError, match=r"read_holding_registers\(address=0, count=4\)"):
        link.read_holding_registers(0, 4)
    assert not link.connected


def test_bad_arguments_are_refused_before_sending(link):
    with pytest.raises(ValueError, match=r"count must be 1\.\.125"):
        link.read_input_registers(0, 126)
    with pytest.raises(ValueError, match="16-bit"):
        link.write_registers(0, [70000])


# Misbehaving peers -------------------------------------------------------------------------


class RawPeer:
    """A TCP peer that answers each Modbus request with ``reply(request_bytes)`` (or nothing)."""

    def __init__(self, reply: Callable[[bytes], bytes | None]) -> None:
        self._reply = reply
        self._sock = socket.create_server(("127.0.0.1", 0))
        self._sock.settimeout(0.05)
        self.port = self._sock.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="raw-modbus-peer")
        self._thread.start()

    def _run(self) -> None:
        conns: list[socket.socket] = []
        try:
            while not self._stop.is_set():
                try:
                    conn, _ = self._sock.accept()
                except TimeoutError:
                    continue
                conns.append(conn)
                conn.settimeout(0.05)
                while not self._stop.is_set():
                    try:
                        request = conn.recv(260)
                    except TimeoutError:
                        continue
                    if not request:
                        break
                    answer = self._reply(request)
                    if answer:
                        conn.sendall(answer)
        finally:
            for c in conns:
                c.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._sock.close()


def _mbap_reply(request: bytes, pdu: bytes) -> bytes:
    tid, proto, _len, unit = struct.unpack(">HHHB", request[:7])
    return struct.pack(">HHHB", tid, proto, len(pdu) + 1, unit) + pdu


def test_short_reply_raises_naming_function_address_count_and_reply():
    # asked for 3 registers, the peer sends 2
    peer = RawPeer(lambda req: _mbap_reply(req, bytes([4, 4, 0x12, 0x34, 0x56, 0x78])))
    expected = (
        r"read_input_registers\(address=0, count=3\): reply holds 2 registers \[4660, 22136\]"
    )
    try:
        with (
            ModbusLink("127.0.0.1", peer.port, timeout_s=0.2) as lk,
            pytest.raises(ModbusReplyError, match=expected),
        ):
            lk.read_input_registers(0, 3)
    finally:
        peer.close()


def test_silent_peer_times_out():
    peer = RawPeer(lambda req: None)
    try:
        with ModbusLink("127.0.0.1", peer.port, timeout_s=0.1) as lk:
            t0 = time.monotonic()
            with pytest.raises(
                ModbusTimeoutError, match=r"read_coils\(address=3, count=2\): no reply"
            ) as err:
                lk.read_coils(3, 2)
            assert time.monotonic() - t0 < 1.0
            assert isinstance(err.value, LinkTimeoutError)
            assert isinstance(err.value, ModbusReplyError)
            assert not lk.connected  # a late reply must not be taken for the next request
    finally:
        peer.close()
