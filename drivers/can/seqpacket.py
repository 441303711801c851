"""A python-can interface for CAN across processes on one machine: Unix ``SOCK_SEQPACKET``.

The cell's CAN driver talks to the robot controller through python-can's ``socketcan`` interface
on ``can0``. Where the kernel has no SocketCAN (no ``vcan``), the virtual controller serves its
CAN segment on a Unix-domain ``SOCK_SEQPACKET`` socket instead, and the driver connects with::

    can.Bus(interface="seqpacket", channel="@leadthrough-vcan0", fd=False, connect_timeout_s=5.0)

(``[can.transport]`` of the cell config). Only the configuration differs from production.

Why this socket type: the kernel keeps datagram boundaries (one datagram = one frame) and
delivers reliably and in order; a full receiver makes the sender wait instead of dropping.

Wire format: each datagram is exactly Linux SocketCAN's ``struct can_frame`` (16 bytes,
``CAN_MTU``) or ``struct canfd_frame`` (72 bytes, ``CANFD_MTU``) from ``<linux/can.h>``, in host
byte order: ``can_id`` with ``CAN_EFF_FLAG``/``CAN_RTR_FLAG``/``CAN_ERR_FLAG``, ``len``, then
``len8_dlc`` (classic) or ``flags`` with ``CANFD_BRS``/``CANFD_ESI``/``CANFD_FDF`` (FD). So a
frame means the same here as on ``socketcan``: same ids, flags, lengths and error frames.

A datagram that is not a valid frame (wrong size, ``len`` over 8 for classic or not a CAN FD
length for FD, unknown FD flags, a remote FD frame, a standard id above 0x7FF) is dropped and
counted in :attr:`SeqpacketBus.malformed_frames`; the first one is logged with what was wrong.
Like a SocketCAN socket without ``CAN_RAW_FD_FRAMES``, a bus opened without ``fd=True`` ignores
FD frames (counted in :attr:`SeqpacketBus.ignored_fd_frames`) and refuses to send them.

Addresses (``channel``): ``@name`` is a name in Linux's abstract socket namespace (no file to
clean up, no path-length trouble in deep temporary folders); anything else is a filesystem path.
The server end is :class:`sim_bridge.can_hub.SeqpacketHubBus`.
"""

from __future__ import annotations

import logging
import math
import select
import socket
import struct
import time

import can
from can.bus import CanProtocol

log = logging.getLogger(__name__)

# <linux/can.h>
CAN_EFF_FLAG = 0x80000000  #: extended frame format (29-bit id)
CAN_RTR_FLAG = 0x40000000  #: remote transmission request
CAN_ERR_FLAG = 0x20000000  #: error message frame
CAN_EFF_MASK = 0x1FFFFFFF
CAN_SFF_MASK = 0x000007FF
CANFD_BRS = 0x01  #: bit rate switch
CANFD_ESI = 0x02  #: error state indicator of the transmitting node
CANFD_FDF = 0x04  #: marks a struct canfd_frame holding an FD frame
CAN_MTU = 16  #: sizeof(struct can_frame) [bytes]
CANFD_MTU = 72  #: sizeof(struct canfd_frame) [bytes]
CAN_MAX_DLEN = 8
CANFD_MAX_DLEN = 64
#: Payload lengths a CAN FD frame can have (ISO 11898-1 DLC 0..15) [bytes].
CANFD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
_FD_LENGTH_SET = frozenset(CANFD_LENGTHS)
#: The next valid FD length for each payload size 0..64 (python-can's socketcan pads the same).
_FD_PADDED = tuple(min(n for n in CANFD_LENGTHS if n >= size) for size in range(65))

#: struct can_frame: can_id, len, __pad, __res0, len8_dlc, data[8]
CAN_FRAME = struct.Struct("=IBBBB8s")
#: struct canfd_frame: can_id, len, flags, __res0, __res1, data[64]
CANFD_FRAME = struct.Struct("=IBBBB64s")
#: The 8-byte header both share (can_id, len, flags or __pad, __res0, len8_dlc or __res1).
FRAME_HEADER = struct.Struct("=IBBBB")
assert CAN_FRAME.size == CAN_MTU and CANFD_FRAME.size == CANFD_MTU

