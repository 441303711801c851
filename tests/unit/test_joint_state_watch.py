"""The gateway takes joint states in once per tick, as the CAN driver's state windows, and still
sees every one of them: a lost stream is found within joint_state_timeout_s (plus one tick and
one window), a motion between two ticks or inside a window still restarts the standstill clock,
and a malformed state or window is refused as the decoder refuses it.
Standstill is judged as a drive measures: a hold that hunts or a noisy velocity does not keep
teaching waiting, a creep faster than the standstill speed does."""

from __future__ import annotations

import math
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from gateway.bus import BusConfig
from gateway.errors import MessageError
from gateway.joint_state_watch import JointStateWatch, joint_state_summary
from gateway.lifecycle import LifecycleMachine, Limits
from gateway.message_factories import make_joint_state
from gateway.messages import ControllerState, JointState, Lifecycle, StateWindow
from gateway.supervisor import TICK_S, Gateway, GatewayConfig

STILL = 5e-4  #: standstill speed [rad/s]
PERIOD_S = 0.004
TRANSIT_S = 2e-4  #: CAN driver stamp → arrival at the gateway
WINDOW_S = 0.02  #: the CAN driver's state window ([can] state_window_s)
#: the servo-on settle time in the standstill tests: those judge the standstill clock alone
#: (the settle rule is tests/unit/test_lifecycle.py's)
NO_SETTLE = 0.0


def state(
    cycle: int,
    stamp_s: float,
    speed: float = 0.0,
    dq: np.ndarray | None = None,
    q: np.ndarray | None = None,
    controller_state: ControllerState = ControllerState.HOLD,
) -> bytes:
    """A JointState's bytes; joint 4 moves at ``speed`` [rad/s] unless ``dq`` is given."""
    q = np.linspace(-0.5, 0.5, 6) if q is None else q
    if dq is None:
        dq = np.full(6, 1e-5)
        dq[3] = speed
    st = make_joint_state(cycle, stamp_s, controller_state, 2, q, dq, np.zeros(6), q,
                          np.zeros(6), PERIOD_S)  # fmt: skip
    return st.to_bytes()


def payload(*args, **kwargs) -> bytes:
    """A StateWindow of the one state :func:`state` makes of the arguments."""
    data = state(*args, **kwargs)
    st = JointState.from_bytes(data)
    return StateWindow(1, float(np.abs(st.dq_rad_s).max()), st.q_rad, st.q_rad, data).to_bytes()


