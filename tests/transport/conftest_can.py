"""Test doubles around the CAN driver, on real in-process transports.

* :class:`FakeController` — a minimal LTC-1 controller on a :class:`SeqpacketHubBus`: sends
  feedback and status every cycle, records every frame the host sends, runs the BRAKED / HOLD /
  EXTERNAL / FAULT transitions of PROTOCOL.md §6 that the tests need, and can drop or corrupt
  chosen feedback frames.
* :class:`GatewayStub` — publishes lifecycle and I/O state on zenoh like the gateway and the
  Modbus driver (settable; can fall silent).
* :class:`ControlStub` — answers every JointState with whatever its ``policy`` returns.

Imported by ``test_can_*.py`` (the shared tests/conftest.py belongs to the whole project).
"""

from __future__ import annotations

import collections
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can
import numpy as np

from drivers.can.adapter import HostRequest
from drivers.can.ltc_frames import (
    ControllerStatus,
    FaultCode,
    Heartbeat,
    HostRequestFrame,
    JointCommandFrame,
)
from drivers.can.ltc_protocol import LtcProtocol
from gateway.errors import FrameError
from gateway.messages import (
    ControllerState,
    IoState,
    JointState,
    Keys,
    Lifecycle,
    LifecycleMsg,
    decode_json,
)
from sim_bridge.can_hub import SeqpacketHubBus

WAIT_S = 5.0
#: injected frames sent per turn of the controller's loop
INJECT_BATCH = 200


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for(cond: Callable[[], Any], timeout_s: float = WAIT_S, what: str = "condition") -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if result := cond():
            return result
        time.sleep(0.005)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@dataclass(frozen=True)
class CommandSet:
    """One complete JOINT_CMD set as the controller received it."""

    cycle_counter: int  #: the 16-bit cycle it answered
    hold: bool
    q_cmd_rad: np.ndarray
    dq_cmd_rad_s: np.ndarray
    after_status_s: float  #: arrival of its last frame − the cycle's CTRL_STATUS send time [s]
    raw: tuple[can.Message, ...]


@dataclass(frozen=True)
class SentCycle:
    cycle_counter: int
    q_rad: np.ndarray
    dq_rad_s: np.ndarray
    current_a: np.ndarray
    state: ControllerState
    t_status_s: float