#: Receive buffer: one byte more than the largest frame, so an oversized datagram shows.
RECV_BYTES = CANFD_MTU + 1
#: select() takes file descriptors below this; above it, waits fall back to poll() (1 ms steps).
_FD_SETSIZE = 1024
_MSG_NOSIGNAL = getattr(socket, "MSG_NOSIGNAL", 0)
#: Longest Unix socket address, NUL of the abstract namespace included (sizeof sun_path − 1).
MAX_ADDRESS_BYTES = 107


class MalformedFrame(ValueError):
    """A datagram that is not a valid struct can_frame / canfd_frame; the text says why."""


def address_problem(channel: object) -> str:
    """Why ``channel`` is not a usable socket address ("" if it is)."""
    if not isinstance(channel, str) or not channel or channel == "@":
        return f"{channel!r}: name the socket, '@name' (abstract namespace) or a file path"
    if "\0" in channel:
        return f"{channel!r}: contains a NUL character"
    size = len(channel.encode())
    if size > MAX_ADDRESS_BYTES:
        return (
            f"{channel!r} is {size} bytes; a Unix socket address holds at most "
            f"{MAX_ADDRESS_BYTES}: use a shorter path or an abstract '@name'"
        )
    return ""


def socket_address(channel: str) -> str:
    """The ``AF_UNIX`` address of ``channel``: ``@name`` → ``"\\0name"``, else the path.

    Raises :class:`can.CanInitializationError` if it cannot be an address.
    """
    problem = address_problem(channel)
    if problem:
        raise can.CanInitializationError(f"seqpacket channel {problem}")
    return "\0" + channel[1:] if channel.startswith("@") else channel


def is_abstract(channel: str) -> bool:
    return channel.startswith("@")


def encode_frame(msg: can.Message, fd_allowed: bool) -> bytes:
    """``msg`` as a struct can_frame (16 bytes) or, if ``msg.is_fd``, struct canfd_frame (72).

    FD payloads are zero-padded to the next valid FD length. Raises
    :class:`can.CanOperationError` for a message no CAN bus could carry.
    """
    can_id = arbitration_id = msg.arbitration_id
    limit = CAN_SFF_MASK
    if msg.is_extended_id:
        can_id |= CAN_EFF_FLAG
        limit = CAN_EFF_MASK
    if msg.is_error_frame:  # its "id" is the error class, up to 29 bits
        can_id |= CAN_ERR_FLAG
        limit = CAN_EFF_MASK
    if not 0 <= arbitration_id <= limit:
        kind = "extended" if msg.is_extended_id else "standard"
        raise can.CanOperationError(f"{kind} id 0x{arbitration_id:X} out of range 0..0x{limit:X}")
    data = msg.data
    size = len(data)
    if msg.is_fd:
        if not fd_allowed:
            raise can.CanOperationError("an FD frame on a bus opened without fd=True")
        if msg.is_remote_frame:
            raise can.CanOperationError("CAN FD has no remote frames")
        if size > CANFD_MAX_DLEN:
            raise can.CanOperationError(f"{size} data bytes; CAN FD carries at most 64")
        flags = CANFD_FDF
        if msg.bitrate_switch:
            flags |= CANFD_BRS
        if msg.error_state_indicator:
            flags |= CANFD_ESI
        return CANFD_FRAME.pack(can_id, _FD_PADDED[size], flags, 0, 0, bytes(data))
    if msg.is_remote_frame:
        can_id |= CAN_RTR_FLAG
        if not 0 <= msg.dlc <= CAN_MAX_DLEN:
            raise can.CanOperationError(f"remote frame DLC {msg.dlc} outside 0..8")
        return CAN_FRAME.pack(can_id, msg.dlc, 0, 0, 0, b"")
    if size > CAN_MAX_DLEN:
        raise can.CanOperationError(f"{size} data bytes; a classic frame carries at most 8")
    # len8_dlc: a DLC of 9..15 with 8 data bytes (CAN_CTRLMODE_CC_LEN8_DLC)
    len8_dlc = msg.dlc if size == CAN_MAX_DLEN and CAN_MAX_DLEN < msg.dlc <= 15 else 0
    return CAN_FRAME.pack(can_id, size, 0, 0, len8_dlc, bytes(data))


