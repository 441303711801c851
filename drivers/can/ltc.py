"""LTC-1: codec and host adapter for the robot controller's external-command CAN protocol.

The frame layouts are data: ``ltc_v1.dbc`` next to this file, loaded once with cantools. This
module adds what a DBC cannot say (see ``PROTOCOL.md``): the CRC of host frames, the enums as
Python types, and strict validation both ways. Encoding a value outside its DBC range raises
:class:`~gateway.errors.FrameError` naming the signal and the value: nothing is ever clamped.
Decoding a frame with the wrong DLC, a bad CRC, an extended id, an unknown enum value, or a
remote or error frame raises :class:`~gateway.errors.FrameError` naming the frame and the fault.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any, Literal, NamedTuple

import can
import cantools
import numpy as np

from drivers.can.adapter import CanAdapter, CycleFeedback, HostRequest
from gateway.errors import ConfigError, FrameError
from gateway.messages import ControllerState

__all__ = [
    "DEFAULT_DBC_PATH",
    "ControllerStatus",
    "FaultCode",
    "Heartbeat",
    "HostRequest",
    "HostRequestFrame",
    "JointCommandFrame",
    "JointFeedback",
    "LtcAdapter",
    "LtcFrame",
    "LtcProtocol",
    "NmtState",
    "crc8_sae_j1850",
]

DEFAULT_DBC_PATH = Path(__file__).with_name("ltc_v1.dbc")


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
    counter: int  #: low byte of the cycle_counter this set answers


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


def crc8_sae_j1850(data: bytes | bytearray) -> int:
    """CRC-8/SAE-J1850: poly 0x1D, init 0xFF, not reflected, xorout 0xFF (check 0x4B)."""
    crc = 0xFF
    for byte in data:
        crc = _CRC8_J1850_TABLE[crc ^ byte]
    return crc ^ 0xFF


def frame_crc(arbitration_id: int, data7: bytes | bytearray) -> int:
    """CRC of an LTC-1 host frame: over the two little-endian id bytes, then data bytes 0..6."""
    return crc8_sae_j1850(bytes((arbitration_id & 0xFF, (arbitration_id >> 8) & 0xFF)) + data7)


@dataclass(frozen=True)
class _Spec:
    """One DBC message and what LTC-1 adds to it."""

    message: Any  # cantools.database.can.Message
    kind: Literal["fb", "cmd", "status", "request", "hb"]
    joint: int  #: 1-based for fb/cmd, 0 otherwise
    node: str  #: heartbeat node, "" otherwise
    has_crc: bool

    @property
    def name(self) -> str:
        return str(self.message.name)

    @property
    def frame_id(self) -> int:
        return int(self.message.frame_id)

    @property
    def where(self) -> str:
        return f"{self.name} (0x{self.frame_id:03X})"


@functools.lru_cache(maxsize=4)
def _load_dbc(path: str) -> Any:
    try:
        return cantools.database.load_file(path, strict=True)
    except FileNotFoundError:
        raise ConfigError(f"{path}: DBC file not found") from None
    except Exception as exc:  # cantools raises several parser-specific types
        raise ConfigError(f"{path}: not a valid DBC file: {exc}") from None


def _check_enum_against_dbc(db: Any, message: str, signal: str, enum: type[IntEnum]) -> None:
    """The enums in Python must say exactly what the DBC's VAL_ table says."""
    choices = db.get_message_by_name(message).get_signal_by_name(signal).choices or {}
    in_dbc = {int(k): str(v) for k, v in choices.items()}
    in_py = {int(e): e.name for e in enum}
    if in_dbc != in_py:
        raise ConfigError(
            f"DBC {message}.{signal} values {in_dbc} differ from {enum.__name__} {in_py}"
        )


