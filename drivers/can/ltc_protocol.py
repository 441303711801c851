"""LTC-1: codec for the robot controller's external-command CAN protocol.

The frame layouts are data: ``ltc_v1.dbc`` next to this file, parsed once with cantools and
compiled into fast codecs (:mod:`drivers.can.codec`, bit for bit cantools' encoding). This
module, with the frame values and CRC of :mod:`drivers.can.ltc_frames`, adds what a DBC cannot
say (see ``PROTOCOL.md``): the CRC of host frames, the enums as Python types, and strict
validation both ways. Encoding a value outside its DBC range raises
:class:`~gateway.errors.FrameError` naming the signal and the value: nothing is ever clamped.
Decoding a frame with the wrong DLC, a bad CRC, an extended id, an unknown enum value, or a
remote or error frame raises :class:`~gateway.errors.FrameError` naming the frame and the fault.

:class:`LtcProtocolBase` holds what LTC-1 shares with its CAN FD profile LTC-1F
(:mod:`drivers.can.ltc_fd`, PROTOCOL.md §10): HOST_REQUEST, the heartbeats, the checks of §8.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from enum import IntEnum
from pathlib import Path
from typing import Any, ClassVar, Literal, NoReturn

import can
import cantools
import numpy as np

from drivers.can.adapter import HostRequest
from drivers.can.codec import MessageCodec, compile_message
from drivers.can.ltc_frames import (
    ControllerStatus,
    FaultCode,
    FrameSpec,
    Heartbeat,
    HostRequestFrame,
    JointCommandFrame,
    JointFeedback,
    LtcFrame,
    NmtState,
    crc8_of_frame,
)
from gateway.errors import ConfigError, FrameError
from gateway.messages import ControllerState

__all__ = [
    "DEFAULT_DBC_PATH",
    "STATUS_SIGNALS",
    "LtcProtocol",
    "LtcProtocolBase",
    "check_enum_against_dbc",
]

DEFAULT_DBC_PATH = Path(__file__).with_name("ltc_v1.dbc")


@functools.lru_cache(maxsize=4)
def _load_dbc(path: str) -> Any:
    try:
        return cantools.database.load_file(path, strict=True)
    except FileNotFoundError:
        raise ConfigError(f"{path}: DBC file not found") from None
    except Exception as exc:  # cantools raises several parser-specific types
        raise ConfigError(f"{path}: not a valid DBC file: {exc}") from None


def check_enum_against_dbc(db: Any, message: str, signal: str, enum: type[IntEnum]) -> None:
    """The enums in Python must say exactly what the DBC's VAL_ table says."""
    choices = db.get_message_by_name(message).get_signal_by_name(signal).choices or {}
    in_dbc = {int(k): str(v) for k, v in choices.items()}
    in_py = {int(e): e.name for e in enum}
    if in_dbc != in_py:
        raise ConfigError(
            f"DBC {message}.{signal} values {in_dbc} differ from {enum.__name__} {in_py}"
        )


@functools.cache
def _members(enum: type[IntEnum]) -> dict[int, Any]:
    return {int(e): e for e in enum}


def _bit(value: Any) -> Any:
    """A bool as the 0/1 the codec's fast path takes; anything else unchanged (it checks)."""
    return 1 if value is True else 0 if value is False else value