class FakeController:
    """An LTC-1 controller for tests; call :meth:`start` and :meth:`stop`."""

    def __init__(
        self,
        server: SeqpacketHubBus,
        n_joints: int = 6,
        period_s: float = 0.02,
        first_counter: int = 0,
    ) -> None:
        self.server = server
        self.proto = LtcProtocol(n_joints)
        self.n = n_joints
        self.period_s = period_s
        self.counter = first_counter & 0xFFFF
        self.lock = threading.Lock()
        # plant, settable by tests (under lock)
        self.q_rad = np.linspace(-0.6, 0.6, n_joints)
        self.dq_rad_s = np.linspace(0.1, -0.1, n_joints)
        self.current_a = np.linspace(-2.0, 3.0, n_joints)
        self.q_drift_rad_per_cycle = 0.0  #: measured q creeping (sag under gravity) [rad]
        self.state = ControllerState.BRAKED
        self.fault = FaultCode.NONE
        #: 16-bit cycle counter → joint whose JOINT_FB is left out / sent with a bad DLC
        self.skip_joint: dict[int, int] = {}
        self.corrupt_joint: dict[int, int] = {}
        # what happened
        self.sent: dict[int, SentCycle] = {}
        self.sets: list[CommandSet] = []
        self.requests: list[tuple[float, HostRequestFrame]] = []
        self.heartbeats: list[tuple[float, Heartbeat]] = []
        self.bad_frames: list[str] = []
        self.late_frames = 0
        #: 16-bit cycle → joint → every command frame the host sent for that cycle, in time or
        #: late (a set that arrives after its cycle ended is dropped, but what it was is kept)
        self.command_frames: dict[int, dict[int, JointCommandFrame]] = {}
        #: 16-bit cycle counters whose next cycle is sent at once, as a controller's would be
        #: if the host missed a whole period (settable by tests, under lock)
        self.rush: set[int] = set()
        self.events: list[tuple[str, Any]] = []  #: ("request", frame) / ("set", CommandSet)
        self._pending: dict[int, tuple[JointCommandFrame, can.Message]] = {}
        #: frames another node puts on the bus, sent by this thread between its own (a server
        #: bus is serviced by one thread)
        self._inject: collections.deque[can.Message] = collections.deque()
        #: ... and frames sent inside a cycle, after its JOINT_FB frames, before its CTRL_STATUS
        self._inject_in_cycle: collections.deque[can.Message] = collections.deque()
        self._per_cycle = 0
        #: cycle counter → frames a forger sends there (settable by tests)
        self.forge: Callable[[int], list[can.Message]] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fake-controller", daemon=True)

    def start(self) -> FakeController:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)

    # --- snapshots ---------------------------------------------------------------------------
    def command_sets(self, hold: bool | None = None) -> list[CommandSet]:
        with self.lock:
            return [s for s in self.sets if hold is None or s.hold == hold]

    def sent_set(self, cycle: int) -> CommandSet | None:
        """The whole set the host sent for the 16-bit ``cycle``, in time or late (timings and
        raw frames not kept: ``after_status_s`` NaN); None unless every joint's frame came."""
        with self.lock:
            frames = self.command_frames.get(cycle, {})
            if len(frames) < self.n:
                return None
            ordered = [frames[k + 1] for k in range(self.n)]
        return CommandSet(
            cycle_counter=cycle,
            hold=any(f.hold for f in ordered),
            q_cmd_rad=np.array([f.q_cmd_rad for f in ordered]),
            dq_cmd_rad_s=np.array([f.dq_cmd_rad_s for f in ordered]),
            after_status_s=float("nan"),
            raw=(),
        )

    def sent_for(self, cycle: int) -> bool:
        """Whether the host sent any command frame for the 16-bit ``cycle``."""
        with self.lock:
            return cycle in self.command_frames

    def request_log(self) -> list[HostRequest]:
        with self.lock:
            return [f.request for _, f in self.requests]

    def inject(self, frames: list[can.Message], per_cycle: int = 0) -> None:
        """Put ``frames`` on the bus (a rogue or broken node): as fast as the bus takes them,
        between this controller's cycles, or ``per_cycle`` of them inside each cycle, between
        its JOINT_FB frames and its CTRL_STATUS, where they can replace a joint's feedback."""
        (self._inject_in_cycle if per_cycle else self._inject).extend(frames)
        self._per_cycle = per_cycle

    def injecting(self) -> int:
        return len(self._inject) + len(self._inject_in_cycle)

    def event_log(self) -> list[tuple[str, Any]]:
        with self.lock:
            return list(self.events)

    # --- the controller ------------------------------------------------------------------
    def _run(self) -> None:
        next_s = time.monotonic()
        while not self._stop.is_set():
            self._send_cycle()
            with self.lock:
                rushed = self.counter in self.rush
            if rushed:
                continue  # the next cycle now; the grid after it as before
            next_s += self.period_s
            while (left := next_s - time.monotonic()) > 0 and not self._stop.is_set():
                for _ in range(min(INJECT_BATCH, len(self._inject))):
                    self.server.send(self._inject.popleft())
                msg = self.server.recv(timeout=0.0 if self._inject else min(left, 0.05))
                if msg is not None:
                    self._on_frame(msg)

    def _send_cycle(self) -> None:
        with self.lock:
            self.counter = (self.counter + 1) & 0xFFFF
            c = self.counter
            self._pending.clear()
            self.q_rad = self.q_rad + self.q_drift_rad_per_cycle
            q, dq, cur = self.q_rad.copy(), self.dq_rad_s.copy(), self.current_a.copy()
            skip, corrupt = self.skip_joint.get(c), self.corrupt_joint.get(c)
            status = ControllerStatus(
                c,
                self.state,
                self.fault,
                0,
                self.state == ControllerState.FAULT and self.fault == FaultCode.ESTOP,
                self.state in (ControllerState.HOLD, ControllerState.EXTERNAL),
                round(self.period_s * 1e6),
            )
        for k in range(self.n):
            if skip == k + 1:
                continue
            msg = self.proto.encode_feedback(k + 1, q[k], dq[k], cur[k], c & 0xFF)
            if corrupt == k + 1:
                msg = can.Message(
                    arbitration_id=msg.arbitration_id, is_extended_id=False, data=msg.data[:7]
                )
            self.server.send(msg)
        for _ in range(min(self._per_cycle, len(self._inject_in_cycle))):
            self.server.send(self._inject_in_cycle.popleft())
        if self.forge is not None:
            for msg in self.forge(c):
                self.server.send(msg)
        status_frame = self.proto.encode_status(status)
        with self.lock:  # recorded first: the host may react before send() returns
            self.sent[c] = SentCycle(c, q, dq, cur, status.state, time.monotonic())
        self.server.send(status_frame)

    def _on_frame(self, msg: can.Message) -> None:
        now = time.monotonic()
        try:
            frame = self.proto.decode(msg)
        except FrameError as exc:
            with self.lock:
                self.bad_frames.append(str(exc))
            return
        with self.lock:
            if isinstance(frame, Heartbeat):
                self.heartbeats.append((now, frame))
            elif isinstance(frame, HostRequestFrame):
                self.requests.append((now, frame))
                self.events.append(("request", frame.request))
                self._on_request(frame.request)
            elif isinstance(frame, JointCommandFrame):
                self._on_command(frame, msg, now)

    def _on_request(self, request: HostRequest) -> None:
        if request == HostRequest.SERVO_ON and self.state == ControllerState.BRAKED:
            self.state = ControllerState.HOLD
        elif request == HostRequest.BRAKE and self.state in (
            ControllerState.HOLD,
            ControllerState.EXTERNAL,
        ):
            self.state = ControllerState.BRAKED
        elif request == HostRequest.RESET_FAULT and self.state == ControllerState.FAULT:
            self.state, self.fault = ControllerState.BRAKED, FaultCode.NONE

    def _on_command(self, frame: JointCommandFrame, msg: can.Message, now: float) -> None:
        cycle = (self.counter - ((self.counter - frame.counter) & 0xFF)) & 0xFFFF
        self.command_frames.setdefault(cycle, {})[frame.joint] = frame
        if frame.counter != self.counter & 0xFF:
            self.late_frames += 1
            return
        self._pending[frame.joint] = (frame, msg)
        if len(self._pending) < self.n:
            return
        frames = [self._pending[k + 1] for k in range(self.n)]
        self._pending.clear()
        sent = self.sent.get(self.counter)
        cset = CommandSet(
            cycle_counter=self.counter,
            hold=any(f.hold for f, _ in frames),
            q_cmd_rad=np.array([f.q_cmd_rad for f, _ in frames]),
            dq_cmd_rad_s=np.array([f.dq_cmd_rad_s for f, _ in frames]),
            after_status_s=now - sent.t_status_s if sent else float("nan"),
            raw=tuple(m for _, m in frames),
        )
        self.sets.append(cset)
        self.events.append(("set", cset))
        if self.state == ControllerState.HOLD:
            self.state = ControllerState.EXTERNAL


