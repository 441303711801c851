"""The seqpacket CAN transport: SeqpacketBus (client, a python-can interface) and
SeqpacketHubBus (the virtual controller's segment), on real Unix sockets in-process.

Timing assertions are one-sided and generous (a loaded CI machine only makes things slower),
except where a minimum over many tries is the property (sub-millisecond timeouts).
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import socket
import stat
import struct
import threading
import time
from collections.abc import Callable, Iterator
from importlib.metadata import entry_points

import can
import pytest
from conftest_can import wait_for

from drivers.can.config import CanDriverConfig
from drivers.can.seqpacket import (
    CAN_FRAME,
    CANFD_FRAME,
    CANFD_LENGTHS,
    SeqpacketBus,
    socket_address,
)
from gateway.errors import ConfigError
from sim_bridge.can_endpoint import SocketcandServerBus
from sim_bridge.can_hub import SeqpacketHubBus
from sim_bridge.config import load_sim_config
from sim_bridge.harness import unique_can_address
from sim_bridge.sim import VirtualCell, open_can_endpoint

BURST_FRAMES = 100_000
#: Generous bound for anything that should take milliseconds, on a loaded machine [s].
SLOW_S = 5.0


@pytest.fixture
def address() -> str:
    return unique_can_address()


@pytest.fixture
def buses() -> Iterator[list[can.BusABC]]:
    """Every bus a test opens goes here and is shut down after it, failures included."""
    opened: list[can.BusABC] = []
    yield opened
    for bus in reversed(opened):
        bus.shutdown()


@pytest.fixture
def hub(address: str, buses: list[can.BusABC]) -> Callable[..., SeqpacketHubBus]:
    def make(**kwargs: object) -> SeqpacketHubBus:
        bus = SeqpacketHubBus(address, **kwargs)
        buses.append(bus)
        return bus

    return make


@pytest.fixture
def client(address: str, buses: list[can.BusABC]) -> Callable[..., can.BusABC]:
    def make(**kwargs: object) -> can.BusABC:
        kwargs.setdefault("connect_timeout_s", 2.0)
        bus = can.Bus(interface="seqpacket", channel=address, **kwargs)
        buses.append(bus)
        return bus

    return make


def numbered(i: int, can_id: int = 0x201) -> can.Message:
    return can.Message(arbitration_id=can_id, is_extended_id=False, data=struct.pack("<Q", i))


def number(msg: can.Message) -> int:
    return struct.unpack("<Q", msg.data)[0]


def same(m: can.Message, s: can.Message) -> bool:
    return m.equals(s, timestamp_delta=None, check_channel=False, check_direction=False)


def recv_n(bus: can.BusABC, n: int, timeout_s: float = SLOW_S) -> list[can.Message]:
    out: list[can.Message] = []
    deadline = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < deadline:
        if (m := bus.recv(0.05)) is not None:
            out.append(m)
    return out


class HubService:
    """Services a hub from a thread (its owner's loop, in a test); counts what it receives."""

    def __init__(self, hub: SeqpacketHubBus) -> None:
        self.hub = hub
        self.received: list[can.Message] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hub-service")

    def _run(self) -> None:
        while not self._stop.is_set():
            if (m := self.hub.recv(0.01)) is not None:
                self.received.append(m)

    def __enter__(self) -> HubService:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


# --- python-can integration -------------------------------------------------------------------
def test_the_interface_resolves_through_python_cans_entry_point(hub, client):
    [ep] = [e for e in entry_points(group="can.interface") if e.name == "seqpacket"]
    assert ep.value == "drivers.can.seqpacket:SeqpacketBus"
    assert "seqpacket" in can.interfaces.VALID_INTERFACES
    hub()
    bus = client()
    assert isinstance(bus, SeqpacketBus)
    assert bus.protocol == can.CanProtocol.CAN_20
    assert bus.fileno() >= 0


def test_no_server_is_an_initialization_error_naming_the_address(address):
    t0 = time.monotonic()
    with pytest.raises(can.CanInitializationError, match=address) as err:
        can.Bus(interface="seqpacket", channel=address, connect_timeout_s=0.3)
    elapsed = time.monotonic() - t0
    assert 0.3 <= elapsed < 0.3 + SLOW_S
    assert "virtual controller" in str(err.value)


def test_a_client_waits_for_a_server_that_comes_up(address, buses):
    def start_later() -> None:
        time.sleep(0.2)
        buses.append(SeqpacketHubBus(address))

    starter = threading.Thread(target=start_later)
    starter.start()
    try:
        bus = can.Bus(interface="seqpacket", channel=address, connect_timeout_s=SLOW_S)
        buses.append(bus)
    finally:
        starter.join()
    assert isinstance(bus, SeqpacketBus)


def test_an_address_too_long_for_a_unix_socket_is_refused():
    with pytest.raises(can.CanInitializationError, match="at most 107"):
        SeqpacketHubBus("/tmp/" + "x" * 200)


# --- semantics of one CAN segment -------------------------------------------------------------
def test_frames_reach_every_other_node_and_never_their_sender(hub, client):
    h = hub()
    a, b, c = client(), client(), client()
    assert h.wait_for_clients(3, SLOW_S)
    a.send(numbered(7))
    for receiver in (h, b, c):  # the hub forwards as its owner services it: h.recv first
        [m] = recv_n(receiver, 1)
        assert (m.arbitration_id, number(m), m.is_rx) == (0x201, 7, True)
    assert a.recv(0.05) is None, "a sender does not receive its own frames"
    h.send(numbered(8, 0x181))
    for receiver in (a, b, c):
        [m] = recv_n(receiver, 1)
        assert (m.arbitration_id, number(m)) == (0x181, 8)
    assert h.recv(0.05) is None, "the hub does not receive its own frames"


def test_drain_returns_every_waiting_frame_in_order_through_the_filters(hub, client):
    h = hub(can_filters=[{"can_id": 0x201, "can_mask": 0x7FF}])
    a, b = client(), client()
    assert h.wait_for_clients(2, SLOW_S)
    assert h.drain() == []
    for i in range(20):
        a.send(numbered(i, 0x201 if i % 2 == 0 else 0x181))
    got: list[can.Message] = []
    deadline = time.monotonic() + SLOW_S
    while len(got) < 10 and time.monotonic() < deadline:
        select.select([h.fileno()], [], [], 0.05)
        got += h.drain()
    assert [number(m) for m in got] == list(range(0, 20, 2))  # 0x181 filtered out
    assert len(recv_n(b, 20)) == 20, "draining still forwards every frame to the others"
    h.shutdown()
    with pytest.raises(can.CanOperationError, match="shut down"):
        h.drain()


def test_a_frame_read_late_carries_the_kernels_arrival_stamp(hub, client):
    h = hub()
    a = client()
    assert h.wait_for_clients(1, SLOW_S)
    assert not h.forwards, "one client: nobody to forward to"
    before = time.time()
    a.send(numbered(1, 0x201))
    sent = time.time()
    time.sleep(0.05)  # the owner's loop reads it a cycle or more later
    got: list[can.Message] = []
    deadline = time.monotonic() + SLOW_S
    while not got and time.monotonic() < deadline:
        select.select([h.fileno()], [], [], 0.05)
        got += h.drain()
    assert len(got) == 1
    assert before - 1e-3 <= got[0].timestamp <= sent + 1e-3, "stamped on arrival, not on read"
    client()
    assert h.wait_for_clients(2, SLOW_S)
    assert h.forwards, "two clients: each one's frames must reach the other"


def test_ids_and_flags_keep_their_meaning(hub, client):
    h = hub()
    a = client()
    assert h.wait_for_clients(1, SLOW_S)
    sent = [
        can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b""),
        can.Message(arbitration_id=0x1ABCDEF0, is_extended_id=True, data=b"\xff" * 8),
        can.Message(arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=5),
        can.Message(arbitration_id=0x18FF00AA, is_extended_id=True, is_remote_frame=True, dlc=0),
        # an error frame: the "id" is the error class (here: controller problems, bus-off)
        can.Message(arbitration_id=0x44, is_extended_id=False, is_error_frame=True, data=bytes(8)),
        can.Message(arbitration_id=0x100, is_extended_id=False, data=bytes(8), dlc=15),
    ]
    for msg in sent:
        a.send(msg)
    got = recv_n(h, len(sent))
    for m, s in zip(got, sent, strict=True):
        assert same(m, s), (m, s)
    for msg in sent:
        h.send(msg)
    for m, s in zip(recv_n(a, len(sent)), sent, strict=True):
        assert same(m, s), (m, s)


