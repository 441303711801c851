"""LTC frames as values: the enums, the frame tuples, the end-to-end CRC-8 of §4, and
:class:`FrameSpec` (one DBC message and what LTC adds to it).

Shared by LTC-1 (:mod:`drivers.can.ltc_protocol`) and its CAN FD profile LTC-1F
(:mod:`drivers.can.ltc_fd`).
"""

from __future__ import annotations

from collections.abc import Callable
from enum import IntEnum
from typing import Any, Literal, NamedTuple

from drivers.can.adapter import HostRequest
from drivers.can.codec import MessageCodec
from gateway.messages import ControllerState

__all__ = [
    "ControllerStatus",
    "FaultCode",
    "FrameCrc",
    "FrameSpec",
    "Heartbeat",
    "HostRequestFrame",
    "JointCommandFrame",
    "JointFeedback",
    "LtcFrame",
    "NmtState",
    "crc8_of_frame",
    "crc8_sae_j1850",
    "frame_crc",
    "id_bytes",
]


class FaultCode(IntEnum):
    """CTRL_STATUS.fault_code (VAL_ table of the DBC)."""

    NONE = 0
    ESTOP = 1  #: e-stop chain opened
    CMD_TIMEOUT = 2  #: too many consecutive cycles without a complete command set
    HOST_HEARTBEAT_LOST = 3  #: HEARTBEAT_HOST silent for 500 ms while servo on
    FOLLOWING_ERROR = 4  #: |reference − measured| beyond the controller's own limit
    BAD_COMMAND = 5  #: a command set failed the controller's validation
    JOINT_LIMIT = 6  #: a position command beyond a joint's software limit


class NmtState(IntEnum):
    """CANopen-style NMT state carried by the heartbeats (CiA 301 heartbeat values)."""

    BOOT = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


class JointFeedback(NamedTuple):
    """JOINT_FB_Jk: one joint's measurement in one control cycle (controller → host)."""

    joint: int  #: 1-based joint number k
    q_rad: float  #: measured position [rad]
    dq_rad_s: float  #: measured velocity [rad/s]
    current_a: float  #: motor current [A]
    counter: int  #: low byte of the cycle's cycle_counter


class ControllerStatus(NamedTuple):
    """CTRL_STATUS: sent last in every control cycle (controller → host)."""

    cycle_counter: int  #: 16-bit cycle number, wraps at 65536
    state: ControllerState
    fault_code: FaultCode
    missed_cycles: int  #: consecutive cycles without a complete valid command set (EXTERNAL)
    estop_active: bool
    servo_power: bool
    cycle_period_us: int  #: control cycle period [µs]


class JointCommandFrame(NamedTuple):
    """JOINT_CMD_Jk: one joint's command answering one cycle (host → controller)."""

    joint: int  #: 1-based joint number k
    q_cmd_rad: float  #: position command [rad]
    dq_cmd_rad_s: float  #: velocity command used to extrapolate between cycles [rad/s]
    hold: bool  #: hold q_cmd_rad with zero velocity
    #: the cycle_counter this set answers, modulo the profile's command_counter_modulus
    #: (its low byte in LTC-1, all 16 bits in LTC-1F)
    counter: int


class HostRequestFrame(NamedTuple):
    """HOST_REQUEST: servo on/off and fault reset (host → controller)."""

    request: HostRequest
    counter: int  #: rolling counter of request frames, 0..255


class Heartbeat(NamedTuple):
    """HEARTBEAT_CTRL / HEARTBEAT_HOST."""

    node: Literal["CTRL", "HOST"]
    nmt_state: NmtState


LtcFrame = JointFeedback | ControllerStatus | JointCommandFrame | HostRequestFrame | Heartbeat


def _crc8_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_CRC8_J1850_TABLE = _crc8_table(0x1D)


def _crc8_update(crc: int, data: bytes | bytearray) -> int:
    table = _CRC8_J1850_TABLE
    for byte in data:
        crc = table[crc ^ byte]
    return crc


def crc8_sae_j1850(data: bytes | bytearray) -> int:
    """CRC-8/SAE-J1850: poly 0x1D, init 0xFF, not reflected, xorout 0xFF (check 0x4B)."""
    return _crc8_update(0xFF, data) ^ 0xFF


def id_bytes(arbitration_id: int) -> bytes:
    """The two identifier bytes, little-endian, that start every LTC CRC's input (§4)."""
    return bytes((arbitration_id & 0xFF, (arbitration_id >> 8) & 0xFF))


def frame_crc(arbitration_id: int, data7: bytes | bytearray) -> int:
    """CRC of an LTC-1 host frame: over the two little-endian id bytes, then data bytes 0..6."""
    return crc8_sae_j1850(id_bytes(arbitration_id) + data7)


#: A frame's end-to-end CRC: payload → the CRC of the id bytes and every byte before the CRC.
FrameCrc = Callable[[bytes | bytearray], int]


def crc8_of_frame(arbitration_id: int) -> FrameCrc:
    """§4: CRC-8/SAE-J1850 in the last data byte, over the id bytes then the bytes before it.

    The CRC state after the id bytes is the same for every frame of one id: computed once.
    """
    after_id = _crc8_update(0xFF, id_bytes(arbitration_id))

    def crc(data: bytes | bytearray) -> int:
        return _crc8_update(after_id, data[:-1]) ^ 0xFF

    return crc


class FrameSpec:
    """One DBC message, its compiled codec, and what LTC adds to it (kind, joint, CRC).

    Shared with :mod:`drivers.can.ltc_fd`; not part of the protocols' public API.
    """

    __slots__ = (
        "bitrate_switch",
        "codec",
        "crc",
        "crc_bytes",
        "decode",
        "encode",
        "frame_id",
        "is_fd",
        "joint",
        "kind",
        "length",
        "name",
        "node",
        "where",
    )

    def __init__(
        self,
        codec: MessageCodec,
        kind: str,
        *,
        joint: int = 0,
        node: str = "",
        crc: FrameCrc | None = None,
        crc_bytes: int = 0,
        bitrate_switch: bool = False,
    ) -> None:
        self.codec = codec
        self.kind = kind
        self.joint = joint  #: 1-based for per-joint frames, 0 otherwise
        self.node = node  #: heartbeat node, "" otherwise
        self.crc = crc  #: the frame's end-to-end CRC, None if it has none
        self.crc_bytes = crc_bytes  #: size of the CRC at the end of the payload [bytes]
        self.bitrate_switch = bitrate_switch  #: CAN FD data phase at the fast bit rate
        self.name = codec.name
        self.frame_id = codec.frame_id
        self.where = codec.where
        self.length = codec.length
        self.is_fd = codec.is_fd
        #: payload from physical values, in the order the protocol bound (set by the protocol)
        self.encode: Callable[..., bytearray] = codec.encode
        #: payload → the frame tuple (set by the protocol)
        self.decode: Callable[[bytearray], Any] = codec.decode