class LtcProtocolBase:
    """What both profiles of LTC-1 share.

    The DBC, parsed once with cantools and compiled into fast codecs
    (:mod:`drivers.can.codec`); HOST_REQUEST and the heartbeats (§7), which are classic frames
    in both profiles; the receiver's checks of §8 (id format, RTR, CAN FD or not, DLC, CRC,
    range, enums). Subclasses add the per-cycle frames of their profile.

    Both profiles offer the same controller-side API, so the virtual controller speaks either:
    :meth:`feedback_frames` (one cycle's frames, in sending order) and :meth:`joint_commands`
    (the per-joint commands a decoded host frame carries).
    """

    #: "classic" (LTC-1, §2) or "fd" (LTC-1F, §10)
    profile: ClassVar[str]
    #: name used in error messages
    protocol_name: ClassVar[str]
    #: JointCommandFrame.counter is the answered cycle_counter modulo this
    command_counter_modulus: ClassVar[int]

    def __init__(self, n_joints: int, dbc_path: str | Path) -> None:
        self.dbc_path = Path(dbc_path)
        db = _load_dbc(str(self.dbc_path.resolve()))
        max_joints = self._max_joints(db)
        if isinstance(n_joints, bool) or not isinstance(n_joints, int):
            raise ConfigError(
                f"{self.protocol_name} joint count must be an integer, got {n_joints!r}"
            )
        if not 1 <= n_joints <= max_joints:
            raise ConfigError(
                f"{self.protocol_name} carries 1..{max_joints} joints, not {n_joints}"
            )
        self.n_joints = n_joints
        self.max_joints = max_joints

        codec = self._compile(db, "HOST_REQUEST")
        request = FrameSpec(codec, "request", crc=crc8_of_frame(codec.frame_id), crc_bytes=1)
        self._bind_request(request)
        hbs = {
            node: FrameSpec(self._compile(db, f"HEARTBEAT_{node}"), "hb", node=node)
            for node in ("CTRL", "HOST")
        }
        for spec in hbs.values():
            self._bind_heartbeat(spec)
        specs = [request, *hbs.values(), *self._profile_specs(db)]
        for spec in specs:
            if spec.codec.is_extended_frame:
                raise ConfigError(f"{self.dbc_path}: {spec.name} must use a standard 11-bit id")
            if spec.crc is not None:
                crc = spec.codec.signals[spec.codec.signal_names.index("crc")]
                k = spec.crc_bytes
                if (crc.start_bit, crc.length_bits) != (8 * (spec.length - k), 8 * k):
                    raise ConfigError(
                        f"{self.dbc_path}: {spec.name}.crc must be the last {k} data byte(s)"
                    )
        check_enum_against_dbc(db, "HOST_REQUEST", "request", HostRequest)
        check_enum_against_dbc(db, "HEARTBEAT_HOST", "nmt_state", NmtState)
        check_enum_against_dbc(db, "HEARTBEAT_CTRL", "nmt_state", NmtState)
        self._by_id: dict[int, FrameSpec] = {s.frame_id: s for s in specs}
        if len(self._by_id) != len(specs):
            raise ConfigError(f"{self.dbc_path}: two LTC messages share an id")
        self._by_name: dict[str, FrameSpec] = {s.name: s for s in specs}
        self._request = request
        self._hb = hbs

    # --- what a profile defines -------------------------------------------------------------
    def _max_joints(self, db: Any) -> int:
        raise NotImplementedError

    def _profile_specs(self, db: Any) -> list[FrameSpec]:
        """The profile's per-cycle frames, with encode and decode bound."""
        raise NotImplementedError

    def feedback_frames(
        self,
        status: ControllerStatus,
        q_rad: Sequence[float] | np.ndarray,
        dq_rad_s: Sequence[float] | np.ndarray,
        current_a: Sequence[float] | np.ndarray,
    ) -> list[can.Message]:
        """The frames the controller sends for one cycle, in sending order (controller side).

        ``status.cycle_counter`` is the cycle's counter; the joint arrays hold ``n_joints``
        values each. Raises FrameError for a value the protocol cannot carry.
        """
        raise NotImplementedError

    def joint_commands(self, frame: Any) -> tuple[JointCommandFrame, ...]:
        """The per-joint commands a decoded frame carries (controller side); () for others."""
        raise NotImplementedError

    # --- ids --------------------------------------------------------------------------------
    @property
    def request_id(self) -> int:
        return self._request.frame_id

    def heartbeat_id(self, node: Literal["CTRL", "HOST"]) -> int:
        return self._hb_spec(node).frame_id

    # --- HOST_REQUEST and heartbeats (§7) ---------------------------------------------------
    def encode_request(self, request: HostRequest | int, counter: int) -> can.Message:
        """HOST_REQUEST with its CRC."""
        spec = self._request
        value = self._enum_for_encode(HostRequest, request, spec, "request")
        return self._message(spec, spec.encode(value, counter, 0))

    def encode_heartbeat(
        self, node: Literal["CTRL", "HOST"], nmt_state: NmtState | int = NmtState.OPERATIONAL
    ) -> can.Message:
        """HEARTBEAT_CTRL or HEARTBEAT_HOST."""
        spec = self._hb_spec(node)
        value = self._enum_for_encode(NmtState, nmt_state, spec, "nmt_state")
        return self._message(spec, spec.encode(value))

    # --- decode -----------------------------------------------------------------------------
    def decode(self, msg: can.Message) -> Any:
        """Decode one received frame; ``None`` if the protocol does not define its id.

        Raises FrameError for an error frame, and for a frame with one of the protocol's ids
        that is extended, remote, CAN FD where the DBC says classic (or the reverse), of the
        wrong length, with a bad CRC, or with a value outside its range (§8).
        """
        if msg.is_error_frame:
            raise FrameError(
                f"CAN error frame received (id field 0x{msg.arbitration_id:X}): "
                "the interface reported a bus error, not a data frame"
            )
        spec = self._by_id.get(msg.arbitration_id)
        if spec is None:
            return None
        if msg.is_extended_id:
            raise FrameError(
                f"{spec.where}: arrived with an extended 29-bit id 0x{msg.arbitration_id:08X}; "
                f"{self.protocol_name} uses standard 11-bit ids only"
            )
        if msg.is_remote_frame:
            raise FrameError(
                f"{spec.where}: remote (RTR) frame; {self.protocol_name} never uses remote frames"
            )
        if msg.is_fd != spec.is_fd:
            raise FrameError(self._fd_mismatch(spec, msg.is_fd))
        data = msg.data
        length = spec.length
        if msg.dlc != length or len(data) != length:
            raise FrameError(
                f"{spec.where}: DLC {msg.dlc} with {len(data)} data bytes, expected {length}"
            )
        if spec.crc is not None:
            k = spec.crc_bytes
            got = int.from_bytes(data[-k:], "little")
            want = spec.crc(data)
            if got != want:
                raise FrameError(
                    f"{spec.where}: CRC 0x{got:0{2 * k}X} does not match 0x{want:0{2 * k}X} "
                    f"computed over the id and data bytes 0..{length - k - 1}"
                )
        return spec.decode(data)

    # --- helpers ----------------------------------------------------------------------------
    def _compile(self, db: Any, name: str) -> MessageCodec:
        try:
            message = db.get_message_by_name(name)
        except KeyError:
            raise ConfigError(f"{self.dbc_path}: message {name} missing") from None
        try:
            return compile_message(message)
        except ConfigError as exc:
            raise ConfigError(f"{self.dbc_path}: {exc}") from None

    def _fd_mismatch(self, spec: FrameSpec, is_fd: bool) -> str:
        if is_fd:
            return f"{spec.where}: CAN FD frame; {self.protocol_name} sends it as classic CAN"
        return f"{spec.where}: classic CAN frame; {self.protocol_name} sends it as CAN FD"

    def _bind_request(self, spec: FrameSpec) -> None:
        values = spec.codec.decoder(("request", "counter"))
        requests = _members(HostRequest)

        def decode(data: bytearray) -> HostRequestFrame:
            value, counter = values(data)
            request = requests.get(value)
            if request is None:
                self._unknown_enum(HostRequest, value, spec, "request")
            return HostRequestFrame(request, counter)

        spec.encode = spec.codec.encoder(("request", "counter", "crc"))
        spec.decode = decode

    def _bind_heartbeat(self, spec: FrameSpec) -> None:
        values = spec.codec.decoder(("nmt_state",))
        node: Literal["CTRL", "HOST"] = "CTRL" if spec.node == "CTRL" else "HOST"
        nmt = _members(NmtState)

        def decode(data: bytearray) -> Heartbeat:
            (value,) = values(data)
            state = nmt.get(value)
            if state is None:
                self._unknown_enum(NmtState, value, spec, "nmt_state")
            return Heartbeat(node, state)

        spec.encode = spec.codec.encoder(("nmt_state",))
        spec.decode = decode

    def _joint_values(self, values: Any, what: str) -> list[float]:
        """``n_joints`` values as Python floats (the codec's fast path), or FrameError."""
        try:
            array = np.asarray(values, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise FrameError(f"{what}: {values!r} is not an array of numbers") from None
        if array.shape != (self.n_joints,):
            raise FrameError(f"{what} needs {self.n_joints} values, got {array.size}")
        return array.tolist()  # type: ignore[no-any-return]

    def _hb_spec(self, node: str) -> FrameSpec:
        try:
            return self._hb[node]
        except (KeyError, TypeError):
            raise FrameError(f"heartbeat node must be 'CTRL' or 'HOST', got {node!r}") from None

    @staticmethod
    def _message(spec: FrameSpec, data: bytearray) -> can.Message:
        crc = spec.crc
        if crc is not None:
            k = spec.crc_bytes
            data[-k:] = crc(data).to_bytes(k, "little")
        return can.Message(
            arbitration_id=spec.frame_id,
            is_extended_id=False,
            is_rx=False,
            data=data,
            dlc=spec.length,
            is_fd=spec.is_fd,
            bitrate_switch=spec.bitrate_switch,
        )

    @staticmethod
    def _enum_for_encode(enum: type[IntEnum], value: Any, spec: FrameSpec, signal: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise FrameError(f"{spec.where}: {signal} = {value!r} is not a {enum.__name__}")
        if int(value) not in _members(enum):
            known = ", ".join(f"{int(e)} {e.name}" for e in enum)
            raise FrameError(f"{spec.where}: {signal} = {value!r} is not one of {known}")
        return int(value)

    @staticmethod
    def _unknown_enum(enum: type[IntEnum], value: Any, spec: FrameSpec, signal: str) -> NoReturn:
        known = ", ".join(f"{int(e)} {e.name}" for e in enum)
        raise FrameError(f"{spec.where}: {signal} = {value} is not a known value ({known})")

    def _decode_status(self, spec: FrameSpec, values: Sequence[int]) -> ControllerStatus:
        """CTRL_STATUS's signals (also the head of LTC-1F's CYCLE_FB) → ControllerStatus."""
        counter, state_raw, fault_raw, missed, estop, servo, period_us = values
        state = _members(ControllerState).get(state_raw)
        if state is None:
            self._unknown_enum(ControllerState, state_raw, spec, "state")
        fault = _members(FaultCode).get(fault_raw)
        if fault is None:
            self._unknown_enum(FaultCode, fault_raw, spec, "fault_code")
        return ControllerStatus(counter, state, fault, missed, bool(estop), bool(servo), period_us)

    def _status_values(self, spec: FrameSpec, status: ControllerStatus) -> tuple[Any, ...]:
        """ControllerStatus → CTRL_STATUS's signal values, in STATUS_SIGNALS order."""
        return (
            status.cycle_counter,
            self._enum_for_encode(ControllerState, status.state, spec, "state"),
            self._enum_for_encode(FaultCode, status.fault_code, spec, "fault_code"),
            status.missed_cycles,
            _bit(status.estop_active),
            _bit(status.servo_power),
            status.cycle_period_us,
        )


#: CTRL_STATUS's signals (and the head of LTC-1F's CYCLE_FB), in ControllerStatus order.
STATUS_SIGNALS = (
    "cycle_counter",
    "state",
    "fault_code",
    "missed_cycles",
    "estop_active",
    "servo_power",
    "cycle_period_us",
)


class LtcProtocol(LtcProtocolBase):
    """Encode and decode LTC-1 frames (classic CAN, §2) for ``n_joints`` joints (1..6).

    ``encode_*`` return standard-id :class:`can.Message` objects; :meth:`decode` returns one of
    the frame tuples of :mod:`drivers.can.ltc_frames`, or ``None`` for an id LTC-1 does not
    define.
    """

    profile = "classic"
    protocol_name = "LTC-1"
    command_counter_modulus = 1 << 8  # JOINT_CMD_Jk.counter: the low byte (§2.1)

    def __init__(self, n_joints: int = 6, dbc_path: str | Path = DEFAULT_DBC_PATH) -> None:
        super().__init__(n_joints, dbc_path)
        self._fb = [self._by_name[f"JOINT_FB_J{k}"] for k in range(1, self.max_joints + 1)]
        self._cmd = [self._by_name[f"JOINT_CMD_J{k}"] for k in range(1, self.max_joints + 1)]
        self._status = self._by_name["CTRL_STATUS"]
        #: ids of the frames the controller sends every cycle (feedback and status)
        self.cycle_frame_ids = frozenset([self._status.frame_id, *(s.frame_id for s in self._fb)])

    def _max_joints(self, db: Any) -> int:
        return sum(1 for m in db.messages if m.name.startswith("JOINT_FB_J"))

    def _fd_mismatch(self, spec: FrameSpec, is_fd: bool) -> str:
        return f"{spec.where}: CAN FD frame; LTC-1 is classic CAN"  # no LTC-1 frame is FD

    def _profile_specs(self, db: Any) -> list[FrameSpec]:
        status = FrameSpec(self._compile(db, "CTRL_STATUS"), "status")
        status.encode = status.codec.encoder(STATUS_SIGNALS)
        status_values = status.codec.decoder(STATUS_SIGNALS)
        status.decode = lambda data: self._decode_status(status, status_values(data))
        check_enum_against_dbc(db, "CTRL_STATUS", "state", ControllerState)
        check_enum_against_dbc(db, "CTRL_STATUS", "fault_code", FaultCode)
        specs = [status]
        for k in range(1, self.max_joints + 1):
            fb = FrameSpec(self._compile(db, f"JOINT_FB_J{k}"), "fb", joint=k)
            fb_names = ("position", "velocity", "current", "counter")
            fb.encode = fb.codec.encoder(fb_names)
            fb.decode = functools.partial(_joint_feedback, k, fb.codec.decoder(fb_names))
            codec = self._compile(db, f"JOINT_CMD_J{k}")
            cmd = FrameSpec(codec, "cmd", joint=k, crc=crc8_of_frame(codec.frame_id), crc_bytes=1)
            cmd.encode = cmd.codec.encoder(
                ("position_cmd", "velocity_cmd", "hold", "counter", "crc")
            )
            cmd.decode = functools.partial(
                _joint_command,
                k,
                cmd.codec.decoder(("position_cmd", "velocity_cmd", "hold", "counter")),
            )
            specs += [fb, cmd]
        return specs

    # --- ids --------------------------------------------------------------------------------
    def feedback_id(self, joint: int) -> int:
        return self._fb[self._joint_index(joint, "JOINT_FB")].frame_id

    def command_id(self, joint: int) -> int:
        return self._cmd[self._joint_index(joint, "JOINT_CMD")].frame_id

    @property
    def status_id(self) -> int:
        return self._status.frame_id

    # --- encode -----------------------------------------------------------------------------
    def encode_feedback(
        self, joint: int, q_rad: float, dq_rad_s: float, current_a: float, counter: int
    ) -> can.Message:
        """JOINT_FB_J<joint>; ``counter`` is the low byte of the cycle counter."""
        spec = self._fb[self._joint_index(joint, "JOINT_FB")]
        return self._message(spec, spec.encode(q_rad, dq_rad_s, current_a, counter))

    def encode_status(self, status: ControllerStatus) -> can.Message:
        """CTRL_STATUS from a :class:`ControllerStatus`."""
        spec = self._status
        return self._message(spec, spec.encode(*self._status_values(spec, status)))

    def encode_command(
        self, joint: int, q_cmd_rad: float, dq_cmd_rad_s: float, hold: bool, counter: int
    ) -> can.Message:
        """JOINT_CMD_J<joint> with its CRC; ``counter`` is the low byte of the answered cycle."""
        spec = self._cmd[self._joint_index(joint, "JOINT_CMD")]
        return self._message(spec, spec.encode(q_cmd_rad, dq_cmd_rad_s, _bit(hold), counter, 0))

    def encode(self, frame: LtcFrame) -> can.Message:
        """Encode any frame tuple of :mod:`drivers.can.ltc_frames` (inverse of :meth:`decode`)."""
        if isinstance(frame, ControllerStatus):
            return self.encode_status(frame)
        if isinstance(frame, JointFeedback):
            return self.encode_feedback(*frame)
        if isinstance(frame, JointCommandFrame):
            return self.encode_command(*frame)
        if isinstance(frame, HostRequestFrame):
            return self.encode_request(*frame)
        if isinstance(frame, Heartbeat):
            return self.encode_heartbeat(*frame)
        raise FrameError(f"cannot encode {type(frame).__name__}: not an LTC-1 frame")

    # --- the controller side ----------------------------------------------------------------
    def feedback_frames(
        self,
        status: ControllerStatus,
        q_rad: Sequence[float] | np.ndarray,
        dq_rad_s: Sequence[float] | np.ndarray,
        current_a: Sequence[float] | np.ndarray,
    ) -> list[can.Message]:
        """JOINT_FB_J1..Jn then CTRL_STATUS, the order of §3 (the status closes the cycle)."""
        status_msg = self.encode_status(status)
        low = int(status.cycle_counter) & 0xFF
        q = self._joint_values(q_rad, "JOINT_FB positions")
        dq = self._joint_values(dq_rad_s, "JOINT_FB velocities")
        cur = self._joint_values(current_a, "JOINT_FB currents")
        frames = []
        for k in range(self.n_joints):
            spec = self._fb[k]
            frames.append(self._message(spec, spec.encode(q[k], dq[k], cur[k], low)))
        frames.append(status_msg)
        return frames

    def joint_commands(self, frame: Any) -> tuple[JointCommandFrame, ...]:
        """``(frame,)`` for a JOINT_CMD_Jk of a configured joint; () for any other frame."""
        if isinstance(frame, JointCommandFrame) and frame.joint <= self.n_joints:
            return (frame,)
        return ()

    # --- helpers ----------------------------------------------------------------------------
    def _joint_index(self, joint: int, what: str) -> int:
        if isinstance(joint, bool) or not isinstance(joint, int | np.integer):
            raise FrameError(f"{what}: joint must be an integer 1..{self.n_joints}, got {joint!r}")
        if not 1 <= joint <= self.n_joints:
            raise FrameError(f"{what}: joint {joint} outside 1..{self.n_joints}")
        return int(joint) - 1


def _joint_feedback(
    joint: int, values: Callable[[bytearray], tuple[Any, ...]], data: bytearray
) -> JointFeedback:
    q, dq, current, counter = values(data)
    return JointFeedback(joint, q, dq, current, counter)


def _joint_command(
    joint: int, values: Callable[[bytearray], tuple[Any, ...]], data: bytearray
) -> JointCommandFrame:
    q, dq, hold, counter = values(data)
    return JointCommandFrame(joint, q, dq, bool(hold), counter)