@pytest.mark.parametrize("brs, esi", [(False, False), (True, False), (False, True), (True, True)])
def test_fd_frames_of_every_length_round_trip_with_their_flags(hub, client, brs, esi):
    h = hub(fd=True)
    a = client(fd=True)
    assert a.protocol == can.CanProtocol.CAN_FD
    assert h.wait_for_clients(1, SLOW_S)
    sent = [
        can.Message(
            arbitration_id=0x1F0 + k,
            is_extended_id=bool(k % 2),
            is_fd=True,
            bitrate_switch=brs,
            error_state_indicator=esi,
            data=bytes((k + i) & 0xFF for i in range(size)),
        )
        for k, size in enumerate(CANFD_LENGTHS)
    ]
    for msg in sent:
        a.send(msg)
        h.send(msg)
    for receiver in (h, a):
        got = recv_n(receiver, len(sent))
        for m, s in zip(got, sent, strict=True):
            assert m.is_fd and m.dlc == len(s.data) == len(m.data)
            assert same(m, s), (m, s)


def test_an_fd_payload_between_lengths_is_padded_to_the_next_one(hub, client):
    h = hub(fd=True)
    a = client(fd=True)
    assert h.wait_for_clients(1, SLOW_S)
    a.send(can.Message(arbitration_id=0x10, is_extended_id=False, is_fd=True, data=b"\x01" * 13))
    [m] = recv_n(h, 1)
    assert bytes(m.data) == b"\x01" * 13 + bytes(3) and m.dlc == 16