class StateWindows:
    """The CAN driver's state windows as the gateway receives them (the rule is
    drivers/can/rt/src/window.rs StateWindowBuilder, tested there; this stands in for the
    driver): a window closes at the first state at or after its due time, due times
    ``period_s`` apart, or at once when ``key`` (the controller's state and its flags)
    changes; the first state closes a window of its own."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.q: list[np.ndarray] = []
        self.speed = 0.0
        self.key: tuple[int, int] | None = None
        self.due_s = -math.inf

    def add(
        self, q: np.ndarray, dq: np.ndarray, key: tuple[int, int], state: bytes, now: float
    ) -> bytes | None:
        """Take one cycle's state; returns the window's bytes when it closes."""
        speed = float(np.abs(dq).max())
        self.speed = max(self.speed, speed) if self.q else speed
        self.q.append(np.array(q, dtype=float))
        if now < self.due_s and key == self.key:
            return None
        qs = np.array(self.q)
        window = StateWindow(len(qs), self.speed, qs.min(axis=0), qs.max(axis=0), state)
        due = self.due_s + self.period_s  # on the period's grid; a gap starts it again
        self.key, self.due_s, self.q = key, due if due > now else now + self.period_s, []
        return window.to_bytes()


def test_summary_reads_what_the_decoder_reads():
    rng = np.random.default_rng(1)
    for k in range(50):
        dq = rng.normal(0.0, 0.3, 6)
        data = state(k, 10.0 + k, q=rng.normal(0, 1, 6), dq=dq,
                     controller_state=ControllerState(k % 4))  # fmt: skip
        st = JointState.from_bytes(data)
        cstate, stamp, speed, q = joint_state_summary(data)
        assert (cstate, stamp, speed) == (st.controller_state, st.stamp_s, np.abs(dq).max())
        np.testing.assert_array_equal(q, st.q_rad)


def _corruptions(good: bytes) -> dict[str, bytes]:
    head = JointState._HEAD.size
    bad = {
        "short": good[:10],
        "magic": b"XXXX" + good[4:],
        "version": good[:4] + b"\x09" + good[5:],
        "truncated body": good[:-8],
        "extra byte": good + b"\x00",
        "joint count 0": good[:5] + b"\x00" + good[6:],
        "controller state 9": good[: head - 10] + b"\x09" + good[head - 9 :],
        "negative period": good[: head - 8] + struct.pack("<d", -0.004),
        "NaN stamp": good[:10] + struct.pack("<d", math.nan) + good[18:],
    }
    for i, name in enumerate(("q", "dq", "current", "q_cmd", "dq_cmd")):
        at = head + (6 * i + 2) * 8
        for v in (math.nan, math.inf):
            bad[f"{v} in {name}"] = good[:at] + struct.pack("<d", v) + good[at + 8 :]
    return bad


def test_summary_refuses_every_payload_the_decoder_refuses():
    good = state(1, 5.0)
    JointState.from_bytes(good)
    joint_state_summary(good)
    for what, data in _corruptions(good).items():
        with pytest.raises(MessageError):
            JointState.from_bytes(data)
        with pytest.raises(MessageError):
            joint_state_summary(data)
        assert what


class Cell:
    """States at 250 Hz, gathered into windows as the CAN driver gathers them, folded at each
    gateway tick, observed by the lifecycle."""

    def __init__(self, limits: Limits) -> None:
        self.watch = JointStateWatch(limits.standstill_rad_s, 0.0, limits.standstill_s)
        self.machine = LifecycleMachine(limits)
        self.windows = StateWindows(WINDOW_S)
        self.pending: list[bytes] = []
        self.cycle = 0

    def arrive(self, t_s: float, speed: float = 0.0, **joints: np.ndarray) -> None:
        """A state stamped ``t_s``: joint 4 at ``speed``, or the ``q`` / ``dq`` given."""
        self.cycle += 1
        data = state(self.cycle, t_s - TRANSIT_S, speed, **joints)
        st = JointState.from_bytes(data)
        window = self.windows.add(st.q_rad, st.dq_rad_s, (1, 2), data, t_s - TRANSIT_S)
        if window is not None:
            self.pending.append(window)

    def tick(self, now_s: float) -> Lifecycle:
        batch, self.pending = self.pending, []
        assert self.watch.fold(batch, now_s) == []
        w = self.watch
        from gateway.lifecycle import Observations

        obs = Observations(
            joint_state_age_s=None if w.rx_s is None else now_s - w.rx_s,
            io_age_s=0.01,
            controller_state=w.controller_state,
            enabling=True,
            estop_ok=True,
            max_speed_rad_s=w.max_speed_rad_s,
            still_for_s=0.0 if w.moving_s is None else now_s - w.moving_s,
            servo_on_for_s=0.0 if w.servo_on_s is None else now_s - w.servo_on_s,
        )
        if self.machine.state == Lifecycle.STOPPED:
            self.machine.command("start", obs)
        return self.machine.update(obs)

    def run(self, t0: float, t1: float, moving: set[int] = frozenset(), stream: bool = True):
        """Simulate [t0, t1): states every PERIOD_S (those in ``moving`` fast), ticks every
        TICK_S; returns (tick time, lifecycle) pairs."""
        out, k, t = [], round(t0 / PERIOD_S), t0
        next_tick = math.ceil(t0 / TICK_S) * TICK_S
        while t < t1:
            t = k * PERIOD_S
            while next_tick <= t and next_tick < t1:
                out.append((next_tick, self.tick(next_tick)))
                next_tick += TICK_S
            if stream and t < t1:
                self.arrive(t, 0.05 if k in moving else 0.0)
            k += 1
        return out


def test_a_motion_between_two_ticks_restarts_the_standstill_clock():
    limits = Limits(
        joint_state_timeout_s=0.1,
        standstill_rad_s=STILL,
        standstill_s=0.3,
        servo_settle_s=NO_SETTLE,
    )
    cell = Cell(limits)
    spike = 26  # one state (t = 0.104 s) moves; the newest state at every tick is still
    history = cell.run(0.0, 1.0, moving={spike})
    teaching = [t for t, s in history if s == Lifecycle.TEACHING]
    assert teaching, "never started teaching"
    assert teaching[0] >= spike * PERIOD_S + limits.standstill_s - 1e-9
    assert teaching[0] <= spike * PERIOD_S + limits.standstill_s + WINDOW_S + TICK_S + 1e-9


def test_a_stream_that_stops_faults_within_the_timeout_plus_one_tick_and_one_window():
    limits = Limits(
        joint_state_timeout_s=0.1,
        standstill_rad_s=STILL,
        standstill_s=0.05,
        servo_settle_s=NO_SETTLE,
    )
    cell = Cell(limits)
    history = cell.run(0.0, 0.5)
    assert history[-1][1] == Lifecycle.TEACHING
    last_arrival = (round(0.5 / PERIOD_S) - 1) * PERIOD_S
    history = cell.run(0.5, 0.8, stream=False)
    faulted = [t for t, s in history if s == Lifecycle.FAULT]
    assert faulted, "a lost joint-state stream was not detected"
    assert limits.joint_state_timeout_s < faulted[0] - last_arrival + WINDOW_S
    assert faulted[0] - last_arrival <= limits.joint_state_timeout_s + TICK_S + 1e-9


def test_arrival_time_is_a_lower_bound_and_never_ahead_of_the_fold():
    w = JointStateWatch(STILL, start_s=1.0)
    w.fold([payload(1, 1.004)], 1.010)
    assert w.rx_s == 1.004  # the driver's stamp: later than the previous fold
    w.fold([payload(2, 0.5)], 1.020)  # a stamp from long ago: the previous fold bounds
    assert w.rx_s == 1.010
    w.fold([payload(3, 9.0)], 1.030)  # a stamp in the future: not beyond the fold
    assert w.rx_s == 1.030
    w.fold([], 1.040)
    assert w.rx_s == 1.030


def test_a_fold_bounds_arrivals_by_when_the_channel_was_drained():
    """States taken between start_s and end_s: a motion counts from end_s (it may have
    arrived just before the drain ended); the next batch arrived after start_s."""
    w = JointStateWatch(STILL, start_s=0.0)
    w.fold([payload(1, 0.5, speed=0.1)], 2.000, 2.003)
    assert (w.rx_s, w.moving_s) == (0.5, 2.003)
    w.fold([payload(2, 0.6)], 2.010, 2.011)
    assert w.rx_s == 2.000 and w.moving_s == 2.003


def test_malformed_states_are_reported_and_do_not_count_as_fresh():
    w = JointStateWatch(STILL, start_s=0.0)
    w.fold([payload(1, 0.001)], 0.01)
    nan = bytearray(payload(2, 0.011))
    nan[-8:] = struct.pack("<d", math.nan)
    problems = w.fold([bytes(nan), b"garbage"], 0.02)
    assert len(problems) == 2 and "finite" in problems[0]
    assert w.rx_s == 0.001 and w.state is not None and w.state.cycle == 1


class _Sample:
    def __init__(self, data: bytes) -> None:
        self.payload = self

        def to_bytes() -> bytes:
            return data

        self.to_bytes = to_bytes


class _Ring:
    """Stands in for the zenoh ring channel the gateway drains."""

    def __init__(self) -> None:
        self.samples: list[_Sample] = []

    def try_recv(self):
        return self.samples.pop(0) if self.samples else None


def test_gateway_observes_and_reports_the_newest_state_of_each_tick():
    gw = Gateway(Path("cell.toml"), BusConfig(), GatewayConfig(processes=()), spawn=False)
    ring = _Ring()
    gw._state_sub = ring
    time.sleep(0.03)
    t0 = time.monotonic() - 0.025  # stamps after the gateway started
    ring.samples = [_Sample(payload(k, t0 + k * PERIOD_S, speed=0.2 if k == 1 else 0.0))
                    for k in (1, 2, 3)]  # fmt: skip
    before = time.monotonic()
    gw._take_states()
    after = time.monotonic()
    obs = gw.observations(after + 0.005)
    assert ring.samples == []
    assert obs.controller_state == ControllerState.HOLD
    assert obs.max_speed_rad_s == pytest.approx(1e-5)  # the newest state's
    assert 0.005 <= obs.still_for_s <= 0.005 + after - before  # the batch held a motion
    assert obs.joint_state_age_s == pytest.approx(after + 0.005 - (t0 + 3 * PERIOD_S))
    status = gw.status(after)
    assert status["controller_state"] == "hold" and len(status["q_rad"]) == 6


def _first_teaching(limits: Limits, duration_s: float, joints) -> float | None:
    """Stream ``joints(k, t) -> (q, dq)`` for ``duration_s``; when teaching began (None: never)."""
    cell, next_tick = Cell(limits), TICK_S
    for k in range(round(duration_s / PERIOD_S)):
        t = k * PERIOD_S
        while next_tick <= t:
            if cell.tick(next_tick) == Lifecycle.TEACHING:
                return next_tick
            next_tick += TICK_S
        q, dq = joints(k, t)
        cell.arrive(t, q=q, dq=dq)
    return None


def test_a_hold_that_hunts_with_a_noisy_velocity_does_not_keep_teaching_waiting():
    """A vendor loop on a quantised encoder dithers by a few standstill speeds, and the drive's
    velocity is noisy (std = the standstill speed); the position stays within a few µrad."""
    limits = Limits(
        joint_state_timeout_s=0.1,
        standstill_rad_s=STILL,
        standstill_s=0.3,
        servo_settle_s=NO_SETTLE,
    )
    rng = np.random.default_rng(3)
    q0 = np.linspace(-0.5, 0.5, 6)

    def hunting(k: int, t: float):
        dq = 3 * STILL * np.sin(2 * np.pi * 5.0 * t + np.arange(6)) + rng.normal(0, STILL, 6)
        return q0 + 3 * STILL / (2 * np.pi * 5.0) * np.sin(2 * np.pi * 5.0 * t), dq

    began = _first_teaching(limits, 3.0, hunting)
    assert began is not None, "a hold's dither kept teaching from starting"
    assert began <= limits.standstill_s + 0.2


@pytest.mark.parametrize("speed_factor, teaches", [(0.5, True), (1.5, False), (4.0, False)])
def test_a_creep_faster_than_the_standstill_speed_is_motion_however_quiet_its_velocity(
    speed_factor: float, teaches: bool
):
    """Joint 2 creeps at ``speed_factor`` standstill speeds while its velocity reads near zero
    (a drive that filters it): the positions decide."""
    limits = Limits(
        joint_state_timeout_s=0.1,
        standstill_rad_s=STILL,
        standstill_s=0.3,
        servo_settle_s=NO_SETTLE,
    )
    q0 = np.linspace(-0.5, 0.5, 6)

    def creeping(k: int, t: float):
        q = q0.copy()
        q[1] += speed_factor * STILL * t
        return q, np.full(6, 0.1 * STILL)

    began = _first_teaching(limits, 3.0, creeping)
    assert (began is not None) == teaches, began


def test_one_state_far_above_the_standstill_speed_restarts_the_clock_at_any_position():
    w = JointStateWatch(STILL, 0.0, 0.3)
    w.fold([payload(1, 0.001)], 0.01)
    w.fold([payload(2, 0.005)], 0.5)
    assert w.moving_s == 0.01
    w.fold([payload(3, 0.505, speed=JointStateWatch.FAST_FACTOR * STILL * 1.01)], 0.51)
    assert w.moving_s == 0.51 and w.band_used_rad == 0.0


def _window(states: list[bytes]) -> bytes:
    """The window the CAN driver makes of ``states`` (one window, closed by the last)."""
    builder, out = StateWindows(period_s=1e9), None
    for k, data in enumerate(states):
        st = JointState.from_bytes(data)
        key = (1, 2) if k == 0 else (1, 2) if k < len(states) - 1 else (2, 2)
        out = builder.add(st.q_rad, st.dq_rad_s, key, data, st.stamp_s)
        assert (out is not None) == (k in (0, len(states) - 1))
    assert out is not None
    return out


def test_a_window_carries_every_state_in_it_to_the_standstill_judgement():
    """The newest state of a window is still; one before it was fast, or the positions in it
    spread wider than the band: either is a motion."""
    w = JointStateWatch(STILL, 0.0, 0.3)
    w.fold([payload(1, 0.001)], 0.01)
    fast = JointStateWatch.FAST_FACTOR * STILL * 1.01
    w.fold([_window([state(k, 0.01 + 0.004 * k, fast if k == 3 else 0.0) for k in range(6)])],
           0.5)  # fmt: skip
    assert w.moving_s == 0.5 and w.max_speed_rad_s == pytest.approx(1e-5)
    q0 = np.linspace(-0.5, 0.5, 6)
    out = q0.copy()
    out[1] += 2 * STILL * 0.3  # twice the band, for one state only
    w.fold([_window([state(k, 0.6, q=out if k == 2 else q0) for k in range(5)])], 0.6)
    assert w.moving_s == 0.6
    w.fold([_window([state(k, 1.0, q=q0) for k in range(5)])], 1.0)
    assert w.moving_s == 0.6


def test_a_malformed_window_is_refused_naming_what_is_wrong():
    good = payload(1, 0.5)
    StateWindow.from_bytes(good)
    head = StateWindow._HEAD.size
    lo_above_hi = good[:head] + struct.pack("<d", 9.0) + good[head + 8 :]
    nan_bound = good[:head] + struct.pack("<d", math.nan) + good[head + 8 :]
    no_states = good[:6] + struct.pack("<I", 0) + good[10:]
    for data, says in ((good[:head + 40], "no state"), (lo_above_hi, "above"),
                       (nan_bound, "finite"), (no_states, "states"),
                       (b"LTJS" + good[4:], "magic")):  # fmt: skip
        with pytest.raises(MessageError, match=says):
            StateWindow.from_bytes(data)
    w = JointStateWatch(STILL, 0.0)
    other_n = StateWindow.from_bytes(good)
    short = StateWindow(1, 0.0, other_n.q_lo_rad[:5], other_n.q_hi_rad[:5], other_n.newest)
    assert "joint count" in w.fold([short.to_bytes()], 0.01)[0]
    assert w.rx_s is None


def test_the_servo_on_time_starts_at_the_first_held_state_and_a_servo_off_clears_it():
    """``servo_on_s`` is the fold that first saw the drives hold (or follow) since they last
    did not; it stays through holding and following, and any other state clears it."""
    w = JointStateWatch(STILL, 0.0)
    assert w.fold([payload(1, 0.0, controller_state=ControllerState.BRAKED)], 0.01) == []
    assert w.servo_on_s is None
    w.fold([payload(2, 0.01, controller_state=ControllerState.HOLD)], 0.02)
    assert w.servo_on_s == 0.02
    w.fold([payload(3, 0.02, controller_state=ControllerState.EXTERNAL)], 0.03)
    w.fold([payload(4, 0.03, controller_state=ControllerState.HOLD)], 0.04)
    assert w.servo_on_s == 0.02
    w.fold([], 0.05)  # no state: nothing changes
    assert w.servo_on_s == 0.02
    w.fold([payload(5, 0.05, controller_state=ControllerState.FAULT)], 0.06)
    assert w.servo_on_s is None
    w.fold([payload(6, 0.06, controller_state=ControllerState.HOLD)], 0.07)
    assert w.servo_on_s == 0.07
