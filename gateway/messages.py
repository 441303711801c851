"""Messages carried on the zenoh bus, and their key expressions.

High-rate messages (joint state, joint command, I/O state, pressure set-points) are fixed
little-endian binary layouts: a 4-byte magic naming the type, a 1-byte layout version, then
fields. Decoding checks the magic, version, length and that every float is finite, and raises
:class:`~gateway.errors.MessageError` naming what was wrong. Low-rate messages (lifecycle,
health, operator requests) are UTF-8 JSON objects.

Stamps are ``time.monotonic()`` seconds [s]. CLOCK_MONOTONIC is one clock for every process on
the machine, so a stamp taken in the CAN driver can be aged in the control process.
"""

from __future__ import annotations

import functools
import json
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, ClassVar

import numpy as np

from gateway.errors import MessageError

LAYOUT_VERSION = 1


class Keys:
    """Zenoh key expressions, all below one configurable prefix (default ``lt``)."""

    def __init__(self, prefix: str = "lt") -> None:
        if not prefix or prefix.startswith("/") or prefix.endswith("/") or "*" in prefix:
            raise MessageError(f"zenoh key prefix {prefix!r} must be a plain path like 'lt'")
        self.prefix = prefix
        #: JointState, published by the CAN driver once per controller cycle.
        self.joint_state = f"{prefix}/state/joints"
        #: StateWindow, published by the CAN driver every [can] state_window_s: the joint
        #: states for readers that are not on the cycle (the gateway).
        self.state_window = f"{prefix}/state/window"
        #: IoState, published by the Modbus driver at its poll rate.
        self.io_state = f"{prefix}/state/io"
        #: JointCommand, published by the control process, one per JointState.
        self.joint_command = f"{prefix}/cmd/joints"
        #: PressureSetpoint, published by the control process.
        self.pressure_setpoint = f"{prefix}/cmd/pressure"
        #: Lifecycle (JSON), published by the gateway on change and at LIFECYCLE_RATE_HZ.
        self.lifecycle = f"{prefix}/gateway/lifecycle"
        #: Queryable answering operator requests (JSON): start, stop, status, reset.
        self.request = f"{prefix}/gateway/request"
        #: Control diagnostics (JSON, low rate): desired torque, estimates, loop statistics.
        self.control_telemetry = f"{prefix}/telemetry/control"
        #: Driver diagnostics (JSON, low rate).
        self.driver_telemetry = f"{prefix}/telemetry/drivers"
        #: Excitation-plan progress (JSON): plan_id, state running|done|failed, segments with
        #: their controller-cycle ranges, published by the control process.
        self.experiment = f"{prefix}/telemetry/experiment"

    def health(self, process: str) -> str:
        """Key of a process's heartbeat (JSON, HEALTH_RATE_HZ)."""
        return f"{self.prefix}/health/{process}"

    @property
    def health_all(self) -> str:
        return f"{self.prefix}/health/*"


LIFECYCLE_RATE_HZ = 20.0
HEALTH_RATE_HZ = 10.0


class ControllerState(IntEnum):
    """State of the closed robot controller as reported in its status frame."""

    BRAKED = 0  #: brakes engaged, servo off (power-on default)
    HOLD = 1  #: servo on, holding the last valid position command
    EXTERNAL = 2  #: servo on, tracking external position/velocity commands
    FAULT = 3  #: brakes engaged after a fault; needs a reset request


#: the controller states in which the drives hold the arm or follow commands: servo on
SERVO_ON = (ControllerState.HOLD, ControllerState.EXTERNAL)


class Lifecycle(IntEnum):
    """Gateway lifecycle. STOPPED is the default and the state every error path leads back to."""

    STOPPED = 0  #: brakes on; nothing moves
    READY = 1  #: servo on, holding position; waiting for the enabling device
    TEACHING = 2  #: enabling device held; the control process's commands reach the robot
    FAULT = 3  #: an error stopped the robot; `reset` once the cause is gone
    IDENTIFYING = 4  #: enabling device held; the control process plays an excitation plan
    REPLAYING = 5  #: enabling device held; the control process plays a taught program back