def test_a_classic_bus_ignores_fd_frames_and_refuses_to_send_them(hub, client):
    h = hub(fd=True)
    fd_node, classic_node = client(fd=True), client()
    assert h.wait_for_clients(2, SLOW_S)
    fd_node.send(can.Message(arbitration_id=0x10, is_fd=True, data=bytes(12)))
    fd_node.send(numbered(1))
    assert [m.is_fd for m in recv_n(h, 2)] == [True, False]
    [m] = recv_n(classic_node, 1)
    assert number(m) == 1 and not m.is_fd
    assert classic_node.ignored_fd_frames == 1
    with pytest.raises(can.CanOperationError, match="fd=True"):
        classic_node.send(can.Message(arbitration_id=0x10, is_fd=True, data=bytes(12)))


def test_frames_no_can_bus_could_carry_are_refused(hub, client):
    hub()
    a = client(fd=True)
    for bad, why in [
        (can.Message(arbitration_id=0x800, is_extended_id=False), "out of range"),
        (can.Message(arbitration_id=0x20000000, is_extended_id=True), "out of range"),
        (can.Message(arbitration_id=0x1, is_extended_id=False, data=bytes(9)), "at most 8"),
        (can.Message(arbitration_id=0x1, is_fd=True, data=bytes(65)), "at most 64"),
        (can.Message(arbitration_id=0x1, is_fd=True, is_remote_frame=True), "no remote"),
    ]:
        with pytest.raises(can.CanOperationError, match=why):
            a.send(bad)


# --- lossless and in order ---------------------------------------------------------------------
def test_a_burst_from_a_client_reaches_the_hub_lossless_and_in_order(hub, client):
    h = hub()
    a = client()
    assert h.wait_for_clients(1, SLOW_S)

    def send_all() -> None:
        for i in range(BURST_FRAMES):
            a.send(numbered(i), timeout=SLOW_S)

    sender = threading.Thread(target=send_all)
    sender.start()
    try:
        got = [number(m) for m in recv_n(h, BURST_FRAMES, timeout_s=120.0)]
    finally:
        sender.join()
    assert got == list(range(BURST_FRAMES))


def test_a_burst_from_the_hub_reaches_a_client_lossless_and_in_order(hub, client):
    h = hub(max_backlog_frames=BURST_FRAMES)  # the reader thread may fall far behind (GIL)
    a = client()
    assert h.wait_for_clients(1, SLOW_S)
    got: list[int] = []
    reader = threading.Thread(target=lambda: got.extend(map(number, recv_n(a, BURST_FRAMES, 120))))
    reader.start()
    try:
        for i in range(BURST_FRAMES):
            h.send(numbered(i))
            if i % 256 == 0:
                h.recv(0.0)  # the owner's loop services the hub now and then
        deadline = time.monotonic() + 120.0
        while reader.is_alive() and time.monotonic() < deadline:
            h.recv(0.01)  # flush the backlog as the reader makes room
    finally:
        reader.join()
    assert got == list(range(BURST_FRAMES))


