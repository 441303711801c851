"""CAN driver decisions with an injected clock: python-can's in-process ``virtual`` bus for CAN,
a recording stand-in for the zenoh session, and no loop thread (the test calls ``spin_once``).
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import can
import numpy as np
import pytest

from drivers.can.config import CanDriverConfig
from drivers.can.driver import CanDriver
from drivers.can.ltc import (
    ControllerStatus,
    FaultCode,
    Heartbeat,
    HostRequest,
    HostRequestFrame,
    JointCommandFrame,
    LtcProtocol,
)
from gateway.bus import BusConfig
from gateway.messages import (
    FLAG_PREV_COAST,
    FLAG_PREV_HOLD,
    ControllerState,
    IoState,
    JointCommand,
    JointState,
    Lifecycle,
    LifecycleMsg,
    decode_json,
)

N = 6
Q0 = np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
KEYS = BusConfig().keys


class Clock:
    def __init__(self, t_s: float = 1000.0) -> None:
        self.t_s = t_s

    def __call__(self) -> float:
        return self.t_s

    def advance(self, dt_s: float) -> None:
        self.t_s += dt_s


@dataclass
class _Payload:
    data: bytes

    def to_bytes(self) -> bytes:
        return self.data


@dataclass
class _Sample:
    payload: _Payload


class _Entity:
    def __init__(self, session: FakeSession, key: str) -> None:
        self.session, self.key = session, key

    def put(self, payload: bytes) -> None:
        self.session.put(self.key, payload)

    def undeclare(self) -> None:
        self.session.undeclared.append(self.key)


class FakeSession:
    """Records what the driver publishes; :meth:`deliver` plays a sample to its subscriber."""

    def __init__(self) -> None:
        self.callbacks: dict[str, Any] = {}
        self.published: list[tuple[str, bytes]] = []
        self.undeclared: list[str] = []

    def declare_publisher(self, key: str, **_: Any) -> _Entity:
        return _Entity(self, key)

    def declare_subscriber(self, key: str, callback: Any) -> _Entity:
        self.callbacks[key] = callback
        return _Entity(self, key)

    def put(self, key: str, payload: bytes) -> None:
        self.published.append((key, bytes(payload)))

    def deliver(self, key: str, payload: bytes) -> None:
        self.callbacks[key](_Sample(_Payload(payload)))

    def joint_states(self) -> list[JointState]:
        return [JointState.from_bytes(p) for k, p in self.published if k == KEYS.joint_state]


@dataclass
class Rig:
    clock: Clock
    driver: CanDriver
    session: FakeSession
    controller_bus: can.BusABC
    proto: LtcProtocol
    config: CanDriverConfig
    counter: int = 0

    # --- the controller side ------------------------------------------------------------------
    def cycle(
        self,
        q_rad: np.ndarray = Q0,
        state: ControllerState = ControllerState.EXTERNAL,
        period_us: int = 20000,
        counter: int | None = None,
    ) -> JointState:
        """Send one controller cycle and let the driver take it; returns its JointState."""
        self.counter = (self.counter + 1) & 0xFFFF if counter is None else counter
        for k in range(N):
            fb = self.proto.encode_feedback(k + 1, float(q_rad[k]), 0.0, 0.0, self.counter & 0xFF)
            self.controller_bus.send(fb)
        status = ControllerStatus(self.counter, state, FaultCode.NONE, 0, False, True, period_us)
        self.controller_bus.send(self.proto.encode_status(status))
        n_before = len(self.session.joint_states())
        for _ in range(N + 1):
            self.driver.spin_once(0.0)
        states = self.session.joint_states()
        assert len(states) == n_before + 1, "the cycle did not produce one JointState"
        return states[-1]

    def received(self) -> list[Any]:
        """Every frame the driver sent since the last call, decoded."""
        out = []
        while (msg := self.controller_bus.recv(0.0)) is not None:
            out.append(self.proto.decode(msg))
        return out

    def command_sets(self) -> list[list[JointCommandFrame]]:
        frames = [f for f in self.received() if isinstance(f, JointCommandFrame)]
        assert len(frames) % N == 0
        return [frames[i : i + N] for i in range(0, len(frames), N)]

    # --- the zenoh side -------------------------------------------------------------------------
    def gateway(
        self, state: Lifecycle, enabling: bool = True, stamp_s: float | None = None
    ) -> None:
        now = self.clock() if stamp_s is None else stamp_s
        self.lifecycle_seq = getattr(self, "lifecycle_seq", 0) + 1  # one per announcement
        msg = LifecycleMsg(state, self.lifecycle_seq, now)
        self.session.deliver(KEYS.lifecycle, msg.to_bytes())
        io = IoState(self.clock(), 6.0, 4.0, 6.0, 4.0, enabling, True)
        self.session.deliver(KEYS.io_state, io.to_bytes())

    def command(self, js: JointState, q_rad: np.ndarray, dq_rad_s: float = 0.0, **kw: Any) -> None:
        cmd = JointCommand(
            kw.get("cycle", js.cycle),
            kw.get("state_stamp_s", js.stamp_s),
            self.clock(),
            np.asarray(q_rad, dtype=float),
            np.full(N, dq_rad_s),
        )
        self.session.deliver(KEYS.joint_command, cmd.to_bytes())


@pytest.fixture
def make_rig() -> Iterator[Any]:
    made: list[Rig] = []

    def make(**overrides: Any) -> Rig:
        channel = f"ltc-{uuid.uuid4().hex[:8]}"
        values: dict[str, Any] = {
            "transport": {"interface": "virtual", "channel": channel},
            "deadline_s": 0.010,
            "heartbeat_period_s": 0.1,
            "max_following_error_rad": 0.05,
            "max_velocity_rad_s": 1.0,
            "current_zero_cycles": 0,  # the servo at once (tests of the zero: test_can_core)
        }
        values.update(overrides)
        config = CanDriverConfig(**values)
        clock, session = Clock(), FakeSession()
        controller_bus = can.Bus(interface="virtual", channel=channel)
        driver_bus = can.Bus(interface="virtual", channel=channel)
        driver = CanDriver(config, BusConfig(), clock=clock, can_bus=driver_bus, session=session)
        driver.open()
        rig = Rig(clock, driver, session, controller_bus, LtcProtocol(N), config)
        made.append(rig)
        rig.driver_bus = driver_bus  # type: ignore[attr-defined]
        return rig

    yield make
    for rig in made:
        rig.driver.close()
        rig.driver_bus.shutdown()  # type: ignore[attr-defined]
        rig.controller_bus.shutdown()


def teaching(make_rig: Any, **overrides: Any) -> Rig:
    rig = make_rig(**overrides)
    rig.gateway(Lifecycle.TEACHING)
    rig.driver.spin_once(0.0)
    rig.received()
    return rig


# --- answering every cycle ------------------------------------------------------------------
@pytest.mark.parametrize(("period_us", "answer_by_s"), [(20000, 0.010), (4000, 0.002)])
def test_unanswered_cycle_is_held_at_the_deadline_or_before_the_next_cycle(
    make_rig, period_us, answer_by_s
):
    rig = teaching(make_rig)
    rig.cycle(period_us=period_us)
    rig.clock.advance(answer_by_s - 1e-4)
    rig.driver.spin_once(0.0)
    assert rig.command_sets() == []
    rig.clock.advance(2e-4)
    rig.driver.spin_once(0.0)
    [hold] = rig.command_sets()
    assert all(f.hold and f.dq_cmd_rad_s == 0.0 and f.counter == rig.counter for f in hold)
    np.testing.assert_allclose([f.q_cmd_rad for f in hold], Q0, atol=1e-6)
    rig.clock.advance(0.05)
    rig.driver.spin_once(0.0)
    assert rig.command_sets() == [], "a cycle is answered once"


def test_forwarded_command_and_the_jointstate_echo(make_rig):
    rig = teaching(make_rig)
    js = rig.cycle()
    np.testing.assert_allclose(js.q_cmd_rad, Q0, atol=1e-6)  # measured q before any command
    rig.clock.advance(0.002)
    rig.command(js, js.q_rad + 0.01, 0.2)
    [cmd] = rig.command_sets()
    assert all(not f.hold and f.counter == rig.counter for f in cmd)
    np.testing.assert_allclose([f.q_cmd_rad for f in cmd], Q0 + 0.01, atol=1e-6)
    np.testing.assert_allclose([f.dq_cmd_rad_s for f in cmd], 0.2, atol=1e-4)
    nxt = rig.cycle()
    np.testing.assert_allclose(nxt.q_cmd_rad, js.q_rad + 0.01)
    np.testing.assert_allclose(nxt.dq_cmd_rad_s, 0.2)
    # a second command for an answered cycle is late
    rig.command(js, js.q_rad, 0.0)
    assert rig.driver.rejected["late_cycle"] == 1


def test_age_counts_from_the_driver_stamp_even_if_the_command_claims_fresh(make_rig):
    rig = teaching(make_rig)
    js = rig.cycle()
    rig.clock.advance(0.011)
    rig.command(js, js.q_rad, state_stamp_s=rig.clock())  # lies about its age
    assert rig.driver.rejected["stale"] == 1
    [hold] = rig.command_sets()
    assert all(f.hold for f in hold)


def test_following_error_and_velocity_limits_are_per_joint(make_rig):
    rig = teaching(make_rig, max_following_error_rad=[0.05, 0.05, 0.05, 0.2, 0.2, 0.2])
    js = rig.cycle()
    q = js.q_rad.copy()
    q[4] += 0.15  # within joint 5's 0.2 rad
    rig.command(js, q)
    assert len(rig.command_sets()) == 1
    js = rig.cycle()
    q = js.q_rad.copy()
    q[1] += 0.06  # beyond joint 2's 0.05 rad
    rig.command(js, q)
    assert rig.driver.rejected["out_of_range"] == 1
    assert all(f.hold for f in rig.command_sets()[0]), "rejected: held at once"
    js = rig.cycle()
    rig.command(js, js.q_rad, dq_rad_s=1.01)
    assert rig.driver.rejected["out_of_range"] == 2


# --- the latched hold position --------------------------------------------------------------
def test_hold_latches_the_last_forwarded_command_and_ignores_sag(make_rig):
    rig = teaching(make_rig)
    js = rig.cycle()
    rig.command(js, js.q_rad + 0.02)
    rig.command_sets()
    q = Q0.copy()
    for _ in range(5):  # commands stop; the arm sags 5 mrad per cycle
        q = q - 0.005
        rig.cycle(q)
        rig.clock.advance(0.011)
        rig.driver.spin_once(0.0)
        [hold] = rig.command_sets()
        np.testing.assert_allclose([f.q_cmd_rad for f in hold], Q0 + 0.02, atol=1e-6)


def test_hold_latches_the_measured_position_if_the_last_command_is_too_far(make_rig):
    rig = teaching(make_rig)
    js = rig.cycle()
    rig.command(js, js.q_rad + 0.04)
    rig.command_sets()
    q_then = Q0 - 0.02  # 0.06 rad from the last command: beyond the 0.05 rad limit
    rig.cycle(q_then)
    rig.clock.advance(0.011)
    rig.driver.spin_once(0.0)
    [hold] = rig.command_sets()
    np.testing.assert_allclose([f.q_cmd_rad for f in hold], q_then, atol=1e-6)
    rig.cycle(q_then - 0.01)  # not re-sampled while holding
    rig.clock.advance(0.011)
    rig.driver.spin_once(0.0)
    [hold] = rig.command_sets()
    np.testing.assert_allclose([f.q_cmd_rad for f in hold], q_then, atol=1e-6)


def test_on_brakes_the_hold_follows_the_measured_position(make_rig):
    rig = make_rig()  # STOPPED: only holds, controller BRAKED
    for k in range(3):
        q = Q0 + 0.01 * k
        rig.cycle(q, state=ControllerState.BRAKED)
        holds = rig.command_sets()
        assert len(holds) == 1, "blocked cycles are held at once"
        np.testing.assert_allclose([f.q_cmd_rad for f in holds[0]], q, atol=1e-6)


def test_blocked_reasons(make_rig):
    rig = make_rig()
    rig.gateway(Lifecycle.TEACHING, enabling=False)
    js = rig.cycle()
    rig.command(js, js.q_rad)
    rig.gateway(Lifecycle.READY, enabling=True)
    js = rig.cycle()
    rig.command(js, js.q_rad)
    rig.gateway(Lifecycle.TEACHING, enabling=True)
    js = rig.cycle(state=ControllerState.BRAKED)
    rig.command(js, js.q_rad)
    rejected = rig.driver.rejected
    assert (
        rejected["blocked_enabling"],
        rejected["blocked_lifecycle"],
        rejected["blocked_controller"],
    ) == (1, 1, 1)
    assert all(f.hold for s in rig.command_sets() for f in s)


# --- requests and heartbeats ----------------------------------------------------------------
def requests(frames: list[Any]) -> list[HostRequest]:
    return [f.request for f in frames if isinstance(f, HostRequestFrame)]


def test_servo_request_follows_a_fresh_lifecycle(make_rig):
    rig = make_rig()
    rig.driver.spin_once(0.0)
    first = rig.received()
    assert Heartbeat("HOST", 5) in first and requests(first) == [HostRequest.BRAKE]
    rig.gateway(Lifecycle.READY)
    rig.driver.spin_once(0.0)
    assert requests(rig.received()) == [HostRequest.SERVO_ON]
    rig.clock.advance(0.05)
    rig.gateway(Lifecycle.READY)
    rig.driver.spin_once(0.0)
    assert rig.received() == [], "no repeat between heartbeats"
    rig.clock.advance(0.051)
    rig.gateway(Lifecycle.READY)
    rig.driver.spin_once(0.0)
    repeat = rig.received()
    assert Heartbeat("HOST", 5) in repeat and requests(repeat) == [HostRequest.SERVO_ON]
    rig.clock.advance(0.25)  # the gateway fell silent
    rig.driver.spin_once(0.0)
    assert requests(rig.received()) == [HostRequest.BRAKE]


def test_a_future_stamp_does_not_keep_the_lifecycle_fresh(make_rig):
    rig = make_rig()
    rig.gateway(Lifecycle.TEACHING, stamp_s=rig.clock() + 3600.0)
    rig.driver.spin_once(0.0)
    assert requests(rig.received()) == [HostRequest.BRAKE]


def test_operator_reset_is_sent_once_and_only_to_a_faulted_controller(make_rig):
    rig = make_rig()
    rig.gateway(Lifecycle.FAULT)
    rig.cycle(state=ControllerState.FAULT)
    rig.gateway(Lifecycle.STOPPED)
    rig.driver.spin_once(0.0)
    rig.driver.spin_once(0.0)
    assert requests(rig.received()) == [
        HostRequest.BRAKE,
        HostRequest.RESET_FAULT,
        HostRequest.BRAKE,
    ]
    rig.gateway(Lifecycle.STOPPED)
    rig.driver.spin_once(0.0)
    assert HostRequest.RESET_FAULT not in requests(rig.received())
    rig.gateway(Lifecycle.FAULT)
    rig.cycle(state=ControllerState.BRAKED)  # the controller is not faulted
    rig.gateway(Lifecycle.STOPPED)
    rig.driver.spin_once(0.0)
    assert HostRequest.RESET_FAULT not in requests(rig.received())


# --- cycle counter and shutdown -------------------------------------------------------------
def test_cycle_counter_is_widened_across_the_wrap_and_repeats_are_dropped(make_rig):
    rig = make_rig()
    assert rig.cycle(counter=65534).cycle == 65534
    assert rig.cycle(counter=65535).cycle == 65535
    assert rig.cycle(counter=0).cycle == 65536
    assert rig.cycle(counter=2).cycle == 65538  # a lost cycle leaves a gap
    n = len(rig.session.joint_states())
    for k in range(N):
        rig.controller_bus.send(rig.proto.encode_feedback(k + 1, 0.0, 0.0, 0.0, 2))
    status = ControllerStatus(2, ControllerState.HOLD, FaultCode.NONE, 0, False, True, 4000)
    rig.controller_bus.send(rig.proto.encode_status(status))
    for _ in range(N + 1):
        rig.driver.spin_once(0.0)
    assert len(rig.session.joint_states()) == n, "a repeated cycle is not published twice"


def test_health_message(make_rig):
    rig = teaching(make_rig)
    rig.cycle()
    rig.clock.advance(0.2)
    rig.driver.spin_once(0.0)
    health = [
        decode_json(p, "h") for k, p in rig.session.published if k == KEYS.health("can_driver")
    ]
    assert health[-1]["process"] == "can_driver"
    assert health[-1]["link_ok"] is False  # 0.2 s since the last cycle > controller_timeout_s
    assert health[-1]["controller_state"] == "EXTERNAL" and health[-1]["held"] == 1


def test_close_brakes_holds_and_never_raises(make_rig):
    rig = teaching(make_rig)
    rig.cycle()
    rig.driver.close()
    frames = rig.received()
    assert requests(frames) == [HostRequest.BRAKE]
    assert isinstance(frames[0], HostRequestFrame)
    assert [f.hold for f in frames[1:]] == [True] * N
    assert sorted(rig.session.undeclared) == sorted(
        [KEYS.joint_state, KEYS.state_window, KEYS.lifecycle, KEYS.io_state, KEYS.joint_command]
    )
    rig.driver.close()  # again: nothing, no error


def test_close_survives_a_dead_bus(make_rig):
    rig = teaching(make_rig)
    rig.cycle()
    rig.driver_bus.shutdown()  # type: ignore[attr-defined]
    rig.driver.close()  # logs, does not raise


def test_a_late_answer_coasts_on_the_last_command_then_holds_on_the_next(make_rig):
    """One late command costs nothing: the driver re-sends the last forwarded command moved on
    by its velocity; a second late cycle in a row holds, where the coast went."""
    rig = teaching(make_rig)
    period_s = 0.004
    js = rig.cycle(period_us=4000)
    rig.command(js, js.q_rad + 0.001, 0.2)
    [sent] = rig.command_sets()
    assert not any(f.hold for f in sent)
    rig.clock.advance(period_s)
    late = rig.cycle(period_us=4000)  # control is late for this one
    assert late.flags & (FLAG_PREV_COAST | FLAG_PREV_HOLD) == 0  # the last was the command
    rig.clock.advance(0.5 * period_s + 1e-4)
    rig.driver.spin_once(0.0)
    [coast] = rig.command_sets()
    assert not any(f.hold for f in coast) and all(f.counter == rig.counter for f in coast)
    np.testing.assert_allclose([f.q_cmd_rad for f in coast], Q0 + 0.001 + 0.2 * period_s, atol=2e-6)
    np.testing.assert_allclose([f.dq_cmd_rad_s for f in coast], 0.2, atol=1e-4)
    assert rig.driver.coasted == 1
    rig.clock.advance(period_s)
    after_coast = rig.cycle(period_us=4000)  # late again: two cycles after the command
    assert after_coast.flags & FLAG_PREV_COAST  # the recorder leaves the next cycles out
    rig.clock.advance(0.5 * period_s + 1e-4)
    rig.driver.spin_once(0.0)
    [hold] = rig.command_sets()
    assert all(f.hold and f.dq_cmd_rad_s == 0.0 for f in hold)
    np.testing.assert_allclose([f.q_cmd_rad for f in hold], Q0 + 0.001 + 0.2 * period_s, atol=2e-6)
    rig.clock.advance(period_s)
    assert rig.cycle(period_us=4000).flags & FLAG_PREV_HOLD
