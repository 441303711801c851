"""The virtual controller's CAN segment: a Unix ``SOCK_SEQPACKET`` server that is a python-can bus.

Clients connect with :class:`drivers.can.seqpacket.SeqpacketBus` (``interface = "seqpacket"``);
the module docstring there describes the wire format (SocketCAN's struct can_frame and
struct canfd_frame, one per datagram) and the addresses (``@name`` or a file path).

It behaves like one CAN segment: a frame sent by a client reaches every other client and this
object's :meth:`~can.BusABC.recv`; a frame passed to :meth:`send` reaches every client; nobody
receives its own frames. A received frame's ``timestamp`` is the kernel's arrival stamp (wall
clock), as with SocketCAN, so it holds however late the owner's loop reads it.

Delivery is lossless and in order: writes to a client never block; what its socket cannot take
waits in a per-client backlog, and a client whose backlog passes
:attr:`SeqpacketHubBus.MAX_BACKLOG_FRAMES` (it stopped reading) is disconnected with a log line.
A malformed datagram from a client is dropped (not forwarded), counted and logged once.

There is no I/O thread: the owner's loop services the hub. :meth:`fileno` is an epoll descriptor
that is readable when the listener or any client needs attention; :meth:`recv` accepts, reads,
flushes backlogs and returns the next frame. Use it from one thread only. Readiness of
:meth:`fileno` covers the sockets, not frames already read into the hub, so drain with
``recv(0)`` until it returns None before waiting on it::

    while running:
        while (msg := hub.recv(0.0)) is not None:
            handle(msg)
        select.select([hub.fileno()], [], [], time_left_s)
"""

from __future__ import annotations

import collections
import contextlib
import errno
import logging
import os
import select
import socket
import stat
import struct
import time

import can
from can.bus import CanProtocol

from drivers.can.seqpacket import (
    RECV_BYTES,
    FrameDecoder,
    encode_frame,
    is_abstract,
    socket_address,
    wait_readable,
)

log = logging.getLogger(__name__)

_MSG_NOSIGNAL = getattr(socket, "MSG_NOSIGNAL", 0)
_UCRED = struct.Struct("3i")  # struct ucred: pid, uid, gid
_READ_EVENTS = select.EPOLLIN
#: SO_TIMESTAMPNS (Linux; not in Python's socket module): the kernel stamps each datagram on
#: arrival with CLOCK_REALTIME, as SocketCAN stamps frames
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("qq")  # struct timespec: tv_sec, tv_nsec
_STAMP_SPACE = socket.CMSG_SPACE(_TIMESPEC.size)
_WRITE_EVENTS = select.EPOLLIN | select.EPOLLOUT


class _Client:
    __slots__ = ("backlog", "decode", "fd", "name", "sock", "want_write")

    def __init__(self, sock: socket.socket, name: str, decode: FrameDecoder) -> None:
        self.sock = sock
        self.fd = sock.fileno()
        self.name = name
        self.decode = decode
        self.backlog: collections.deque[bytes] = collections.deque()
        self.want_write = False  #: registered for EPOLLOUT (the backlog is not empty)