def test_a_burst_between_clients_through_the_hub_is_lossless_and_in_order(hub, client):
    h = hub(max_backlog_frames=BURST_FRAMES)
    a, b = client(), client()
    assert h.wait_for_clients(2, SLOW_S)

    def send_all() -> None:
        for i in range(BURST_FRAMES):
            a.send(numbered(i), timeout=SLOW_S)

    with HubService(h) as service:
        sender = threading.Thread(target=send_all)
        sender.start()
        try:
            got = [number(m) for m in recv_n(b, BURST_FRAMES, timeout_s=120.0)]
        finally:
            sender.join()
        wait_for(lambda: len(service.received) == BURST_FRAMES, 60.0, "the hub's own copies")
    assert got == list(range(BURST_FRAMES))
    assert [number(m) for m in service.received] == got


# --- robustness --------------------------------------------------------------------------------
def raw_client(address: str) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    sock.connect(socket_address(address))
    return sock


MALFORMED = [
    b"\x00" * 10,  # neither size
    CAN_FRAME.pack(0x201, 9, 0, 0, 0, bytes(8)),  # classic len 9
    CANFD_FRAME.pack(0x201, 13, 0x04, 0, 0, bytes(64)),  # not an FD length
    CANFD_FRAME.pack(0x201, 65, 0x04, 0, 0, bytes(64)),  # FD len > 64
    CANFD_FRAME.pack(0x201, 8, 0x84, 0, 0, bytes(64)),  # unknown FD flag
    CANFD_FRAME.pack(0x40000201, 8, 0x04, 0, 0, bytes(64)),  # remote FD frame
    CAN_FRAME.pack(0x800, 1, 0, 0, 0, bytes(8)),  # standard id > 0x7FF
    b"\x00" * 200,  # too long
]


def test_malformed_datagrams_to_the_hub_are_dropped_counted_and_logged_once(
    hub, client, address, caplog
):
    h = hub(fd=True)
    listener = client(fd=True)
    caplog.set_level(logging.WARNING, logger="drivers.can.seqpacket")
    with raw_client(address) as sock:
        assert h.wait_for_clients(2, SLOW_S)
        for datagram in MALFORMED:
            sock.send(datagram)
        sock.send(CAN_FRAME.pack(0x123, 2, 0, 0, 0, b"\x0a\x0b"))
        [m] = recv_n(h, 1)
    assert (m.arbitration_id, bytes(m.data)) == (0x123, b"\x0a\x0b")
    assert h.malformed_frames == len(MALFORMED)
    [forwarded] = recv_n(listener, 1)
    assert forwarded.arbitration_id == 0x123, "malformed datagrams are not forwarded"
    warnings = [r for r in caplog.records if "malformed" in r.getMessage()]
    assert len(warnings) == 1 and "neither" in warnings[0].getMessage()


def test_malformed_datagrams_to_a_client_are_dropped_and_counted(address, buses):
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    with listener:
        listener.bind(socket_address(address))
        listener.listen(1)
        bus = can.Bus(interface="seqpacket", channel=address, fd=True, connect_timeout_s=1.0)
        buses.append(bus)
        server, _ = listener.accept()
        with server:
            for datagram in MALFORMED:
                server.send(datagram)
            server.send(CAN_FRAME.pack(0x321, 1, 0, 0, 0, b"\x05"))
            m = bus.recv(SLOW_S)
            assert m is not None and (m.arbitration_id, bytes(m.data)) == (0x321, b"\x05")
            assert bus.malformed_frames == len(MALFORMED)
        with pytest.raises(can.CanOperationError, match="closed"):
            bus.recv(SLOW_S)


def test_a_client_that_stops_reading_is_dropped_without_blocking_the_hub(hub, client, address):
    h = hub(max_backlog_frames=1000)
    good = client()
    with raw_client(address) as stuck:
        assert h.wait_for_clients(2, SLOW_S)
        t0 = time.monotonic()
        got: list[int] = []
        for chunk in range(50):
            for i in range(chunk * 100, chunk * 100 + 100):
                h.send(numbered(i))
            got += [number(m) for m in recv_n(good, 100)]
        assert time.monotonic() - t0 < 10 * SLOW_S
        assert h.client_count == 1 and h.dropped_clients == 1
        stuck.settimeout(SLOW_S)
        while stuck.recv(100):  # what was queued for it, then end of file: the hub closed it
            pass
    assert got == list(range(5000)), "the reader that keeps up loses nothing"