def decode_frame(
    datagram: bytes, channel: str | None = None, timestamp: float | None = None
) -> can.Message:
    """A received struct can_frame / canfd_frame as a Message (``is_rx``), stamped
    ``timestamp`` (wall clock [s], e.g. the kernel's arrival stamp) or now.

    Raises :class:`MalformedFrame` saying what is wrong; never anything else.
    """
    size = len(datagram)
    if size != CAN_MTU and size != CANFD_MTU:
        raise MalformedFrame(
            f"{size} bytes, neither a can_frame ({CAN_MTU}) nor a canfd_frame ({CANFD_MTU})"
        )
    can_id, length, flags, _res0, len8_dlc = FRAME_HEADER.unpack_from(datagram)
    is_fd = size == CANFD_MTU
    if is_fd:
        if length not in _FD_LENGTH_SET:
            raise MalformedFrame(f"FD len {length} is not a CAN FD length {CANFD_LENGTHS}")
        if flags & ~(CANFD_BRS | CANFD_ESI | CANFD_FDF):
            raise MalformedFrame(f"unknown FD flags 0x{flags:02X}")
        if can_id & CAN_RTR_FLAG:
            raise MalformedFrame("remote flag on an FD frame")
        dlc = length
    else:
        if length > CAN_MAX_DLEN:
            raise MalformedFrame(f"classic len {length} > 8")
        # As the kernel: len8_dlc counts only with 8 data bytes and a value of 9..15.
        dlc = len8_dlc if length == CAN_MAX_DLEN and CAN_MAX_DLEN < len8_dlc <= 15 else length
    extended = bool(can_id & CAN_EFF_FLAG)
    error = bool(can_id & CAN_ERR_FLAG)
    remote = bool(can_id & CAN_RTR_FLAG)
    arbitration_id = can_id & CAN_EFF_MASK  # an error frame's "id" is its error class
    if arbitration_id > CAN_SFF_MASK and not (extended or error):
        raise MalformedFrame(f"standard id 0x{arbitration_id:X} > 0x7FF without CAN_EFF_FLAG")
    return can.Message(
        timestamp=time.time() if timestamp is None else timestamp,
        arbitration_id=arbitration_id,
        is_extended_id=extended,
        is_remote_frame=remote,
        is_error_frame=error,
        channel=channel,
        dlc=dlc,
        data=None if remote else datagram[8 : 8 + length],
        is_fd=is_fd,
        is_rx=True,
        bitrate_switch=bool(flags & CANFD_BRS) if is_fd else False,
        error_state_indicator=bool(flags & CANFD_ESI) if is_fd else False,
    )


def wait_readable(fd: int, timeout_s: float | None) -> bool:
    """Wait until ``fd`` is readable or ``timeout_s`` [s] passed (None: forever); True if it is.

    ``select`` keeps the timeout's microseconds; epoll and poll would round it up to whole
    milliseconds, which is a quarter of a 250 Hz cycle.
    """
    if fd < _FD_SETSIZE:
        return bool(select.select((fd,), (), (), timeout_s)[0])
    return _poll(fd, select.POLLIN, timeout_s)


def wait_writable(fd: int, timeout_s: float | None) -> bool:
    """As :func:`wait_readable`, for room to write."""
    if fd < _FD_SETSIZE:
        return bool(select.select((), (fd,), (), timeout_s)[1])
    return _poll(fd, select.POLLOUT, timeout_s)


def _poll(fd: int, events: int, timeout_s: float | None) -> bool:
    poller = select.poll()
    poller.register(fd, events)
    timeout_ms = None if timeout_s is None else math.ceil(max(timeout_s, 0.0) * 1e3)
    return bool(poller.poll(timeout_ms))


class FrameDecoder:
    """:func:`decode_frame` with the drop-and-count rules of one bus (or one hub client)."""

    def __init__(self, owner: str, fd: bool) -> None:
        self.owner = owner
        self.fd = fd
        self.malformed = 0  #: datagrams dropped as malformed
        self.ignored_fd = 0  #: FD frames ignored because FD is off

    def __call__(
        self, datagram: bytes, channel: str | None, timestamp: float | None = None
    ) -> can.Message | None:
        try:
            msg = decode_frame(datagram, channel, timestamp)
        except MalformedFrame as exc:
            self.malformed += 1
            if self.malformed == 1:
                log.warning(
                    "%s: dropped a malformed CAN datagram (%s); further ones are only counted",
                    self.owner,
                    exc,
                )
            return None
        if msg.is_fd and not self.fd:
            self.ignored_fd += 1
            return None
        return msg