class GatewayStub:
    """Publishes LifecycleMsg and IoState at ``rate_hz`` until :meth:`stop`."""

    def __init__(self, session: Any, keys: Keys, rate_hz: float = 50.0) -> None:
        self.session, self.keys, self.period_s = session, keys, 1.0 / rate_hz
        self.lifecycle = Lifecycle.STOPPED
        self.enabling = False
        self.estop_ok = True
        self.silent = False
        self._seq = 0
        self._published = self.lifecycle
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gateway-stub", daemon=True)

    def start(self) -> GatewayStub:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)

    def set(self, lifecycle: Lifecycle | None = None, enabling: bool | None = None) -> None:
        if lifecycle is not None:
            self.lifecycle = lifecycle
        if enabling is not None:
            self.enabling = enabling
        self.publish()

    def publish(self) -> None:
        if self.silent:
            return
        now = time.monotonic()
        if self.lifecycle != self._published:
            self._seq += 1
            self._published = self.lifecycle
        msg = LifecycleMsg(self.lifecycle, self._seq, now, "test")
        self.session.put(self.keys.lifecycle, msg.to_bytes())
        io = IoState(now, 6.0, 4.0, 6.0, 4.0, self.enabling, self.estop_ok)
        self.session.put(self.keys.io_state, io.to_bytes())

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.publish()


class ControlStub:
    """Collects JointState and health; answers each JointState with ``policy(state)``.

    ``policy`` returns a JointCommand, raw bytes, or None (no answer).
    """

    def __init__(self, session: Any, keys: Keys) -> None:
        self.session, self.keys = session, keys
        self.lock = threading.Lock()
        self.states: list[JointState] = []
        self.health: list[dict[str, Any]] = []
        self.policy: Callable[[JointState], Any] | None = None
        self._subs = [
            session.declare_subscriber(keys.joint_state, self._on_state),
            session.declare_subscriber(keys.health("can_driver"), self._on_health),
        ]

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self._subs = []

    def joint_states(self) -> list[JointState]:
        with self.lock:
            return list(self.states)

    def last_health(self) -> dict[str, Any] | None:
        with self.lock:
            return self.health[-1] if self.health else None

    def _on_state(self, sample: Any) -> None:
        state = JointState.from_bytes(sample.payload.to_bytes())
        with self.lock:
            self.states.append(state)
            policy = self.policy
        if policy is None:
            return
        answer = policy(state)
        if answer is None:
            return
        payload = answer if isinstance(answer, bytes) else answer.to_bytes()
        self.session.put(self.keys.joint_command, payload)

    def _on_health(self, sample: Any) -> None:
        health = decode_json(sample.payload.to_bytes(), "health")
        with self.lock:
            self.health.append(health)