def test_frames_a_client_sent_before_it_went_reach_the_hub_even_if_a_send_finds_it_gone(
    hub, client
):
    """A host that sends BRAKE and exits at once: the hub's next send finds its socket closed
    before the hub read what it sent. On a CAN bus those frames were on the wire: they arrive
    (the virtual controller once lost such a BRAKE and ran into its command timeout)."""
    h = hub()
    leaving, staying = client(), client()
    assert h.wait_for_clients(2, SLOW_S)
    for i in range(7):
        leaving.send(numbered(i))
    leaving.shutdown()
    h.send(numbered(99, 0x181))  # finds it gone: dropped, what it sent read first
    assert [number(m) for m in recv_n(h, 7)] == list(range(7))
    assert [number(m) for m in recv_n(staying, 8)] == [*range(7), 99]
    assert h.client_count == 1


def test_send_waits_at_most_its_timeout_when_nobody_reads(hub, client):
    hub()  # never serviced: its kernel buffer fills
    a = client()
    t0 = time.monotonic()
    with pytest.raises(can.CanOperationError, match="transmit buffer full"):
        for i in range(100_000):
            a.send(numbered(i), timeout=0.05)
    assert time.monotonic() - t0 < 10 * SLOW_S


def test_a_client_sees_the_hub_going_away(hub, client):
    h = hub()
    a = client()
    assert h.wait_for_clients(1, SLOW_S)
    h.shutdown()
    with pytest.raises(can.CanOperationError):
        a.recv(SLOW_S)


# --- timeouts and readiness ---------------------------------------------------------------------
@pytest.mark.parametrize("side", ["client", "hub"])
def test_sub_millisecond_receive_timeouts_are_honoured(hub, client, side):
    h = hub()
    a = client()
    bus = a if side == "client" else h
    timeout_s = 0.0002
    elapsed = []
    for _ in range(50):
        t0 = time.perf_counter()
        assert bus.recv(timeout_s) is None
        elapsed.append(time.perf_counter() - t0)
    assert min(elapsed) >= timeout_s, "never returns before its timeout"
    # A timeout rounded to whole milliseconds (epoll, poll, settimeout) never returns below 1 ms;
    # load can only make some tries slower, so the fastest one shows the resolution.
    assert min(elapsed) < 0.001, f"fastest of 50 recv({timeout_s}) took {min(elapsed):.6f} s"


def test_the_hubs_fileno_turns_readable_when_a_client_has_sent(hub, client):
    h = hub()
    a = client()
    assert h.wait_for_clients(1, SLOW_S)
    assert h.recv(0.0) is None
    a.send(numbered(3))
    wait_for(lambda: _readable(h.fileno()), SLOW_S, "the hub's descriptor readable")
    assert number(h.recv(0.0)) == 3


def _readable(fd: int) -> bool:
    return bool(select.select([fd], [], [], 0.0)[0])


# --- addresses ---------------------------------------------------------------------------------
def test_a_filesystem_socket_is_private_and_removed_on_shutdown(tmp_path, buses):
    path = str(tmp_path / "can.sock")
    h = SeqpacketHubBus(path, mode=0o660)
    buses.append(h)
    assert stat.S_ISSOCK(os.stat(path).st_mode)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o660
    a = can.Bus(interface="seqpacket", channel=path, connect_timeout_s=1.0)
    buses.append(a)
    assert h.wait_for_clients(1, SLOW_S)
    h.shutdown()
    assert not os.path.exists(path)


def test_an_address_in_use_by_a_live_server_is_refused(tmp_path, hub, address, buses):
    hub()
    with pytest.raises(can.CanInitializationError, match="in use by a running server"):
        SeqpacketHubBus(address)
    path = str(tmp_path / "can.sock")
    buses.append(SeqpacketHubBus(path))
    with pytest.raises(can.CanInitializationError, match="in use by a running server"):
        SeqpacketHubBus(path)


def test_a_stale_socket_file_is_replaced_and_a_regular_file_is_not(tmp_path, buses):
    stale = str(tmp_path / "stale.sock")
    with socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET) as dead:
        dead.bind(stale)  # closed without unlinking: a server that crashed
    h = SeqpacketHubBus(stale)
    buses.append(h)
    assert stat.S_IMODE(os.stat(stale).st_mode) == 0o600
    regular = tmp_path / "notes.txt"
    regular.write_text("keep me")
    with pytest.raises(can.CanInitializationError, match="not a socket"):
        SeqpacketHubBus(str(regular))
    assert regular.read_text() == "keep me"