class SeqpacketBus(can.BusABC):
    """Client end: one connection to a :class:`~sim_bridge.can_hub.SeqpacketHubBus`.

    :param channel: the server's address, ``@name`` (abstract namespace) or a file path
    :param fd: accept and send CAN FD frames
    :param connect_timeout_s: keep retrying to connect for this long [s] (the server may be
        starting), then raise :class:`can.CanInitializationError`
    """

    #: Pause between connection attempts [s].
    CONNECT_RETRY_S = 0.05

    def __init__(
        self,
        channel: str,
        fd: bool = False,
        connect_timeout_s: float = 5.0,
        can_filters: can.typechecking.CanFilters | None = None,
        **kwargs: object,
    ) -> None:
        address = socket_address(channel)
        self.channel = channel
        self.channel_info = f"seqpacket {channel}"
        self.fd = bool(fd)
        self._can_protocol = CanProtocol.CAN_FD if self.fd else CanProtocol.CAN_20
        self._sock = _connect(address, channel, connect_timeout_s, self.CONNECT_RETRY_S)
        self._fileno = self._sock.fileno()
        self._decode = FrameDecoder(self.channel_info, self.fd)
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    @property
    def malformed_frames(self) -> int:
        """Datagrams received and dropped because they were not valid frames."""
        return self._decode.malformed

    @property
    def ignored_fd_frames(self) -> int:
        """FD frames received and ignored because this bus was opened without ``fd=True``."""
        return self._decode.ignored_fd

    def fileno(self) -> int:
        return self._fileno

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send one frame; wait at most ``timeout`` [s] (None: as long as it takes) for room.

        Raises :class:`can.CanOperationError` if the server does not take it in time, the
        connection is gone, or the frame is invalid.
        """
        data = encode_frame(msg, self.fd)
        sock = self._sock
        try:
            sock.send(data, _MSG_NOSIGNAL)
            return
        except BlockingIOError:
            pass
        except OSError as exc:
            raise can.CanOperationError(f"{self.channel_info}: send failed: {exc}") from exc
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                raise can.CanOperationError(
                    f"{self.channel_info}: transmit buffer full for {timeout:g} s "
                    "(the server is not reading)"
                )
            try:
                wait_writable(self._fileno, left)
                sock.send(data, _MSG_NOSIGNAL)
                return
            except BlockingIOError:
                continue
            except (OSError, ValueError) as exc:
                raise can.CanOperationError(f"{self.channel_info}: send failed: {exc}") from exc

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        sock, fileno, decode, channel = self._sock, self._fileno, self._decode, self.channel
        deadline: float | None = None
        while True:
            try:
                datagram = sock.recv(RECV_BYTES)
            except BlockingIOError:
                if timeout is None:
                    left = None
                else:
                    if deadline is None:
                        deadline = time.monotonic() + timeout
                    left = deadline - time.monotonic()
                    if left <= 0:
                        return None, False
                try:
                    wait_readable(fileno, left)
                except (OSError, ValueError) as exc:  # closed by shutdown() in another thread
                    raise can.CanOperationError(f"{self.channel_info}: {exc}") from exc
                continue
            except OSError as exc:
                raise can.CanOperationError(f"{self.channel_info}: receive failed: {exc}") from exc
            if not datagram:
                raise can.CanOperationError(
                    f"{self.channel_info}: the server closed the connection"
                )
            msg = decode(datagram, channel)
            if msg is not None:
                return msg, False

    def shutdown(self) -> None:
        """Close the connection. Idempotent."""
        if self._is_shutdown:
            return
        super().shutdown()
        self._sock.close()


def _connect(address: str, channel: str, timeout_s: float, retry_s: float) -> socket.socket:
    """A non-blocking connected SOCK_SEQPACKET socket, retrying until ``timeout_s`` [s]."""
    deadline = time.monotonic() + max(timeout_s, 0.0)
    while True:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            sock.settimeout(max(deadline - time.monotonic(), retry_s))
            sock.connect(address)
        except (FileNotFoundError, ConnectionRefusedError, BlockingIOError, TimeoutError) as exc:
            sock.close()
            # FileNotFound/refused: no server (yet); BlockingIO/Timeout: its backlog is full.
            now = time.monotonic()
            if now >= deadline:
                raise can.CanInitializationError(
                    f"no CAN server at seqpacket address {channel!r} after {timeout_s:g} s "
                    f"({exc.strerror or exc}); is the virtual controller (leadthrough sim) "
                    "running?"
                ) from None
            time.sleep(min(retry_s, deadline - now))
            continue
        except OSError as exc:
            sock.close()
            raise can.CanInitializationError(
                f"cannot connect to seqpacket address {channel!r}: {exc}"
            ) from exc
        sock.setblocking(False)
        return sock