class SeqpacketHubBus(can.BusABC):
    """The server end, listening on ``channel`` (``@name`` or a file path).

    :param channel: the address to listen on
    :param fd: this bus's own :meth:`recv` returns FD frames and :meth:`send` may send them
        (clients' FD frames are forwarded to the other clients either way)
    :param mode: permissions of a filesystem socket (0o600: this user only; 0o660: and group)
    :param max_backlog_frames: override :attr:`MAX_BACKLOG_FRAMES`
    """

    #: A client whose socket is full and has this many more frames waiting for it is
    #: disconnected: about 8 s of a 250 Hz controller's traffic [frames].
    MAX_BACKLOG_FRAMES = 16384
    #: Datagrams read from one client per pass, so one chatty client cannot starve the rest.
    READ_BATCH = 256
    #: Datagrams still read from a client being dropped (what it sent before it went).
    DRAIN_LIMIT = 4096
    #: Connections the kernel queues before the owner's loop accepts them.
    LISTEN_BACKLOG = 16

    def __init__(
        self,
        channel: str = "@leadthrough-vcan0",
        fd: bool = False,
        mode: int = 0o600,
        max_backlog_frames: int | None = None,
        can_filters: can.typechecking.CanFilters | None = None,
        **kwargs: object,
    ) -> None:
        address = socket_address(channel)
        if mode & ~0o770:
            raise can.CanInitializationError(f"socket mode {mode:#o}: only owner and group bits")
        self.channel = channel
        self.channel_info = f"seqpacket hub {channel}"
        self.fd = bool(fd)
        self._can_protocol = CanProtocol.CAN_FD if self.fd else CanProtocol.CAN_20
        if max_backlog_frames is not None:
            self.MAX_BACKLOG_FRAMES = max_backlog_frames
        self._path: str | None = None if is_abstract(channel) else channel
        self._path_id: tuple[int, int] | None = None  #: (st_dev, st_ino) of our socket file
        self._listener = self._listen(address, mode)
        self._listen_fd = self._listener.fileno()
        self._epoll = select.epoll()
        self._epoll.register(self._listen_fd, _READ_EVENTS)
        self._epoll_fd = self._epoll.fileno()
        self._clients: dict[int, _Client] = {}
        self._client_list: tuple[_Client, ...] = ()  #: snapshot for sending
        self._rx: collections.deque[can.Message] = collections.deque()
        self._accepted = 0
        self.malformed_frames = 0  #: datagrams from clients dropped as malformed
        self.ignored_fd_frames = 0  #: FD frames not returned by recv (``fd`` is off)
        self.dropped_clients = 0  #: clients disconnected for not reading
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        log.info("%s listening", self.channel_info)

    # --- python-can API -------------------------------------------------------------------
    def fileno(self) -> int:
        """An epoll descriptor, readable when the hub has sockets to service."""
        return self._epoll_fd

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Broadcast ``msg`` to every client. Never blocks (``timeout`` is ignored)."""
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.channel_info} is shut down")
        data = encode_frame(msg, self.fd)
        for client in self._client_list:
            self._write(client, data)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        rx = self._rx
        if rx:
            return rx.popleft(), False
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.channel_info} is shut down")
        self._service()
        if rx:
            return rx.popleft(), False
        if timeout is not None and timeout <= 0:
            return None, False
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None, False
            wait_readable(self._epoll_fd, left)
            self._service()
            if rx:
                return rx.popleft(), False

    def drain(self) -> list[can.Message]:
        """Every frame there is now, oldest first, after servicing the sockets once; never
        waits. What :meth:`recv` with a zero timeout returns one by one (the bus's filters
        applied), without python-can's per-call overhead."""
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.channel_info} is shut down")
        self._service()
        rx = self._rx
        out = list(rx) if self._filters is None else [m for m in rx if self._matches_filters(m)]
        rx.clear()
        return out

    def shutdown(self) -> None:
        """Close every connection and the listener; remove the socket file. Idempotent."""
        if self._is_shutdown:
            return
        super().shutdown()
        for client in self._client_list:
            with contextlib.suppress(OSError):
                client.sock.close()
        self._clients, self._client_list = {}, ()
        self._epoll.close()
        self._listener.close()
        if self._path is not None and self._path_id is not None:
            # Only our own file: a successor may already listen on the same path.
            with contextlib.suppress(OSError):
                st = os.stat(self._path)
                if (st.st_dev, st.st_ino) == self._path_id:
                    os.unlink(self._path)
        log.info("%s closed", self.channel_info)

    # --- introspection (tests, logs) ------------------------------------------------------
    @property
    def client_count(self) -> int:
        return len(self._clients)

    @property
    def forwards(self) -> bool:
        """True when a client's frames must reach other clients: with two or more connected,
        the owner's loop should service the hub as frames arrive (:meth:`fileno`), not only
        when it wants them itself."""
        return len(self._clients) > 1

    def wait_for_clients(self, n: int, timeout_s: float) -> bool:
        """Service the hub until at least ``n`` clients are connected; False on timeout.

        Frames that arrive meanwhile are kept for :meth:`recv`.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            self._service()
            if len(self._clients) >= n:
                return True
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            wait_readable(self._epoll_fd, left)

    # --- internals ------------------------------------------------------------------------
    def _listen(self, address: str, mode: int) -> socket.socket:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            if self._path is not None:
                self._clear_stale_path(self._path)
                # The file is created with the socket inode's mode minus umask: never wider
                # than ``mode``; chmod then sets it exactly (group bits despite umask 022).
                os.fchmod(sock.fileno(), mode)
            try:
                sock.bind(address)
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    raise can.CanInitializationError(
                        f"seqpacket address {self.channel!r} is in use by a running server "
                        "(another virtual controller?)"
                    ) from None
                raise can.CanInitializationError(
                    f"cannot listen on seqpacket address {self.channel!r}: {exc}"
                ) from exc
            if self._path is not None:
                os.chmod(self._path, mode)
                st = os.stat(self._path)
                self._path_id = (st.st_dev, st.st_ino)
            sock.listen(self.LISTEN_BACKLOG)
            sock.setblocking(False)
        except BaseException:
            sock.close()
            raise
        return sock

    def _clear_stale_path(self, path: str) -> None:
        """Remove a socket file left by a server that died; refuse if one still listens there."""
        try:
            st = os.lstat(path)
        except FileNotFoundError:
            return
        if not stat.S_ISSOCK(st.st_mode):
            raise can.CanInitializationError(
                f"seqpacket address {path!r} exists and is not a socket; not touching it"
            )
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        probe.setblocking(False)
        try:
            probe.connect(path)
        except ConnectionRefusedError:
            os.unlink(path)
            log.info("%s: removed the stale socket file of a server that is gone", path)
            return
        except BlockingIOError:
            pass  # a live server with a full accept queue
        except OSError as exc:
            raise can.CanInitializationError(
                f"seqpacket address {path!r} is in use ({exc}); not touching it"
            ) from None
        finally:
            probe.close()
        raise can.CanInitializationError(
            f"seqpacket address {path!r} is in use by a running server "
            "(another virtual controller?)"
        )

    def _service(self) -> None:
        """Accept, read and flush whatever is ready now; never waits."""
        for fd, events in self._epoll.poll(0):
            if fd == self._listen_fd:
                self._accept()
                continue
            client = self._clients.get(fd)
            if client is None:
                continue
            if events & select.EPOLLOUT:
                self._flush(client)
            if events & (select.EPOLLIN | select.EPOLLHUP | select.EPOLLERR):
                self._read(client)

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. out of descriptors: leave it queued, say so
                log.error("%s: accept failed: %s", self.channel_info, exc)
                return
            sock.setblocking(False)
            sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
            self._accepted += 1
            try:
                pid = _UCRED.unpack(
                    sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _UCRED.size)
                )[0]
                name = f"client {self._accepted} (pid {pid})"
            except OSError:
                name = f"client {self._accepted}"
            client = _Client(sock, name, FrameDecoder(f"{self.channel_info} {name}", True))
            self._clients[client.fd] = client
            self._client_list = tuple(self._clients.values())
            self._epoll.register(client.fd, _READ_EVENTS)
            log.info("%s: %s connected", self.channel_info, name)

    def _read(self, client: _Client, batch: int | None = None) -> None:
        """Up to ``batch`` (default :attr:`READ_BATCH`) datagrams from ``client``, forwarded to
        the others and queued for :meth:`recv`; drops it at its end of file."""
        sock, decode, channel = client.sock, client.decode, self.channel
        rx, own_fd = self._rx, self.fd
        for _ in range(self.READ_BATCH if batch is None else batch):
            try:
                datagram, ancillary, _flags, _addr = sock.recvmsg(RECV_BYTES, _STAMP_SPACE)
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionResetError:
                self._drop(client, "disconnected")
                return
            except OSError as exc:
                self._drop(client, f"receive failed: {exc}")
                return
            if not datagram:
                self._drop(client, "disconnected")
                return
            stamp = None
            for level, kind, data in ancillary:
                if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS:
                    sec, nsec = _TIMESPEC.unpack(data)
                    stamp = sec + nsec * 1e-9
            msg = decode(datagram, channel, stamp)
            if msg is None:
                self.malformed_frames += 1
                continue
            for other in self._client_list:
                if other is not client:
                    self._write(other, datagram)
            if msg.is_fd and not own_fd:
                self.ignored_fd_frames += 1
            else:
                rx.append(msg)

    def _write(self, client: _Client, data: bytes) -> None:
        backlog = client.backlog
        if backlog:  # behind it, in order; it may have room again (the owner only sends)
            self._flush(client)
        if not backlog:
            sent = self._send(client, data)
            if sent is not False:  # sent, or the client was dropped
                return
        backlog.append(data)
        if len(backlog) > self.MAX_BACKLOG_FRAMES:
            self.dropped_clients += 1
            self._drop(client, f"stopped reading ({len(backlog)} frames waiting for it)")
        elif not client.want_write:
            client.want_write = True
            self._epoll.modify(client.fd, _WRITE_EVENTS)

    def _flush(self, client: _Client) -> None:
        backlog = client.backlog
        while backlog:
            if not self._send(client, backlog[0]):  # full, or the client was dropped
                return
            backlog.popleft()
        if client.want_write:
            client.want_write = False
            self._epoll.modify(client.fd, _READ_EVENTS)

    def _send(self, client: _Client, data: bytes) -> bool | None:
        """One datagram to ``client``: True sent, False its socket is full (try later), None
        it is gone (dropped, with the reason logged)."""
        try:
            client.sock.send(data, _MSG_NOSIGNAL)
            return True
        except (BlockingIOError, InterruptedError):
            return False
        except (BrokenPipeError, ConnectionResetError):
            self._drop(client, "disconnected")
        except OSError as exc:
            self._drop(client, f"send failed: {exc}")
        return None

    def _drop(self, client: _Client, why: str) -> None:
        if self._clients.pop(client.fd, None) is None:
            return
        self._client_list = tuple(self._clients.values())
        # What it sent before it went is on the wire: delivered, as on a CAN bus. (A host that
        # sends BRAKE and exits at once can be found gone by a send to it before its frames
        # were read; closing then would lose the BRAKE.)
        self._read(client, self.DRAIN_LIMIT)
        with contextlib.suppress(OSError, ValueError):
            self._epoll.unregister(client.fd)
        client.backlog.clear()
        client.sock.close()
        level = logging.INFO if why == "disconnected" else logging.WARNING
        log.log(level, "%s: %s dropped: %s", self.channel_info, client.name, why)