# --- the cell config ---------------------------------------------------------------------------
def test_the_cell_config_checks_a_seqpacket_transport():
    ok = {"interface": "seqpacket", "channel": "@leadthrough-vcan0", "fd": True}
    assert CanDriverConfig(transport=ok).transport["fd"] is True
    for bad, field in [
        ({**ok, "port": 29536}, "not \\['port'\\]"),
        ({**ok, "channel": "@"}, "transport.channel"),
        ({**ok, "channel": "/" + "x" * 120}, "at most 107"),
        ({**ok, "fd": "yes"}, "transport.fd"),
        ({**ok, "connect_timeout_s": -1}, "connect_timeout_s"),
    ]:
        with pytest.raises(ConfigError, match=field):
            CanDriverConfig(transport=bad)


# --- the virtual controller on its segment -----------------------------------------------------
def test_the_virtual_controller_serves_its_segment_where_its_config_says(
    address, port, buses, caplog
):
    cfg = load_sim_config(
        None,
        {
            "controller": {"cycle_period_s": 0.004},
            "endpoints": {"can_channel": address, "modbus_port": port},
            "scheduling": {"cpu_affinity": [4095]},  # no such CPU: refused with a warning
        },
    )
    cell = VirtualCell(cfg)
    cell.open()
    got: list[can.Message] = []

    def read_until_closed(host: can.BusABC) -> None:
        with contextlib.suppress(can.CanOperationError):  # the hub's close ends it
            while (m := host.recv(SLOW_S)) is not None:
                got.append(m)

    reader: threading.Thread | None = None
    try:
        assert isinstance(cell.can, SeqpacketHubBus)
        host = can.Bus(interface="seqpacket", channel=address, connect_timeout_s=1.0)
        buses.append(host)
        reader = threading.Thread(target=read_until_closed, args=(host,))
        reader.start()
        cell.run(duration_s=0.2)  # real time: 50 cycles
    finally:
        cell.close()  # which ends the reader (end of file)
        if reader is not None:
            reader.join()
    status_id = cell.proto.status_id
    assert sum(m.arbitration_id == status_id for m in got) >= 45, "feedback every cycle"
    summary = cell.summary()
    assert summary["can_endpoint"] == f"seqpacket {address}"
    assert summary["wake_late_p50_s"] is not None
    assert "not applied" in summary["scheduling"]["cpu_affinity"]
    assert "cpu_affinity" in caplog.text


def test_a_lossy_segment_loses_frames_at_its_rate_and_counts_them(address, port, buses):
    """[endpoints] can_frame_loss (the soak benchmark's noisy segment): each frame is lost on
    its own; 30 % of 100 cycles' status frames, within what chance allows."""
    cfg = load_sim_config(
        None,
        {
            "controller": {"cycle_period_s": 0.002},
            "endpoints": {"can_channel": address, "modbus_port": port, "can_frame_loss": 0.3},
        },
    )
    cell = VirtualCell(cfg)
    cell.open()
    got: list[can.Message] = []

    def read_until_closed(host: can.BusABC) -> None:
        with contextlib.suppress(can.CanOperationError):
            while (m := host.recv(SLOW_S)) is not None:
                got.append(m)

    reader: threading.Thread | None = None
    try:
        host = can.Bus(interface="seqpacket", channel=address, connect_timeout_s=1.0)
        buses.append(host)
        reader = threading.Thread(target=read_until_closed, args=(host,))
        reader.start()
        cell.run(duration_s=0.2)  # 100 cycles
    finally:
        cell.close()
        if reader is not None:
            reader.join()
    summary = cell.summary()
    status = sum(m.arbitration_id == cell.proto.status_id for m in got)
    sent = summary["cycles"]
    assert 0.55 * sent <= status <= 0.85 * sent, (status, sent)
    lost = summary["can_frames_lost"]["to_host"]  # every frame the cell sent: lost or got
    assert 0.25 < lost / (lost + len(got)) < 0.35, (lost, len(got))
    with pytest.raises(ConfigError, match="can_frame_loss"):
        load_sim_config(None, {"endpoints": {"can_frame_loss": 0.7}})


def test_the_virtual_controller_can_serve_socketcand_for_a_remote_host(port):
    cfg = load_sim_config(None, {"endpoints": {"can_interface": "socketcand", "can_port": 0}})
    bus = open_can_endpoint(cfg.endpoints)
    try:
        assert isinstance(bus, SocketcandServerBus)
    finally:
        bus.shutdown()
    with pytest.raises(ConfigError, match="classic frames only"):
        open_can_endpoint(cfg.endpoints, fd=True)