_CONTROLLER_STATES = tuple(ControllerState)

#: Lifecycle states in which the control process's commands may reach the robot.
COMMANDING = (Lifecycle.TEACHING, Lifecycle.IDENTIFYING, Lifecycle.REPLAYING)
#: Lifecycle states in which the control process plays a plan (the lifecycle's ``plan``).
PLAYING = (Lifecycle.IDENTIFYING, Lifecycle.REPLAYING)


def _finite(name: str, values: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise MessageError(f"{name}[{bad}] is {values.flat[bad]!r}; every value must be finite")
    return values


def _check_header(
    data: bytes, magic: bytes, what: str, min_len: int, version: int = LAYOUT_VERSION
) -> None:
    if not isinstance(data, bytes | bytearray | memoryview):
        raise MessageError(f"{what}: payload must be bytes, got {type(data).__name__}")
    if len(data) < min_len:
        raise MessageError(f"{what}: payload is {len(data)} bytes, shorter than its header")
    if bytes(data[:4]) != magic:
        raise MessageError(f"{what}: magic {bytes(data[:4])!r} is not {magic!r}")
    if data[4] != version:
        raise MessageError(f"{what}: layout version {data[4]} unsupported (want {version})")


#: JointState.flags bits. The controller's e-stop and servo power, and how the driver answered
#: the previous cycle (the one ``q_cmd_rad``/``dq_cmd_rad_s`` echo) when it was not with the
#: control process's command: a hold (or no answer at all, which freezes the controller's
#: reference), or a coast on the last command. The recorder's export leaves the cycles after
#: those out of identification data.
FLAG_ESTOP = 1
FLAG_SERVO_POWER = 2
FLAG_PREV_HOLD = 4
FLAG_PREV_COAST = 8


@dataclass(frozen=True)
class JointState:
    """One controller cycle of joint feedback, as seen by the CAN driver.

    ``q_cmd_rad``/``dq_cmd_rad_s`` echo the command the driver last sent to the controller
    (hold or forwarded), so the control process can take over without a bump.
    """

    MAGIC: ClassVar[bytes] = b"LTJS"
    _HEAD: ClassVar[struct.Struct] = struct.Struct("<4sBBIdBBd")

    cycle: int  #: controller cycle counter (16 bit on the wire, widened by the driver)
    stamp_s: float  #: driver monotonic time when the full cycle had arrived [s]
    controller_state: ControllerState
    flags: int  #: FLAG_* bits: e-stop, servo power, how the previous cycle was answered
    q_rad: np.ndarray
    dq_rad_s: np.ndarray
    current_a: np.ndarray
    q_cmd_rad: np.ndarray
    dq_cmd_rad_s: np.ndarray
    #: the controller's command cycle (from its status frame) [s]; 0 = not reported
    cycle_period_s: float = 0.0

    @property
    def n(self) -> int:
        return int(self.q_rad.shape[0])

    @staticmethod
    @functools.cache
    def _layout(n: int) -> struct.Struct:
        return struct.Struct(f"<4sBBIdBBd{5 * n}d")

    @classmethod
    def pack(
        cls,
        cycle: int,
        stamp_s: float,
        controller_state: int,
        flags: int,
        cycle_period_s: float,
        q_rad: Sequence[float],
        dq_rad_s: Sequence[float],
        current_a: Sequence[float],
        q_cmd_rad: Sequence[float],
        dq_cmd_rad_s: Sequence[float],
    ) -> bytes:
        """The wire bytes of a JointState, straight from float sequences (the CAN driver's hot
        path: one precompiled struct, no intermediate arrays). The caller guarantees finite
        values of equal length (they come from decoded CAN frames and sent commands)."""
        n = len(q_rad)
        return cls._layout(n).pack(
            cls.MAGIC,
            LAYOUT_VERSION,
            n,
            cycle & 0xFFFFFFFF,
            stamp_s,
            controller_state,
            flags,
            cycle_period_s,
            *q_rad,
            *dq_rad_s,
            *current_a,
            *q_cmd_rad,
            *dq_cmd_rad_s,
        )

    def to_bytes(self) -> bytes:
        head = self._HEAD.pack(
            self.MAGIC,
            LAYOUT_VERSION,
            self.n,
            self.cycle & 0xFFFFFFFF,
            self.stamp_s,
            int(self.controller_state),
            self.flags,
            self.cycle_period_s,
        )
        body = np.concatenate(
            [self.q_rad, self.dq_rad_s, self.current_a, self.q_cmd_rad, self.dq_cmd_rad_s]
        )
        return head + body.astype("<f8").tobytes()

    @classmethod
    def from_bytes(cls, data: bytes) -> JointState:
        _check_header(data, cls.MAGIC, "JointState", cls._HEAD.size)
        _, _, n, cycle, stamp, cstate, flags, period = cls._HEAD.unpack_from(data)
        if not 1 <= n <= 16:
            raise MessageError(f"JointState: joint count {n} outside 1..16")
        want = cls._HEAD.size + 5 * n * 8
        if len(data) != want:
            raise MessageError(f"JointState: {len(data)} bytes, expected {want} for {n} joints")
        if not (math.isfinite(stamp) and math.isfinite(period) and period >= 0):
            raise MessageError(f"JointState: stamp_s {stamp} / cycle_period_s {period} invalid")
        if not 0 <= cstate < len(_CONTROLLER_STATES):
            raise MessageError(f"JointState: controller_state {cstate} unknown")
        # One copy and one finiteness check for the whole block (the hot path of every
        # subscriber); the offending field is looked for only when there is one.
        body = np.frombuffer(data, dtype="<f8", offset=cls._HEAD.size).reshape(5, n).copy()
        if not np.isfinite(body).all():
            names = ("q_rad", "dq_rad_s", "current_a", "q_cmd_rad", "dq_cmd_rad_s")
            for i, nm in enumerate(names):
                _finite(f"JointState.{nm}", body[i])
        q, dq, i_a, q_cmd, dq_cmd = body
        state = _CONTROLLER_STATES[cstate]
        return cls(cycle, stamp, state, flags, q, dq, i_a, q_cmd, dq_cmd, cycle_period_s=period)


@dataclass(frozen=True)
class StateWindow:
    """The joint states of a window of controller cycles, for a reader that is not on the
    cycle (the gateway supervises at 100 Hz and has no use for 500 states a second): how many
    states, the fastest joint speed any of them read, each joint's lowest and highest position
    among them, and the newest state whole (its JointState bytes, decoded by the reader). The
    CAN driver publishes one every ``[can] state_window_s`` and at once when the controller's
    state or its e-stop or servo-power flag changes (drivers/can/rt/src/window.rs
    StateWindowBuilder)."""

    MAGIC: ClassVar[bytes] = b"LTSW"
    _HEAD: ClassVar[struct.Struct] = struct.Struct("<4sBBId")  #: magic, version, n, states, speed

    states: int  #: controller cycles in the window (≥ 1)
    max_speed_rad_s: float  #: the fastest joint's measured speed in any of them [rad/s]
    q_lo_rad: np.ndarray  #: each joint's lowest measured position in the window [rad]
    q_hi_rad: np.ndarray  #: ... and its highest [rad]
    newest: bytes  #: the window's last JointState payload

    def to_bytes(self) -> bytes:
        n = int(self.q_lo_rad.shape[0])
        head = self._HEAD.pack(self.MAGIC, LAYOUT_VERSION, n, self.states, self.max_speed_rad_s)
        bounds = np.concatenate([self.q_lo_rad, self.q_hi_rad]).astype("<f8").tobytes()
        return head + bounds + bytes(self.newest)

    @classmethod
    def from_bytes(cls, data: bytes) -> StateWindow:
        """Check the window's own fields (the newest state is checked by whoever decodes it)."""
        _check_header(data, cls.MAGIC, "StateWindow", cls._HEAD.size)
        _, _, n, states, speed = cls._HEAD.unpack_from(data)
        if not 1 <= n <= 16:
            raise MessageError(f"StateWindow: joint count {n} outside 1..16")
        end = cls._HEAD.size + 2 * n * 8
        if len(data) <= end:
            raise MessageError(f"StateWindow: {len(data)} bytes, no state after {n} bounds")
        if states < 1 or not (math.isfinite(speed) and speed >= 0.0):
            raise MessageError(f"StateWindow: {states} states / max speed {speed} invalid")
        lo, hi = np.frombuffer(data, dtype="<f8", count=2 * n, offset=cls._HEAD.size).reshape(2, n)
        _finite("StateWindow.q_lo_rad", lo)
        _finite("StateWindow.q_hi_rad", hi)
        if (lo > hi).any():
            raise MessageError("StateWindow: a joint's lowest position is above its highest")
        return cls(states, speed, lo, hi, bytes(data[end:]))


@dataclass(frozen=True)
class JointCommand:
    """Position/velocity command computed from one JointState (eq. (21) of the paper).

    Its three stamps time the loop's stages (every process reads the same CLOCK_MONOTONIC):
    the JointState's driver stamp, the control process's receipt of it, and publication.
    """

    MAGIC: ClassVar[bytes] = b"LTJC"
    #: layout 2 added ``state_rx_stamp_s``
    VERSION: ClassVar[int] = 2
    _HEAD: ClassVar[struct.Struct] = struct.Struct("<4sBBIddd")

    cycle: int  #: the JointState.cycle this command answers
    state_stamp_s: float  #: JointState.stamp_s it was computed from: ages the command [s]
    sent_stamp_s: float  #: control-process monotonic time at publication [s]
    q_cmd_rad: np.ndarray
    dq_cmd_rad_s: np.ndarray
    #: control-process monotonic time the JointState arrived [s]; 0 = not reported
    state_rx_stamp_s: float = 0.0

    @property
    def n(self) -> int:
        return int(self.q_cmd_rad.shape[0])

    def to_bytes(self) -> bytes:
        head = self._HEAD.pack(
            self.MAGIC,
            self.VERSION,
            self.n,
            self.cycle & 0xFFFFFFFF,
            self.state_stamp_s,
            self.sent_stamp_s,
            self.state_rx_stamp_s,
        )
        return head + np.concatenate([self.q_cmd_rad, self.dq_cmd_rad_s]).astype("<f8").tobytes()

    @staticmethod
    @functools.cache
    def _layout(n: int) -> struct.Struct:
        return struct.Struct(f"<4sBBIddd{2 * n}d")

    @classmethod
    def pack(
        cls,
        cycle: int,
        state_stamp_s: float,
        sent_stamp_s: float,
        q_cmd_rad: Sequence[float],
        dq_cmd_rad_s: Sequence[float],
        state_rx_stamp_s: float = 0.0,
    ) -> bytes:
        """The wire bytes of a JointCommand from float sequences (the control process's hot
        path). Raises MessageError, naming the field, on a NaN or infinity or a length
        mismatch: a command that is not finite is never sent."""
        n = len(q_cmd_rad)
        if len(dq_cmd_rad_s) != n or not 1 <= n <= 16:
            raise MessageError(f"JointCommand: {n} positions and {len(dq_cmd_rad_s)} velocities")
        for name, values in (("q_cmd_rad", q_cmd_rad), ("dq_cmd_rad_s", dq_cmd_rad_s)):
            for k, v in enumerate(values):
                if not math.isfinite(v):
                    raise MessageError(f"JointCommand.{name}[{k}] is {v!r}; must be finite")
        stamps = (state_stamp_s, sent_stamp_s, state_rx_stamp_s)
        if not all(math.isfinite(v) for v in stamps):
            raise MessageError("JointCommand: stamps must be finite")
        return cls._layout(n).pack(
            cls.MAGIC,
            cls.VERSION,
            n,
            cycle & 0xFFFFFFFF,
            *stamps,
            *q_cmd_rad,
            *dq_cmd_rad_s,
        )

    @classmethod
    def from_bytes(cls, data: bytes) -> JointCommand:
        _check_header(data, cls.MAGIC, "JointCommand", cls._HEAD.size, cls.VERSION)
        _, _, n, cycle, state_stamp, sent_stamp, rx_stamp = cls._HEAD.unpack_from(data)
        if not 1 <= n <= 16:
            raise MessageError(f"JointCommand: joint count {n} outside 1..16")
        want = cls._HEAD.size + 2 * n * 8
        if len(data) != want:
            raise MessageError(f"JointCommand: {len(data)} bytes, expected {want} for {n} joints")
        if not (np.isfinite(state_stamp) and np.isfinite(sent_stamp) and np.isfinite(rx_stamp)):
            raise MessageError("JointCommand: stamps must be finite")
        body = np.frombuffer(data, dtype="<f8", offset=cls._HEAD.size).reshape(2, n)
        q = _finite("JointCommand.q_cmd_rad", body[0].copy())
        dq = _finite("JointCommand.dq_cmd_rad_s", body[1].copy())
        return cls(cycle, state_stamp, sent_stamp, q, dq, rx_stamp)


@dataclass(frozen=True)
class IoState:
    """Cylinder pressures and safety inputs, as read over Modbus."""

    MAGIC: ClassVar[bytes] = b"LTIO"
    _FMT: ClassVar[struct.Struct] = struct.Struct("<4sBdddddBBB")
    #: the layout before the teach handle's mark button (read as "not pressed")
    _FMT_NO_MARK: ClassVar[struct.Struct] = struct.Struct("<4sBdddddBB")

    stamp_s: float  #: Modbus driver monotonic time of the poll [s]
    p2_bar: float  #: measured pressure, assist cylinder of joint 2 [bar]
    p3_bar: float  #: measured pressure, assist cylinder of joint 3 [bar]
    p2_set_bar: float  #: set-point read back from the valve [bar]
    p3_set_bar: float
    enabling: bool  #: enabling device held (3-position switch in its middle position)
    estop_ok: bool  #: e-stop chain closed (False = e-stop pressed or wire broken)
    mark: bool = False  #: the teach handle's mark button pressed (False: no such button)

    def to_bytes(self) -> bytes:
        return self._FMT.pack(
            self.MAGIC,
            LAYOUT_VERSION,
            self.stamp_s,
            self.p2_bar,
            self.p3_bar,
            self.p2_set_bar,
            self.p3_set_bar,
            int(self.enabling),
            int(self.estop_ok),
            int(self.mark),
        )

    @classmethod
    def from_bytes(cls, data: bytes) -> IoState:
        _check_header(data, cls.MAGIC, "IoState", 5)
        if len(data) == cls._FMT.size:
            _, _, stamp, p2, p3, s2, s3, en, es, mk = cls._FMT.unpack(data)
        elif len(data) == cls._FMT_NO_MARK.size:
            (_, _, stamp, p2, p3, s2, s3, en, es), mk = cls._FMT_NO_MARK.unpack(data), 0
        else:
            raise MessageError(f"IoState: {len(data)} bytes, expected {cls._FMT.size}")
        _finite("IoState(stamp, p2, p3, p2_set, p3_set)", np.array([stamp, p2, p3, s2, s3]))
        if en not in (0, 1) or es not in (0, 1) or mk not in (0, 1):
            raise MessageError(
                f"IoState: flags enabling={en} estop_ok={es} mark={mk} must be 0 or 1"
            )
        return cls(stamp, p2, p3, s2, s3, bool(en), bool(es), bool(mk))


@dataclass(frozen=True)
class PressureSetpoint:
    """Cylinder pressure set-points for the proportional valves."""

    MAGIC: ClassVar[bytes] = b"LTPS"
    _FMT: ClassVar[struct.Struct] = struct.Struct("<4sBddd")

    stamp_s: float
    p2_set_bar: float
    p3_set_bar: float

    def to_bytes(self) -> bytes:
        return self._FMT.pack(
            self.MAGIC, LAYOUT_VERSION, self.stamp_s, self.p2_set_bar, self.p3_set_bar
        )

    @classmethod
    def from_bytes(cls, data: bytes) -> PressureSetpoint:
        _check_header(data, cls.MAGIC, "PressureSetpoint", 5)
        if len(data) != cls._FMT.size:
            raise MessageError(f"PressureSetpoint: {len(data)} bytes, expected {cls._FMT.size}")
        _, _, stamp, p2, p3 = cls._FMT.unpack(data)
        _finite("PressureSetpoint(stamp, p2, p3)", np.array([stamp, p2, p3]))
        return cls(stamp, p2, p3)


@dataclass(frozen=True)
class LifecycleMsg:
    """Lifecycle announcement from the gateway (JSON)."""

    state: Lifecycle
    seq: int
    stamp_s: float
    reason: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def to_bytes(self) -> bytes:
        return encode_json(
            {
                "state": self.state.name.lower(),
                "seq": self.seq,
                "stamp_s": self.stamp_s,
                "reason": self.reason,
                **self.extra,
            }
        )

    @classmethod
    def from_bytes(cls, data: bytes) -> LifecycleMsg:
        obj = decode_json(data, "Lifecycle")
        name = str(obj.get("state", "")).upper()
        if name not in Lifecycle.__members__:
            raise MessageError(f"Lifecycle: state {obj.get('state')!r} is not one of {_STATES}")
        try:
            state = Lifecycle[name]
            seq = int(obj["seq"])
            stamp = float(obj["stamp_s"])
        except (KeyError, ValueError, TypeError) as exc:
            raise MessageError(f"Lifecycle: bad or missing field: {exc!r}") from None
        if not np.isfinite(stamp):
            raise MessageError("Lifecycle: stamp_s is not finite")
        known = {"state", "seq", "stamp_s", "reason"}
        extra = {k: v for k, v in obj.items() if k not in known}
        return cls(state, seq, stamp, str(obj.get("reason", "")), extra)


_STATES = [s.name.lower() for s in Lifecycle]


class LifecycleOrder:
    """A reader's check of the gateway's lifecycle stream: what it drops, and counts.

    The gateway numbers every change of state (``seq``) and repeats the current one at
    :data:`LIFECYCLE_RATE_HZ` with the same number and a newer stamp. A reader keeps the
    newest and drops (see :meth:`admit`):

    - ``out_of_order``: a lower ``seq``, or the same one with an older stamp: older news than
      what it has (a late "teaching" must not undo a "stopped");
    - ``conflicting``: the same ``seq`` naming another state: not what the gateway sends.

    Every process that reads the lifecycle is a child of the gateway and starts with it, so the
    numbering starts afresh only when the reader does. Freshness (the stamp's age) stays the
    reader's own deadline check."""

    def __init__(self) -> None:
        self.last: LifecycleMsg | None = None
        self.dropped: dict[str, int] = {}

    def admit(self, msg: LifecycleMsg) -> str | None:
        """None if ``msg`` is the newest (kept as :attr:`last`), else the reason it is dropped
        (counted in :attr:`dropped`)."""
        last, reason = self.last, None
        if last is not None:
            if msg.seq < last.seq or (msg.seq == last.seq and msg.stamp_s < last.stamp_s):
                reason = "out_of_order"
            elif msg.seq == last.seq and msg.state != last.state:
                reason = "conflicting"
        if reason is None:
            self.last = msg
        else:
            self.dropped[reason] = self.dropped.get(reason, 0) + 1
        return reason


def encode_json(obj: dict[str, Any]) -> bytes:
    return json.dumps(obj, allow_nan=False, separators=(",", ":")).encode()


def decode_json(data: bytes, what: str) -> dict[str, Any]:
    """Decode a JSON object payload; NaN/Infinity literals are refused."""

    def _no_constants(name: str) -> Any:
        raise MessageError(f"{what}: non-finite number {name} in JSON")

    try:
        obj = json.loads(bytes(data).decode("utf-8"), parse_constant=_no_constants)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MessageError(f"{what}: payload is not JSON: {exc}") from None
    if not isinstance(obj, dict):
        raise MessageError(f"{what}: payload must be a JSON object, got {type(obj).__name__}")
    return obj
