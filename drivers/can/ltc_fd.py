"""LTC-1F: the CAN FD profile of LTC-1 (PROTOCOL.md §10), one frame each way per cycle.

Per control cycle the controller sends one ``CYCLE_FB`` (CAN FD, 64 bytes: the CTRL_STATUS
signals and every joint's position, velocity and current) and the host answers with one
``CYCLE_CMD`` (CAN FD, 48 bytes: the 16-bit counter, the hold flag, every joint's position and
velocity command, a CRC-16). HOST_REQUEST and the heartbeats are LTC-1's classic frames. The
layouts are ``ltc_fd_v1.dbc``; scalings and ranges are those of LTC-1 (§2.1).

Classic CAN at 1 Mbit/s cannot carry LTC-1 at 500 Hz (13 frames are 1.4–1.8 ms of wire time);
LTC-1F needs about 0.3 ms at 1 Mbit/s arbitration and 5 Mbit/s data phase (§10.5,
:func:`cycle_wire_time_s`).

:class:`LtcFdProtocol` shares LtcProtocol's controller-side API (``feedback_frames``,
``joint_commands``), so the virtual controller speaks either profile; :class:`LtcFdAdapter` is
the host side (registry name ``ltc_fd``).
"""

from __future__ import annotations

import binascii
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, NamedTuple

import can
import numpy as np

from drivers.can.adapter import CanAdapter, CycleFeedback, HostRequest
from drivers.can.ltc import command_arrays, cycle_feedback
from drivers.can.ltc_frames import (
    ControllerStatus,
    FaultCode,
    FrameCrc,
    FrameSpec,
    Heartbeat,
    HostRequestFrame,
    JointCommandFrame,
    NmtState,
    id_bytes,
)
from drivers.can.ltc_protocol import STATUS_SIGNALS, LtcProtocolBase, check_enum_against_dbc
from gateway.errors import ConfigError, FrameError
from gateway.messages import ControllerState

__all__ = [
    "DEFAULT_FD_DBC_PATH",
    "BitRates",
    "CommandSetFrame",
    "CycleFeedbackFrame",
    "LtcFdAdapter",
    "LtcFdFrame",
    "LtcFdProtocol",
    "classic_frame_bits",
    "crc16_ccitt_false",
    "crc16_of_frame",
    "cycle_wire_time_s",
    "fd_frame_bits",
    "frame_crc16",
    "frame_wire_time_s",
    "host_window_s",
    "housekeeping_wire_time_s",
]

DEFAULT_FD_DBC_PATH = Path(__file__).with_name("ltc_fd_v1.dbc")

CYCLE_FB = "CYCLE_FB"
CYCLE_CMD = "CYCLE_CMD"