class LtcProtocol:
    """Encode and decode LTC-1 frames for ``n_joints`` joints (1..6).

    ``encode_*`` return standard-id :class:`can.Message` objects; :meth:`decode` returns one of
    the frame tuples of this module, or ``None`` for an id LTC-1 does not define.
    """

    def __init__(self, n_joints: int = 6, dbc_path: str | Path = DEFAULT_DBC_PATH) -> None:
        self.dbc_path = Path(dbc_path)
        db = _load_dbc(str(self.dbc_path.resolve()))
        fb_count = sum(1 for m in db.messages if m.name.startswith("JOINT_FB_J"))
        if isinstance(n_joints, bool) or not isinstance(n_joints, int):
            raise ConfigError(f"LTC-1 joint count must be an integer, got {n_joints!r}")
        if not 1 <= n_joints <= fb_count:
            raise ConfigError(f"LTC-1 carries 1..{fb_count} joints, not {n_joints}")
        self.n_joints = n_joints
        self.max_joints = fb_count

        def get(name: str) -> Any:
            try:
                return db.get_message_by_name(name)
            except KeyError:
                raise ConfigError(f"{self.dbc_path}: message {name} missing") from None

        specs = [
            _Spec(get("CTRL_STATUS"), "status", 0, "", False),
            _Spec(get("HOST_REQUEST"), "request", 0, "", True),
            _Spec(get("HEARTBEAT_CTRL"), "hb", 0, "CTRL", False),
            _Spec(get("HEARTBEAT_HOST"), "hb", 0, "HOST", False),
        ]
        for k in range(1, fb_count + 1):
            specs.append(_Spec(get(f"JOINT_FB_J{k}"), "fb", k, "", False))
            specs.append(_Spec(get(f"JOINT_CMD_J{k}"), "cmd", k, "", True))
        for spec in specs:
            if spec.message.is_extended_frame:
                raise ConfigError(f"{self.dbc_path}: {spec.name} must use a standard 11-bit id")
            if spec.has_crc:
                crc = spec.message.get_signal_by_name("crc")
                if (crc.start, crc.length, spec.message.length) != (56, 8, 8):
                    raise ConfigError(f"{self.dbc_path}: {spec.name}.crc must be data byte 7")
        _check_enum_against_dbc(db, "CTRL_STATUS", "state", ControllerState)
        _check_enum_against_dbc(db, "CTRL_STATUS", "fault_code", FaultCode)
        _check_enum_against_dbc(db, "HOST_REQUEST", "request", HostRequest)
        _check_enum_against_dbc(db, "HEARTBEAT_HOST", "nmt_state", NmtState)
        _check_enum_against_dbc(db, "HEARTBEAT_CTRL", "nmt_state", NmtState)

        self._by_id: dict[int, _Spec] = {s.frame_id: s for s in specs}
        self._by_name: dict[str, _Spec] = {s.name: s for s in specs}
        self._fb = [self._by_name[f"JOINT_FB_J{k}"] for k in range(1, fb_count + 1)]
        self._cmd = [self._by_name[f"JOINT_CMD_J{k}"] for k in range(1, fb_count + 1)]
        self._status = self._by_name["CTRL_STATUS"]
        self._request = self._by_name["HOST_REQUEST"]
        self._hb = {
            "CTRL": self._by_name["HEARTBEAT_CTRL"],
            "HOST": self._by_name["HEARTBEAT_HOST"],
        }
        #: ids of the frames the controller sends every cycle (feedback and status)
        self.cycle_frame_ids = frozenset([self._status.frame_id, *(s.frame_id for s in self._fb)])

    # --- ids --------------------------------------------------------------------------------
    def feedback_id(self, joint: int) -> int:
        return self._fb[self._joint_index(joint, "JOINT_FB")].frame_id

    def command_id(self, joint: int) -> int:
        return self._cmd[self._joint_index(joint, "JOINT_CMD")].frame_id

    @property
    def status_id(self) -> int:
        return self._status.frame_id

    @property
    def request_id(self) -> int:
        return self._request.frame_id

    def heartbeat_id(self, node: Literal["CTRL", "HOST"]) -> int:
        return self._hb_spec(node).frame_id

    # --- encode -----------------------------------------------------------------------------
    def encode_feedback(
        self, joint: int, q_rad: float, dq_rad_s: float, current_a: float, counter: int
    ) -> can.Message:
        """JOINT_FB_J<joint>; ``counter`` is the low byte of the cycle counter."""
        spec = self._fb[self._joint_index(joint, "JOINT_FB")]
        values = {"position": q_rad, "velocity": dq_rad_s, "current": current_a, "counter": counter}
        return self._encode(spec, values)

    def encode_status(self, status: ControllerStatus) -> can.Message:
        """CTRL_STATUS from a :class:`ControllerStatus`."""
        spec = self._status
        state = self._enum_for_encode(ControllerState, status.state, spec, "state")
        fault = self._enum_for_encode(FaultCode, status.fault_code, spec, "fault_code")
        return self._encode(
            spec,
            {
                "cycle_counter": status.cycle_counter,
                "state": state,
                "fault_code": fault,
                "missed_cycles": status.missed_cycles,
                "estop_active": status.estop_active,
                "servo_power": status.servo_power,
                "cycle_period_us": status.cycle_period_us,
            },
        )

    def encode_command(
        self, joint: int, q_cmd_rad: float, dq_cmd_rad_s: float, hold: bool, counter: int
    ) -> can.Message:
        """JOINT_CMD_J<joint> with its CRC; ``counter`` is the low byte of the answered cycle."""
        spec = self._cmd[self._joint_index(joint, "JOINT_CMD")]
        return self._encode(
            spec,
            {
                "position_cmd": q_cmd_rad,
                "velocity_cmd": dq_cmd_rad_s,
                "hold": hold,
                "counter": counter,
                "crc": 0,
            },
        )

    def encode_request(self, request: HostRequest | int, counter: int) -> can.Message:
        """HOST_REQUEST with its CRC."""
        spec = self._request
        value = self._enum_for_encode(HostRequest, request, spec, "request")
        return self._encode(spec, {"request": value, "counter": counter, "crc": 0})

    def encode_heartbeat(
        self, node: Literal["CTRL", "HOST"], nmt_state: NmtState | int = NmtState.OPERATIONAL
    ) -> can.Message:
        """HEARTBEAT_CTRL or HEARTBEAT_HOST."""
        spec = self._hb_spec(node)
        value = self._enum_for_encode(NmtState, nmt_state, spec, "nmt_state")
        return self._encode(spec, {"nmt_state": value})

    def encode(self, frame: LtcFrame) -> can.Message:
        """Encode any frame tuple of this module (the inverse of :meth:`decode`)."""
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

    # --- decode -----------------------------------------------------------------------------
    def decode(self, msg: can.Message) -> LtcFrame | None:
        """Decode one received frame; ``None`` if LTC-1 does not define its id.

        Raises FrameError for an error frame, and for a frame with an LTC-1 id that is extended,
        remote, CAN FD, of the wrong length, with a bad CRC, or with a value outside its range.
        """
        if msg.is_error_frame:
            raise FrameError(
                f"CAN error frame received (id field 0x{msg.arbitration_id:X}): "
                "the interface reported a bus error, not a data frame"
            )
        spec = self._by_id.get(msg.arbitration_id)
        if spec is None:
            return None
        where = spec.where
        if msg.is_extended_id:
            raise FrameError(
                f"{where}: arrived with an extended 29-bit id 0x{msg.arbitration_id:08X}; "
                "LTC-1 uses standard 11-bit ids only"
            )
        if msg.is_remote_frame:
            raise FrameError(f"{where}: remote (RTR) frame; LTC-1 never uses remote frames")
        if msg.is_fd:
            raise FrameError(f"{where}: CAN FD frame; LTC-1 is classic CAN")
        data = bytes(msg.data)
        length = spec.message.length
        if msg.dlc != length or len(data) != length:
            raise FrameError(
                f"{where}: DLC {msg.dlc} with {len(data)} data bytes, expected {length}"
            )
        if spec.has_crc:
            want = frame_crc(spec.frame_id, data[:7])
            if data[7] != want:
                raise FrameError(
                    f"{where}: CRC 0x{data[7]:02X} does not match 0x{want:02X} computed over "
                    "the id and data bytes 0..6"
                )
        try:
            values = spec.message.decode(data, decode_choices=False, scaling=True)
        except Exception as exc:  # cantools' DecodeError and friends
            raise FrameError(f"{where}: cannot decode: {exc}") from None
        for sig in spec.message.signals:
            v = values[sig.name]
            tol = abs(sig.scale) / 2
            if (sig.minimum is not None and v < sig.minimum - tol) or (
                sig.maximum is not None and v > sig.maximum + tol
            ):
                raise FrameError(
                    f"{where}: {sig.name} = {v} outside its range [{sig.minimum}, {sig.maximum}]"
                )
        kind = spec.kind
        if kind == "fb":
            return JointFeedback(
                spec.joint,
                float(values["position"]),
                float(values["velocity"]),
                float(values["current"]),
                int(values["counter"]),
            )
        if kind == "status":
            return ControllerStatus(
                int(values["cycle_counter"]),
                self._enum_for_decode(ControllerState, values["state"], spec, "state"),
                self._enum_for_decode(FaultCode, values["fault_code"], spec, "fault_code"),
                int(values["missed_cycles"]),
                bool(values["estop_active"]),
                bool(values["servo_power"]),
                int(values["cycle_period_us"]),
            )
        if kind == "cmd":
            return JointCommandFrame(
                spec.joint,
                float(values["position_cmd"]),
                float(values["velocity_cmd"]),
                bool(values["hold"]),
                int(values["counter"]),
            )
        if kind == "request":
            return HostRequestFrame(
                self._enum_for_decode(HostRequest, values["request"], spec, "request"),
                int(values["counter"]),
            )
        node: Literal["CTRL", "HOST"] = "CTRL" if spec.node == "CTRL" else "HOST"
        nmt = self._enum_for_decode(NmtState, values["nmt_state"], spec, "nmt_state")
        return Heartbeat(node, nmt)

    # --- helpers ----------------------------------------------------------------------------
    def _joint_index(self, joint: int, what: str) -> int:
        if isinstance(joint, bool) or not isinstance(joint, int | np.integer):
            raise FrameError(f"{what}: joint must be an integer 1..{self.n_joints}, got {joint!r}")
        if not 1 <= joint <= self.n_joints:
            raise FrameError(f"{what}: joint {joint} outside 1..{self.n_joints}")
        return int(joint) - 1

    def _hb_spec(self, node: str) -> _Spec:
        try:
            return self._hb[node]
        except KeyError:
            raise FrameError(f"heartbeat node must be 'CTRL' or 'HOST', got {node!r}") from None

    @staticmethod
    def _enum_for_encode(enum: type[IntEnum], value: Any, spec: _Spec, signal: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise FrameError(f"{spec.where}: {signal} = {value!r} is not a {enum.__name__}")
        try:
            return int(enum(int(value)))
        except ValueError:
            known = ", ".join(f"{int(e)} {e.name}" for e in enum)
            raise FrameError(f"{spec.where}: {signal} = {value!r} is not one of {known}") from None

    @staticmethod
    def _enum_for_decode(enum: type[IntEnum], value: Any, spec: _Spec, signal: str) -> Any:
        try:
            return enum(int(value))
        except ValueError:
            known = ", ".join(f"{int(e)} {e.name}" for e in enum)
            raise FrameError(
                f"{spec.where}: {signal} = {value} is not a known value ({known})"
            ) from None

    @staticmethod
    def _encode(spec: _Spec, values: dict[str, Any]) -> can.Message:
        checked: dict[str, int | float] = {}
        for sig in spec.message.signals:
            value = values[sig.name]
            if isinstance(value, bool | np.bool_):
                value = int(value)
            if not isinstance(value, int | float | np.integer | np.floating):
                raise FrameError(f"{spec.where}: {sig.name} = {value!r} is not a number")
            v = float(value)
            unit = f" {sig.unit}" if sig.unit else ""
            if not math.isfinite(v):
                raise FrameError(f"{spec.where}: {sig.name} = {value!r}{unit} is not finite")
            if (sig.minimum is not None and v < sig.minimum) or (
                sig.maximum is not None and v > sig.maximum
            ):
                raise FrameError(
                    f"{spec.where}: {sig.name} = {value!r}{unit} outside its DBC range "
                    f"[{sig.minimum}, {sig.maximum}]"
                )
            if sig.scale == 1 and sig.offset == 0:
                if not v.is_integer():
                    raise FrameError(f"{spec.where}: {sig.name} = {value!r} must be an integer")
                checked[sig.name] = int(v)
            else:
                checked[sig.name] = v
        try:
            data = bytearray(spec.message.encode(checked, scaling=True, padding=False, strict=True))
        except Exception as exc:  # cantools' EncodeError; unreachable after the checks above
            raise FrameError(f"{spec.where}: cannot encode: {exc}") from None
        if spec.has_crc:
            data[7] = frame_crc(spec.frame_id, data[:7])
        return can.Message(
            arbitration_id=spec.frame_id,
            is_extended_id=False,
            is_rx=False,
            data=data,
            dlc=len(data),
        )


class LtcAdapter(CanAdapter):
    """LTC-1 seen from the host: cycle assembly, command sets, requests and heartbeats.

    A cycle is complete when CTRL_STATUS arrives and every configured joint's JOINT_FB frame
    since the previous CTRL_STATUS carries the status's counter low byte. Any bad frame among
    the controller's per-cycle frames (or a bus error frame) drops the whole cycle: a cycle is
    either entirely valid or not reported at all.
    """

    name = "ltc_dbc"
    counter_modulus = 1 << 16  # CTRL_STATUS.cycle_counter is 16 bits
    host_heartbeat_timeout_s = 0.5  # DBC comment on HEARTBEAT_HOST
    max_joints = 6

    def __init__(self, n_joints: int = 6, dbc_path: str | Path = DEFAULT_DBC_PATH) -> None:
        super().__init__(n_joints)
        self.protocol = LtcProtocol(n_joints, dbc_path)
        self._fb: list[JointFeedback | None] = [None] * n_joints
        self._tainted = ""  #: why the cycle being assembled is already lost ("" = it is not)
        self._request_counter = 0

    def feed(self, msg: can.Message) -> CycleFeedback | None:
        stats = self.stats
        stats.frames += 1
        try:
            frame = self.protocol.decode(msg)
        except FrameError as exc:
            stats.bad_frames += 1
            stats.last_error = str(exc)
            if msg.arbitration_id == self.protocol.status_id and not msg.is_error_frame:
                # The status that would close this cycle is lost: so is the cycle.
                self._fb, self._tainted = [None] * self.n_joints, ""
                stats.corrupt_cycles += 1
            elif msg.is_error_frame or self.is_cycle_frame(msg):
                self._tainted = str(exc)
            return None
        if frame is None:
            stats.unknown_frames += 1
            return None
        if isinstance(frame, JointFeedback):
            if frame.joint <= self.n_joints:  # a bigger arm's extra joints are not ours
                self._fb[frame.joint - 1] = frame
            return None
        if isinstance(frame, ControllerStatus):
            return self._close_cycle(frame)
        return None  # heartbeats; other hosts' commands

    def _close_cycle(self, status: ControllerStatus) -> CycleFeedback | None:
        fb, tainted = self._fb, self._tainted
        self._fb, self._tainted = [None] * self.n_joints, ""
        stats = self.stats
        if tainted:
            stats.corrupt_cycles += 1
            stats.last_error = f"cycle {status.cycle_counter} dropped: {tainted}"
            return None
        low = status.cycle_counter & 0xFF
        missing = [k + 1 for k, f in enumerate(fb) if f is None or f.counter != low]
        if missing:
            stats.incomplete_cycles += 1
            stats.last_error = (
                f"cycle {status.cycle_counter} dropped: no JOINT_FB with counter {low} "
                f"for joint(s) {missing}"
            )
            return None
        stats.cycles += 1
        frames: list[JointFeedback] = fb  # type: ignore[assignment]  # none missing
        return CycleFeedback(
            counter=status.cycle_counter,
            q_rad=np.array([f.q_rad for f in frames]),
            dq_rad_s=np.array([f.dq_rad_s for f in frames]),
            current_a=np.array([f.current_a for f in frames]),
            controller_state=status.state,
            estop_active=status.estop_active,
            servo_power=status.servo_power,
            fault=status.fault_code.name,
            cycle_period_s=status.cycle_period_us * 1e-6,
            status=status,
        )

    def command_frames(
        self, counter: int, q_cmd_rad: np.ndarray, dq_cmd_rad_s: np.ndarray, hold: bool
    ) -> list[can.Message]:
        q = np.asarray(q_cmd_rad, dtype=float).reshape(-1)
        dq = np.asarray(dq_cmd_rad_s, dtype=float).reshape(-1)
        if q.shape != (self.n_joints,) or dq.shape != (self.n_joints,):
            raise FrameError(
                f"JOINT_CMD set needs {self.n_joints} positions and velocities, "
                f"got {q.size} and {dq.size}"
            )
        low = int(counter) & 0xFF
        return [
            self.protocol.encode_command(k + 1, float(q[k]), float(dq[k]), bool(hold), low)
            for k in range(self.n_joints)
        ]

    def request_frame(self, request: HostRequest) -> can.Message:
        msg = self.protocol.encode_request(request, self._request_counter)
        self._request_counter = (self._request_counter + 1) & 0xFF
        return msg

    def heartbeat_frame(self) -> can.Message:
        return self.protocol.encode_heartbeat("HOST", NmtState.OPERATIONAL)

    def is_cycle_frame(self, msg: can.Message) -> bool:
        return msg.arbitration_id in self.protocol.cycle_frame_ids
