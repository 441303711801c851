"""The virtual controller's CAN endpoint for a host on another machine (HIL): socketcand over TCP.

On one machine the virtual controller serves CAN on a Unix SOCK_SEQPACKET socket
(:mod:`sim_bridge.can_hub`, ``[endpoints] can_interface = "seqpacket"``, the default): binary
frames, CAN FD, no thread. This server is for ``can_interface = "socketcand"``, when the host
under test runs elsewhere and reaches the virtual controller over the network. It is slower
(ASCII lines parsed on both sides, one TCP write per frame) and carries classic data frames
only. It keeps its own I/O thread, which accepts, reads and flushes while the controller loop
computes; received frames wait in a queue for :meth:`SocketcandServerBus.recv`.

It speaks the socketcand protocol (https://github.com/linux-can/socketcand,
``doc/protocol.md``), raw mode only. Any number of python-can clients connect with::

    can.Bus(interface="socketcand", channel="vcan0", host=HOST, port=PORT, tcp_tune=True)

and the CAN driver code is the same as on the cell's real ``socketcan`` ``can0``.

Semantics of one shared CAN segment: a frame sent by a client reaches every other client and
this object's :meth:`recv`; a frame passed to this object's :meth:`send` reaches every client.
Nobody receives its own frames. Delivery is lossless and in order per sender (TCP, unbounded
per-client backlog up to :attr:`MAX_BACKLOG_BYTES`, after which a client that stopped reading
is disconnected). A malformed line from a client is logged and dropped.

Protocol, as python-can 4.6's client speaks it::

    server: < hi >             client: < open vcan0 >
    server: < ok >             client: < rawmode >
    server: < ok >
    server: < frame 181 1712345678.123456 40420F0000000000 >     (id: 3 hex digits standard,
    client: < send 201 8 0 0 0 0 0 0 0 2a >                       8 extended; data hex bytes)

python-can's client reads each handshake reply with a single ``recv`` and compares it exactly,
so every reply goes out alone and only after the request; frames for a new client are held for
:attr:`HANDSHAKE_GRACE_S` after its rawmode ``< ok >`` (queued, not dropped) so they cannot
share that ``recv``.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import re
import selectors
import socket
import threading
import time
from typing import Any

import can

log = logging.getLogger(__name__)

_HEX_ID = re.compile(r"^[0-9A-Fa-f]{1,8}$")
_HEX_LEN = re.compile(r"^[0-9A-Fa-f]{1,2}$")
_HEX_BYTE = re.compile(r"^[0-9A-Fa-f]{1,2}$")

_WAIT_OPEN, _WAIT_MODE, _RAW = "wait_open", "wait_mode", "raw"


class _Client:
    """One connected TCP client. ``lock`` guards ``outbuf``, ``ready_at_s`` and ``dead``."""

    def __init__(self, sock: socket.socket, addr: Any) -> None:
        self.sock = sock
        self.name = f"{addr[0]}:{addr[1]}" if isinstance(addr, tuple) else str(addr)
        self.state = _WAIT_OPEN
        self.inbuf = bytearray()
        self.outbuf = bytearray()
        self.lock = threading.Lock()
        self.ready_at_s = float("inf")  #: frames may flow from this monotonic time on
        self.dead = ""  #: why it must be dropped ("" = alive); the I/O thread drops it
        self.want_write = False  #: registered for EVENT_WRITE (I/O thread only)
        self.closed = False
        self.bad_lines = 0


def _frame_line(msg: can.Message, stamp_s: float) -> bytes:
    """``< frame ID SECS.USECS DATA >`` as socketcand sends a received frame."""
    if msg.is_error_frame or msg.is_remote_frame or msg.is_fd or len(msg.data) > 8:
        raise can.CanOperationError(
            "socketcand raw mode carries classic CAN data frames only "
            f"(error={msg.is_error_frame}, remote={msg.is_remote_frame}, fd={msg.is_fd}, "
            f"{len(msg.data)} bytes)"
        )
    if msg.is_extended_id:
        if not 0 <= msg.arbitration_id <= 0x1FFFFFFF:
            raise can.CanOperationError(f"extended id 0x{msg.arbitration_id:X} out of range")
        can_id = f"{msg.arbitration_id:08X}"
    else:
        if not 0 <= msg.arbitration_id <= 0x7FF:
            raise can.CanOperationError(f"standard id 0x{msg.arbitration_id:X} out of range")
        can_id = f"{msg.arbitration_id:03X}"
    secs = int(stamp_s)
    usecs = min(int((stamp_s - secs) * 1e6), 999_999)
    return f"< frame {can_id} {secs}.{usecs:06d} {bytes(msg.data).hex().upper()} >".encode()


def _parse_send(tokens: list[str]) -> can.Message:
    """``send ID LEN B0 .. Bn`` (tokens of one element) → Message; ValueError if malformed."""
    if len(tokens) < 3:
        raise ValueError("expected '< send ID LEN BYTES... >'")
    id_s, len_s, data_s = tokens[1], tokens[2], tokens[3:]
    if not _HEX_ID.match(id_s):
        raise ValueError(f"id {id_s!r} is not 1..8 hex digits")
    arbitration_id = int(id_s, 16)
    extended = len(id_s) > 3  # socketcand's rule: 3 digits standard, 8 extended
    if not extended and arbitration_id > 0x7FF:
        raise ValueError(f"standard id 0x{arbitration_id:X} exceeds 0x7FF")
    if extended and arbitration_id > 0x1FFFFFFF:
        raise ValueError(f"extended id 0x{arbitration_id:X} exceeds 0x1FFFFFFF")
    if not _HEX_LEN.match(len_s) or int(len_s, 16) > 8:
        raise ValueError(f"length {len_s!r} is not 0..8")
    dlc = int(len_s, 16)
    if len(data_s) != dlc:
        raise ValueError(f"length {dlc} but {len(data_s)} data bytes")
    for b in data_s:
        if not _HEX_BYTE.match(b):
            raise ValueError(f"data byte {b!r} is not 1..2 hex digits")
    return can.Message(
        arbitration_id=arbitration_id,
        is_extended_id=extended,
        data=bytes(int(b, 16) for b in data_s),
        dlc=dlc,
        is_rx=True,
    )


class SocketcandServerBus(can.BusABC):
    """A socketcand-protocol TCP server on ``host:port`` serving one CAN ``channel``.

    ``port=0`` picks a free port; read it back from :attr:`port`. One I/O thread accepts,
    reads and flushes; :meth:`send` writes from the caller's thread when the socket takes it.
    """

    #: Frames for a client wait this long after its rawmode ``< ok >`` [s].
    HANDSHAKE_GRACE_S = 0.05
    #: A client that has this much unread data queued is disconnected [bytes].
    MAX_BACKLOG_BYTES = 4 << 20
    #: Longest element accepted from a client; longer unterminated input is discarded [bytes].
    MAX_ELEMENT_BYTES = 256
    #: Malformed lines logged per client before logging only every 1000th.
    LOGGED_BAD_LINES = 10

    def __init__(
        self,
        channel: str = "vcan0",
        host: str = "127.0.0.1",
        port: int = 29536,
        *,
        handshake_grace_s: float | None = None,
        can_filters: can.typechecking.CanFilters | None = None,
        **kwargs: object,
    ) -> None:
        self.channel = channel
        self._grace_s = self.HANDSHAKE_GRACE_S if handshake_grace_s is None else handshake_grace_s
        try:
            listener = socket.create_server((host, port), backlog=16)
        except OSError as exc:
            raise can.CanInitializationError(f"cannot listen on {host}:{port}: {exc}") from exc
        listener.setblocking(False)
        self._listener = listener
        self.host, self.port = listener.getsockname()[:2]
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._sel = selectors.DefaultSelector()
        self._sel.register(listener, selectors.EVENT_READ, "accept")
        self._sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._clients: dict[int, _Client] = {}
        self._clients_changed = threading.Condition()  # also guards _clients
        self._rx: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self._stop = threading.Event()
        self.channel_info = f"socketcand server {channel}@{self.host}:{self.port}"
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self._thread = threading.Thread(
            target=self._serve, name=f"socketcand-server:{self.port}", daemon=True
        )
        self._thread.start()

    # --- python-can API -------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Broadcast ``msg`` to every connected client (``timeout`` is ignored: never blocks)."""
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.channel_info} is shut down")
        line = _frame_line(msg, time.time())
        for client in self._raw_clients():
            self._write(client, line)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            if timeout is None:
                while not self._is_shutdown:
                    with contextlib.suppress(queue.Empty):
                        return self._rx.get(timeout=0.1), False
                return None, False
            if timeout <= 0:
                return self._rx.get_nowait(), False
            return self._rx.get(timeout=timeout), False
        except queue.Empty:
            return None, False

    def shutdown(self) -> None:
        """Close every socket and join the I/O thread. Idempotent."""
        if self._is_shutdown:
            return
        self._stop.set()
        self._wake()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        with self._clients_changed:
            clients = list(self._clients.values())
        for client in clients:
            self._drop(client, "server shutting down", level=logging.DEBUG)
        for sock in (self._listener, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                sock.close()
        with contextlib.suppress(Exception):
            self._sel.close()
        super().shutdown()

    # --- introspection (tests, logs) -------------------------------------------------------
    @property
    def client_count(self) -> int:
        """Clients that completed the handshake and receive frames."""
        return len(self._raw_clients())

    def wait_for_clients(self, n: int, timeout_s: float) -> bool:
        """Block until at least ``n`` clients completed the handshake and frames sent from now
        on reach them at once (their :attr:`HANDSHAKE_GRACE_S` is over); False on timeout."""
        deadline = time.monotonic() + timeout_s
        with self._clients_changed:
            while len(raw := [c for c in self._clients.values() if c.state == _RAW]) < n:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._clients_changed.wait(left)
            ready_at_s = sorted(c.ready_at_s for c in raw)[n - 1] if n > 0 else 0.0
        wait_s = ready_at_s - time.monotonic()
        if wait_s > deadline - time.monotonic():
            return False
        if wait_s > 0:
            time.sleep(wait_s)
        return True

    # --- internals -------------------------------------------------------------------------
    def _raw_clients(self) -> list[_Client]:
        with self._clients_changed:
            return [c for c in self._clients.values() if c.state == _RAW]

    def _wake(self) -> None:
        with contextlib.suppress(OSError):  # full (already woken) or closed
            self._wake_w.send(b"\0")

    def _write(self, client: _Client, data: bytes, *, handshake: bool = False) -> None:
        """Queue or send ``data``; never blocks. Any thread. ``handshake`` replies skip the
        post-handshake hold-back (frames never precede them: see :meth:`_handle`)."""
        with client.lock:
            wake = self._write_locked(client, data, handshake=handshake)
        if wake:
            self._wake()

    def _write_locked(self, client: _Client, data: bytes, *, handshake: bool = False) -> bool:
        """:meth:`_write` with ``client.lock`` held; True if the I/O thread must look."""
        if client.dead or client.closed:
            return False
        wake = False
        if client.outbuf or (not handshake and time.monotonic() < client.ready_at_s):
            wake = not client.outbuf
            client.outbuf += data
        else:
            try:
                sent = client.sock.send(data)
            except (BlockingIOError, InterruptedError):
                sent = 0
            except OSError as exc:
                client.dead, sent, wake = f"send failed: {exc}", len(data), True
            if sent < len(data):
                client.outbuf += data[sent:]
                wake = True
        if len(client.outbuf) > self.MAX_BACKLOG_BYTES and not client.dead:
            client.dead = f"stopped reading ({len(client.outbuf)} bytes queued)"
            wake = True
        return wake

    def _flush(self, client: _Client) -> None:
        with client.lock:
            if not client.outbuf or client.dead or client.closed:
                return
            try:
                sent = client.sock.send(client.outbuf)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                client.dead = f"send failed: {exc}"
                return
            del client.outbuf[:sent]

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                self._serve_once()
            except Exception:  # a bug must not take the whole bus down: log, carry on
                if self._stop.is_set():
                    break
                log.exception("%s: I/O error; continuing", self.channel_info)
                self._stop.wait(0.01)

    def _serve_once(self) -> None:
        timeout = self._service_backlogs()
        for key, mask in self._sel.select(timeout):
            if key.data == "accept":
                self._accept()
            elif key.data == "wake":
                with contextlib.suppress(OSError):
                    while self._wake_r.recv(4096):
                        pass
            else:
                client: _Client = key.data
                if mask & selectors.EVENT_READ and not client.closed:
                    self._read(client)
                if mask & selectors.EVENT_WRITE and not client.closed:
                    self._flush(client)

    def _service_backlogs(self) -> float:
        """Drop dead clients, flush ready backlogs, keep write interest in step; return how
        long the I/O thread may sleep before a held-back backlog becomes due [s]."""
        now, timeout = time.monotonic(), 0.5
        with self._clients_changed:
            clients = list(self._clients.values())
        for client in clients:
            if client.dead:
                self._drop(client, client.dead)
                continue
            with client.lock:
                due = client.ready_at_s - now
            if due <= 0:
                self._flush(client)
            with client.lock:
                backlog = bool(client.outbuf) and not client.dead
            if backlog and due > 0:
                timeout = min(timeout, due)  # one clock reading for both: nothing falls between
            want = backlog and due <= 0
            if want != client.want_write and not client.closed:
                events = selectors.EVENT_READ | (selectors.EVENT_WRITE if want else 0)
                self._sel.modify(client.sock, events, client)
                client.want_write = want
        return timeout

    def _accept(self) -> None:
        while True:
            try:
                sock, addr = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                log.warning("%s: accept failed: %s", self.channel_info, exc)
                return
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(sock, addr)
            with self._clients_changed:
                self._clients[sock.fileno()] = client
            self._sel.register(sock, selectors.EVENT_READ, client)
            log.debug("%s: client %s connected", self.channel_info, client.name)
            self._write(client, b"< hi >", handshake=True)

    def _drop(self, client: _Client, why: str, level: int = logging.INFO) -> None:
        with client.lock:
            if client.closed:
                return
            client.closed = True
            client.outbuf.clear()
        with self._clients_changed:
            self._clients = {k: c for k, c in self._clients.items() if c is not client}
            self._clients_changed.notify_all()
        with contextlib.suppress(KeyError, ValueError, OSError):
            self._sel.unregister(client.sock)
        with contextlib.suppress(OSError):
            client.sock.close()
        log.log(level, "%s: client %s dropped: %s", self.channel_info, client.name, why)

    def _read(self, client: _Client) -> None:
        try:
            data = client.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._drop(client, f"receive failed: {exc}")
            return
        if not data:
            self._drop(client, "disconnected")
            return
        if hasattr(socket, "TCP_QUICKACK"):
            with contextlib.suppress(OSError):
                client.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_QUICKACK, 1)
        buf = client.inbuf
        buf += data
        while buf and not client.closed:
            start = buf.find(b"<")
            if start < 0:
                self._bad_line(client, bytes(buf), "text outside < >")
                buf.clear()
                break
            if start > 0:
                if bytes(buf[:start]).strip():
                    self._bad_line(client, bytes(buf[:start]), "text outside < >")
                del buf[:start]
            end = buf.find(b">")
            if end < 0:
                if len(buf) > self.MAX_ELEMENT_BYTES:
                    self._bad_line(client, bytes(buf[:64]) + b"...", "unterminated element")
                    buf.clear()
                break
            element = bytes(buf[: end + 1])
            del buf[: end + 1]
            self._handle(client, element)

    def _bad_line(self, client: _Client, line: bytes, why: str) -> None:
        client.bad_lines += 1
        if client.bad_lines <= self.LOGGED_BAD_LINES or client.bad_lines % 1000 == 0:
            log.warning(
                "%s: dropped malformed input from %s (%s, #%d): %r",
                self.channel_info,
                client.name,
                why,
                client.bad_lines,
                line,
            )

    def _handle(self, client: _Client, element: bytes) -> None:
        try:
            tokens = element.decode("ascii")[1:-1].split()
        except UnicodeDecodeError:
            self._bad_line(client, element, "not ASCII")
            return
        if not tokens or any("<" in t for t in tokens):
            self._bad_line(client, element, "empty or nested element")
            return
        command = tokens[0]
        if client.state == _RAW:
            if command == "send":
                try:
                    msg = _parse_send(tokens)
                except ValueError as exc:
                    self._bad_line(client, element, str(exc))
                    return
                self._deliver(client, msg)
            elif command == "echo":
                self._write(client, b"< echo >")
            else:
                self._bad_line(client, element, f"'{command}' not supported in raw mode")
        elif client.state == _WAIT_OPEN:
            if command == "open" and len(tokens) == 2:
                if tokens[1] == self.channel:
                    client.state = _WAIT_MODE
                    self._write(client, b"< ok >", handshake=True)
                else:
                    self._write(client, b"< error could not open bus >", handshake=True)
                    client.dead = f"asked for channel {tokens[1]!r}, this is {self.channel!r}"
                    self._wake()
            else:
                self._bad_line(client, element, "expected '< open CHANNEL >'")
        elif command == "rawmode" and len(tokens) == 1:
            # Join the bus and answer under the client's lock: a frame sent from now on is
            # queued (held back by ready_at_s) behind this "< ok >", never lost or ahead of it.
            with client.lock:
                client.ready_at_s = time.monotonic() + self._grace_s
                with self._clients_changed:
                    client.state = _RAW
                    self._clients_changed.notify_all()
                wake = self._write_locked(client, b"< ok >", handshake=True)
            if wake:
                self._wake()
            log.info("%s: client %s joined", self.channel_info, client.name)
        else:
            self._write(client, b"< error only rawmode is supported >", handshake=True)
            self._bad_line(client, element, "expected '< rawmode >'")

    def _deliver(self, sender: _Client, msg: can.Message) -> None:
        msg.timestamp = time.time()
        msg.channel = self.channel
        line = _frame_line(msg, msg.timestamp)
        for client in self._raw_clients():
            if client is not sender:
                self._write(client, line)
        self._rx.put(msg)