def crc16_ccitt_false(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, not reflected, xorout 0 (check 0x29B1).

    ``binascii.crc_hqx`` is this CRC (XMODEM's) with the initial value as its argument, in C.
    """
    return binascii.crc_hqx(data, 0xFFFF)


def frame_crc16(arbitration_id: int, data: bytes | bytearray) -> int:
    """CRC of an LTC-1F CYCLE_CMD (§10.3): the two little-endian id bytes, then ``data``
    (data bytes 0..45)."""
    return crc16_ccitt_false(id_bytes(arbitration_id) + bytes(data))


def crc16_of_frame(arbitration_id: int) -> FrameCrc:
    """§10.3: CRC-16/CCITT-FALSE in the last two data bytes (little-endian), over the id bytes
    then every data byte before it. The state after the id bytes is computed once per id."""
    after_id = binascii.crc_hqx(id_bytes(arbitration_id), 0xFFFF)

    def crc(data: bytes | bytearray) -> int:
        return binascii.crc_hqx(memoryview(data)[:-2], after_id)

    return crc


class CycleFeedbackFrame(NamedTuple):
    """CYCLE_FB: one whole control cycle (controller → host), §10.2."""

    status: ControllerStatus  #: the CTRL_STATUS signals of LTC-1
    q_rad: tuple[float, ...]  #: measured positions of joints 1..n [rad]
    dq_rad_s: tuple[float, ...]  #: measured velocities [rad/s]
    current_a: tuple[float, ...]  #: motor currents, averaged over the cycle (§2.1) [A]


class CommandSetFrame(NamedTuple):
    """CYCLE_CMD: the whole command set answering one cycle (host → controller), §10.3."""

    counter: int  #: the cycle_counter this set answers (all 16 bits)
    hold: bool  #: hold every q_cmd_rad with zero velocity
    q_cmd_rad: tuple[float, ...]  #: position commands of joints 1..n [rad]
    dq_cmd_rad_s: tuple[float, ...]  #: velocity commands, extrapolated between cycles [rad/s]


LtcFdFrame = CycleFeedbackFrame | CommandSetFrame | HostRequestFrame | Heartbeat


def _joint_signals(prefixes: Sequence[str], joints: int) -> tuple[str, ...]:
    """("position_j1", …, "position_jN", "velocity_j1", …): by quantity, then by joint."""
    return tuple(f"{p}_j{k}" for p in prefixes for k in range(1, joints + 1))


def _bitrate_switch(db: Any, message: Any) -> bool:
    """The DBC's CANFD_BRS for ``message`` (Vector's attribute; default "1": switch)."""
    definition = db.dbc.attribute_definitions.get("CANFD_BRS") if db.dbc else None
    attribute = message.dbc.attributes.get("CANFD_BRS") if message.dbc else None
    if attribute is not None:
        value = attribute.value
        if definition is not None and definition.choices:
            value = definition.choices[int(value)]
    elif definition is not None and definition.default_value is not None:
        value = definition.default_value
    else:
        return True
    return str(value) == "1"


class LtcFdProtocol(LtcProtocolBase):
    """Encode and decode LTC-1F frames for ``n_joints`` joints (1..6).

    The per-cycle frames are CAN FD with bit-rate switch; :meth:`decode` refuses a CYCLE_FB or
    CYCLE_CMD that arrives as a classic frame, and a HOST_REQUEST or heartbeat that arrives as
    CAN FD. Joints beyond ``n_joints`` are sent as 0 and ignored on reception.
    """

    profile = "fd"
    protocol_name = "LTC-1F"
    command_counter_modulus = 1 << 16  # CYCLE_CMD.counter: all 16 bits (§10.3)

    def __init__(self, n_joints: int = 6, dbc_path: str | Path = DEFAULT_FD_DBC_PATH) -> None:
        super().__init__(n_joints, dbc_path)
        self._cycle = self._by_name[CYCLE_FB]
        self._command = self._by_name[CYCLE_CMD]
        self._zeros = [0.0] * (self.max_joints - self.n_joints)
        #: ids of the frames the controller sends every cycle
        self.cycle_frame_ids = frozenset([self._cycle.frame_id])

    def _max_joints(self, db: Any) -> int:
        try:
            fb = {s.name for s in db.get_message_by_name(CYCLE_FB).signals}
            cmd = {s.name for s in db.get_message_by_name(CYCLE_CMD).signals}
        except KeyError as exc:
            raise ConfigError(f"{self.dbc_path}: message {exc} missing") from None
        joints = 0
        while f"position_j{joints + 1}" in fb:
            joints += 1
        for k in range(1, joints + 1):
            want = {f"velocity_j{k}", f"current_j{k}"} - fb
            want |= {f"position_cmd_j{k}", f"velocity_cmd_j{k}"} - cmd
            if want:
                raise ConfigError(f"{self.dbc_path}: joint {k} lacks {sorted(want)}")
        return joints

    def _profile_specs(self, db: Any) -> list[FrameSpec]:
        n, all_joints = self.n_joints, self.max_joints
        fb_codec = self._compile(db, CYCLE_FB)
        cmd_codec = self._compile(db, CYCLE_CMD)
        for codec in (fb_codec, cmd_codec):
            if not codec.is_fd:
                raise ConfigError(
                    f"{self.dbc_path}: {codec.name} must be a CAN FD frame "
                    '(BA_ "VFrameFormat" BO_ ... 14, StandardCAN_FD)'
                )
        check_enum_against_dbc(db, CYCLE_FB, "state", ControllerState)
        check_enum_against_dbc(db, CYCLE_FB, "fault_code", FaultCode)

        fb = FrameSpec(
            fb_codec,
            "cycle_fb",
            bitrate_switch=_bitrate_switch(db, db.get_message_by_name(CYCLE_FB)),
        )
        quantities = ("position", "velocity", "current")
        fb.encode = fb_codec.encoder(STATUS_SIGNALS + _joint_signals(quantities, all_joints))
        fb_values = fb_codec.decoder(STATUS_SIGNALS + _joint_signals(quantities, n))
        n_status = len(STATUS_SIGNALS)

        def decode_cycle(data: bytearray) -> CycleFeedbackFrame:
            values = fb_values(data)
            status = self._decode_status(fb, values[:n_status])
            joints = values[n_status:]
            return CycleFeedbackFrame(status, joints[:n], joints[n : 2 * n], joints[2 * n :])

        fb.decode = decode_cycle

        cmd = FrameSpec(
            cmd_codec,
            "cycle_cmd",
            crc=crc16_of_frame(cmd_codec.frame_id),
            crc_bytes=2,
            bitrate_switch=_bitrate_switch(db, db.get_message_by_name(CYCLE_CMD)),
        )
        commands = ("position_cmd", "velocity_cmd")
        cmd.encode = cmd_codec.encoder(
            ("counter", "hold", *_joint_signals(commands, all_joints), "crc")
        )
        cmd_values = cmd_codec.decoder(("counter", "hold", *_joint_signals(commands, n)))

        def decode_command(data: bytearray) -> CommandSetFrame:
            values = cmd_values(data)
            return CommandSetFrame(values[0], bool(values[1]), values[2 : 2 + n], values[2 + n :])

        cmd.decode = decode_command
        return [fb, cmd]

    # --- ids --------------------------------------------------------------------------------
    @property
    def cycle_feedback_id(self) -> int:
        return self._cycle.frame_id

    @property
    def command_set_id(self) -> int:
        return self._command.frame_id

    # --- encode -----------------------------------------------------------------------------
    def encode_cycle(
        self,
        status: ControllerStatus,
        q_rad: Sequence[float] | np.ndarray,
        dq_rad_s: Sequence[float] | np.ndarray,
        current_a: Sequence[float] | np.ndarray,
    ) -> can.Message:
        """CYCLE_FB: the status and ``n_joints`` positions, velocities and currents."""
        spec = self._cycle
        status_values = self._status_values(spec, status)
        pad = self._zeros
        q = self._joint_values(q_rad, "CYCLE_FB positions") + pad
        dq = self._joint_values(dq_rad_s, "CYCLE_FB velocities") + pad
        cur = self._joint_values(current_a, "CYCLE_FB currents") + pad
        return self._message(spec, spec.encode(*status_values, *q, *dq, *cur))

    def encode_command_set(
        self,
        counter: int,
        q_cmd_rad: Sequence[float] | np.ndarray,
        dq_cmd_rad_s: Sequence[float] | np.ndarray,
        hold: bool,
    ) -> can.Message:
        """CYCLE_CMD with its CRC-16; ``counter`` is the answered cycle_counter (16 bits)."""
        spec = self._command
        pad = self._zeros
        q = self._joint_values(q_cmd_rad, "CYCLE_CMD positions") + pad
        dq = self._joint_values(dq_cmd_rad_s, "CYCLE_CMD velocities") + pad
        hold_bit = 1 if hold is True else 0 if hold is False else hold
        return self._message(spec, spec.encode(counter, hold_bit, *q, *dq, 0))

    def encode(self, frame: LtcFdFrame) -> can.Message:
        """Encode any frame tuple of this module (the inverse of :meth:`decode`)."""
        if isinstance(frame, CycleFeedbackFrame):
            return self.encode_cycle(*frame)
        if isinstance(frame, CommandSetFrame):
            return self.encode_command_set(
                frame.counter, frame.q_cmd_rad, frame.dq_cmd_rad_s, frame.hold
            )
        if isinstance(frame, HostRequestFrame):
            return self.encode_request(*frame)
        if isinstance(frame, Heartbeat):
            return self.encode_heartbeat(*frame)
        raise FrameError(f"cannot encode {type(frame).__name__}: not an LTC-1F frame")

    # --- the controller side ----------------------------------------------------------------
    def feedback_frames(
        self,
        status: ControllerStatus,
        q_rad: Sequence[float] | np.ndarray,
        dq_rad_s: Sequence[float] | np.ndarray,
        current_a: Sequence[float] | np.ndarray,
    ) -> list[can.Message]:
        """``[CYCLE_FB]``: one frame carries, and completes, the whole cycle (§10.4)."""
        return [self.encode_cycle(status, q_rad, dq_rad_s, current_a)]

    def joint_commands(self, frame: Any) -> tuple[JointCommandFrame, ...]:
        """One JointCommandFrame per configured joint for a CYCLE_CMD; () for other frames.

        Each carries the set's 16-bit counter and hold flag, so a controller that assembles
        sets joint by joint (LTC-1) gets a complete set from one frame.
        """
        if not isinstance(frame, CommandSetFrame):
            return ()
        return tuple(
            JointCommandFrame(k + 1, q, dq, frame.hold, frame.counter)
            for k, (q, dq) in enumerate(zip(frame.q_cmd_rad, frame.dq_cmd_rad_s, strict=True))
        )


class LtcFdAdapter(CanAdapter):
    """LTC-1F seen from the host: one CYCLE_FB is one cycle, one CYCLE_CMD answers it.

    A valid CYCLE_FB is a complete cycle; a bad one (wrong length, classic instead of CAN FD,
    extended id, RTR, a value out of range, an unknown enum value) is counted in
    :attr:`stats` and its cycle lost. There is nothing to assemble, so a bad frame cannot
    spoil a neighbouring cycle.
    """

    name = "ltc_fd"
    counter_modulus = 1 << 16  # CYCLE_FB.cycle_counter is 16 bits
    host_heartbeat_timeout_s = 0.5  # DBC comment on HEARTBEAT_HOST
    max_joints = 6

    def __init__(self, n_joints: int = 6, dbc_path: str | Path = DEFAULT_FD_DBC_PATH) -> None:
        super().__init__(n_joints)
        self.protocol = LtcFdProtocol(n_joints, dbc_path)
        self._cycle_id = self.protocol.cycle_feedback_id
        self._request_counter = 0

    def feed(self, msg: can.Message) -> CycleFeedback | None:
        stats = self.stats
        stats.frames += 1
        try:
            frame = self.protocol.decode(msg)
        except FrameError as exc:
            stats.bad_frames += 1
            stats.last_error = str(exc)
            if msg.arbitration_id == self._cycle_id and not msg.is_error_frame:
                stats.corrupt_cycles += 1
            return None
        if frame is None:
            stats.unknown_frames += 1
            return None
        if not isinstance(frame, CycleFeedbackFrame):
            return None  # heartbeats; another host's commands and requests
        stats.cycles += 1
        status = frame.status
        return cycle_feedback(status, frame.q_rad, frame.dq_rad_s, frame.current_a)

    def command_frames(
        self, counter: int, q_cmd_rad: np.ndarray, dq_cmd_rad_s: np.ndarray, hold: bool
    ) -> list[can.Message]:
        q, dq = command_arrays(q_cmd_rad, dq_cmd_rad_s, self.n_joints, "CYCLE_CMD")
        return [self.protocol.encode_command_set(int(counter) & 0xFFFF, q, dq, bool(hold))]

    def request_frames(self, request: HostRequest) -> list[can.Message]:
        msg = self.protocol.encode_request(request, self._request_counter)
        self._request_counter = (self._request_counter + 1) & 0xFF
        return [msg]

    def heartbeat_frame(self) -> can.Message:
        return self.protocol.encode_heartbeat("HOST", NmtState.OPERATIONAL)

    def is_cycle_frame(self, msg: can.Message) -> bool:
        return msg.arbitration_id == self._cycle_id


# --- wire time (§10.5) ----------------------------------------------------------------------
#: Valid CAN FD payload lengths [bytes] (ISO 11898-1:2015, DLC 0..15).
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


@dataclass(frozen=True)
class BitRates:
    """Bus bit rates [bit/s]: arbitration (nominal) and CAN FD data phase (with BRS)."""

    nominal_bps: float = 1e6
    data_bps: float = 5e6

    def __post_init__(self) -> None:
        if not (self.nominal_bps > 0 and self.data_bps >= self.nominal_bps):
            raise ConfigError(f"bit rates {self} must be > 0 with data >= nominal")


def classic_frame_bits(data_bytes: int, *, worst_case: bool = True) -> int:
    """Bits of a classic CAN 2.0A data frame, 3-bit intermission included.

    47 + 8n bits, plus up to ⌊(34 + 8n − 1)/4⌋ stuff bits in the 34 + 8n bits from SOF to the
    end of the CRC (Davis et al., "CAN schedulability analysis: refuted, revisited and
    revised", Real-Time Systems 35, 2007): 135 bits for 8 bytes, 65 for 1.
    """
    if not 0 <= data_bytes <= 8:
        raise ConfigError(f"classic CAN carries 0..8 data bytes, not {data_bytes}")
    stuffed = 34 + 8 * data_bytes
    return 47 + 8 * data_bytes + ((stuffed - 1) // 4 if worst_case else 0)


def fd_frame_bits(data_bytes: int, *, worst_case: bool = True) -> tuple[int, int]:
    """(nominal-rate bits, data-rate bits) of a CAN FD frame, 11-bit id, BRS set.

    Nominal phase: SOF, 11 id bits, RRS, IDE, FDF, res, BRS (17), then CRC delimiter, ACK,
    ACK delimiter, 7 EOF and 3 intermission bits (13). Data phase: ESI, 4 DLC bits, the data,
    the 4-bit stuff count, the CRC (17 bits up to 16 data bytes, 21 above) and its fixed stuff
    bits (6 resp. 7, one before the stuff count and one after every 4 bits; ISO 11898-1:2015).
    Dynamic stuff bits, from SOF to the end of the data, are at most
    ⌊(22 + 8n − 1)/4⌋; the worst case puts 4 of them in the 17 nominal bits.
    """
    if data_bytes not in FD_LENGTHS:
        raise ConfigError(f"{data_bytes} is not a CAN FD payload length {FD_LENGTHS}")
    crc_bits, fixed_stuff = (17, 6) if data_bytes <= 16 else (21, 7)
    dynamic = (22 + 8 * data_bytes - 1) // 4 if worst_case else 0
    nominal_stuff = min(dynamic, 4)
    nominal = 17 + 13 + nominal_stuff
    data = 5 + 8 * data_bytes + (dynamic - nominal_stuff) + 4 + crc_bits + fixed_stuff
    return nominal, data


def frame_wire_time_s(
    data_bytes: int, *, fd: bool, rates: BitRates = BitRates(), worst_case: bool = True
) -> float:
    """Time one frame occupies the bus [s], intermission included."""
    if not fd:
        return classic_frame_bits(data_bytes, worst_case=worst_case) / rates.nominal_bps
    nominal, data = fd_frame_bits(data_bytes, worst_case=worst_case)
    return nominal / rates.nominal_bps + data / rates.data_bps


def cycle_wire_time_s(
    profile: Literal["classic", "fd"],
    n_joints: int = 6,
    rates: BitRates = BitRates(),
    *,
    worst_case: bool = True,
) -> float:
    """Bus time of one control cycle's frames, both directions [s] (§10.5).

    classic: n JOINT_FB + CTRL_STATUS + n JOINT_CMD (8 bytes each); fd: CYCLE_FB (64 bytes)
    + CYCLE_CMD (48 bytes). Heartbeats and HOST_REQUEST (every 100 ms) are not included:
    :func:`housekeeping_wire_time_s`.
    """
    if profile == "classic":
        return (2 * n_joints + 1) * frame_wire_time_s(
            8, fd=False, rates=rates, worst_case=worst_case
        )
    if profile == "fd":
        return frame_wire_time_s(
            64, fd=True, rates=rates, worst_case=worst_case
        ) + frame_wire_time_s(48, fd=True, rates=rates, worst_case=worst_case)
    raise ConfigError(f"profile must be 'classic' or 'fd', not {profile!r}")


def housekeeping_wire_time_s(rates: BitRates = BitRates(), *, worst_case: bool = True) -> float:
    """HEARTBEAT_CTRL + HEARTBEAT_HOST + HOST_REQUEST, sent every 100 ms in both profiles [s]."""
    one_byte = frame_wire_time_s(1, fd=False, rates=rates, worst_case=worst_case)
    return 2 * one_byte + frame_wire_time_s(8, fd=False, rates=rates, worst_case=worst_case)


def host_window_s(
    profile: Literal["classic", "fd"],
    period_s: float,
    n_joints: int = 6,
    rates: BitRates = BitRates(),
) -> float:
    """Worst case, what a period leaves the host to answer [s]: the period minus the cycle's
    frames and a burst of the 100-ms frames, all maximally stuffed."""
    if not (math.isfinite(period_s) and period_s > 0):
        raise ConfigError(f"period {period_s!r} s must be > 0")
    return period_s - cycle_wire_time_s(profile, n_joints, rates) - housekeeping_wire_time_s(rates)
