"""The CAN host's pure core, cycle by cycle: frames and payloads in, frames and payloads out,
no bus, no zenoh, no thread, an explicit clock."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.can.config import CanDriverConfig
from drivers.can.core import COAST, COMMAND, HOLD, RAMP, HostCore
from drivers.can.ltc import (
    ControllerStatus,
    FaultCode,
    HostRequest,
    HostRequestFrame,
    JointCommandFrame,
    LtcAdapter,
    LtcProtocol,
)
from gateway.latency import Histogram
from gateway.messages import (
    FLAG_PREV_COAST,
    FLAG_PREV_HOLD,
    FLAG_SERVO_POWER,
    ControllerState,
    IoState,
    JointCommand,
    JointState,
    Lifecycle,
    LifecycleMsg,
)

N = 6
Q0 = np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
PERIOD_US = 4000
T0 = 500.0


class Cell:
    """The core and a scripted controller; ``t`` is the injected clock [s]."""

    def __init__(self, **overrides: object) -> None:
        values: dict = {
            "transport": {"interface": "virtual", "channel": "unused"},
            "current_zero_cycles": 0,  # the servo at once; the zero's own tests set it
        }
        values.update(overrides)
        self.config = CanDriverConfig(**values)
        self.core = HostCore(self.config, LtcAdapter(N))
        self.proto = LtcProtocol(N)
        self.t = T0
        self.counter = 0
        self.seq = 0

    def gateway(self, state: Lifecycle, enabling: bool = True, estop_ok: bool = True) -> None:
        self.seq += 1  # the gateway numbers every announcement it changes
        self.core.on_lifecycle(LifecycleMsg(state, self.seq, self.t).to_bytes(), self.t)
        io = IoState(self.t, 6.0, 4.0, 6.0, 4.0, enabling, estop_ok)
        self.core.on_io(io.to_bytes(), self.t)

    def cycle(
        self, q=Q0, state=ControllerState.EXTERNAL, current=(1.5,) * N, power=True,
        period_us=PERIOD_US,
    ) -> tuple[JointState, list]:  # fmt: skip
        """Feed one controller cycle; returns its JointState and the frames sent at once."""
        self.counter = (self.counter + 1) & 0xFFFF
        frames = [
            self.proto.encode_feedback(
                k + 1, float(q[k]), 0.01 * k, float(current[k]), self.counter & 0xFF
            )
            for k in range(N)
        ]
        status = ControllerStatus(self.counter, state, FaultCode.NONE, 0, False, power, period_us)
        frames.append(self.proto.encode_status(status))
        out, payload = [], None
        for msg in frames:
            result = self.core.on_frame(msg, self.t)
            out += result.frames
            if result.state is not None:
                assert payload is None, "one JointState per cycle"
                payload = result.state
        assert payload is not None, "the cycle's last frame completes it"
        return JointState.from_bytes(payload), [self.proto.decode(m) for m in out]

    def tick(self) -> list:
        return [self.proto.decode(m) for m in self.core.on_tick(self.t)]

    def command(self, js: JointState, q, dq=0.0):
        cmd = JointCommand(js.cycle, js.stamp_s, self.t, np.asarray(q, float), np.full(N, dq))
        result = self.core.on_command(cmd.to_bytes(), self.t)
        return result.answer, [self.proto.decode(m) for m in result.frames]


def commands(frames: list) -> list[JointCommandFrame]:
    return [f for f in frames if isinstance(f, JointCommandFrame)]


def test_a_cycle_becomes_one_joint_state_with_the_feedback_and_the_echo():
    cell = Cell()
    js, _ = cell.cycle()
    assert js.cycle == cell.counter and js.stamp_s == T0 and js.cycle_period_s == 0.004
    np.testing.assert_allclose(js.q_rad, Q0, atol=1e-6)
    np.testing.assert_allclose(js.dq_rad_s, 0.01 * np.arange(N), atol=1e-4)
    np.testing.assert_allclose(js.current_a, 1.5)
    np.testing.assert_allclose(js.q_cmd_rad, js.q_rad)  # nothing sent yet: the measurement
    assert js.flags & FLAG_SERVO_POWER


def test_currents_are_published_less_the_zero_measured_with_the_servo_power_off():
    cell = Cell(current_zero_cycles=4, current_zero_settle_cycles=2)
    zero = np.array([0.07, -0.21, 0.15, 0.02, -0.01, 0.0])
    js, _ = cell.cycle(current=zero + 2.0)  # powered: nothing measured yet
    np.testing.assert_allclose(js.current_a, zero + 2.0, atol=6e-3)
    for k in range(8):  # the power goes off; the first 2 cycles still hold powered ticks
        js, _ = cell.cycle(state=ControllerState.BRAKED, current=zero + (1.0 if k < 2 else 0.0),
                           power=False)  # fmt: skip
    np.testing.assert_allclose(js.current_a, 0.0, atol=6e-3)
    np.testing.assert_allclose(cell.core.health(cell.t)["current_zero_a"], zero, atol=6e-3)
    assert cell.core.health(cell.t)["current_zero_samples"] == 4
    js, _ = cell.cycle(current=zero + 3.0)  # powered again: the zero stays as measured
    np.testing.assert_allclose(js.current_a, 3.0, atol=6e-3)


def test_the_first_servo_on_waits_until_the_current_zero_is_measured():
    cell = Cell(current_zero_cycles=3, current_zero_settle_cycles=0)
    cell.gateway(Lifecycle.READY)
    assert cell.core.desired_request(cell.t) == HostRequest.BRAKE  # nothing measured yet
    for _ in range(2):
        cell.cycle(state=ControllerState.BRAKED, current=(0.1,) * N, power=False)
    assert cell.core.desired_request(cell.t) == HostRequest.BRAKE
    cell.cycle(state=ControllerState.BRAKED, current=(0.1,) * N, power=False)
    assert cell.core.desired_request(cell.t) == HostRequest.SERVO_ON
    cell.cycle(current=(2.0,) * N)  # powered, then off again: no new wait
    cell.cycle(state=ControllerState.BRAKED, current=(0.1,) * N, power=False)
    assert cell.core.desired_request(cell.t) == HostRequest.SERVO_ON


def test_a_blocked_cycle_is_held_at_once_and_flagged_in_the_next_state():
    cell = Cell()  # no lifecycle: blocked
    _, sent = cell.cycle()
    hold = commands(sent)
    assert len(hold) == N and all(f.hold and f.counter == cell.counter for f in hold)
    assert cell.core.pending.answer == HOLD
    js, _ = cell.cycle()
    assert js.flags & FLAG_PREV_HOLD


def test_a_fresh_command_is_forwarded_once_and_echoed():
    cell = Cell()
    cell.gateway(Lifecycle.TEACHING)
    js, sent = cell.cycle()
    assert commands(sent) == []
    cell.t += 0.001
    answer, frames = cell.command(js, Q0 + 0.01, 0.2)
    assert answer == COMMAND
    assert [f.counter for f in frames] == [cell.counter] * N and not any(f.hold for f in frames)
    np.testing.assert_allclose([f.q_cmd_rad for f in frames], Q0 + 0.01, atol=1e-6)
    again, frames = cell.command(js, Q0, 0.0)
    assert (again, frames) == ("", []) and cell.core.rejected["late_cycle"] == 1
    nxt, _ = cell.cycle()
    np.testing.assert_allclose(nxt.q_cmd_rad, Q0 + 0.01)
    assert not nxt.flags & (FLAG_PREV_HOLD | FLAG_PREV_COAST)


def test_the_next_deadline_is_the_answer_time_of_an_unanswered_cycle():
    cell = Cell(deadline_s=0.010, answer_by_period_fraction=0.5)
    cell.gateway(Lifecycle.TEACHING)
    cell.tick()  # first heartbeat and request go out
    cell.cycle()
    assert cell.core.next_tick_s() == pytest.approx(T0 + 0.002)  # 0.5 × 4 ms < 10 ms
    cell.t += 0.0019
    assert commands(cell.tick()) == []
    cell.t += 0.0002
    hold = commands(cell.tick())
    assert len(hold) == N and all(f.hold for f in hold)
    assert cell.core.next_tick_s() == pytest.approx(T0 + 0.1)  # next heartbeat


def test_at_ltc1s_8_ms_one_late_command_coasts_and_a_second_in_a_row_holds():
    """The coast's bound is one cycle, whatever the period: at 8 ms the command of the cycle
    before is 12 ms old when the late cycle is answered (past deadline_s, 10 ms), and still
    coasts; the next late cycle holds."""
    cell = Cell(deadline_s=0.010)
    cell.gateway(Lifecycle.TEACHING)
    cell.tick()
    js, _ = cell.cycle(period_us=8000)
    assert cell.command(js, Q0 + 0.001, 0.2)[0] == COMMAND
    coasted = Q0 + 0.001 + 0.2 * 0.008
    for answer, q in ((COAST, coasted), (HOLD, coasted)):  # the hold keeps the coast's place
        cell.t += 0.008
        cell.gateway(Lifecycle.TEACHING)
        cell.cycle(period_us=8000)
        cell.t += 0.0041  # past the answer deadline, half the period
        sent = commands(cell.tick())
        assert cell.core.pending.answer == answer
        assert all(f.hold == (answer == HOLD) for f in sent) and len(sent) == N
        np.testing.assert_allclose([f.q_cmd_rad for f in sent], q, atol=2e-6)
        cell.t -= 0.0041


def test_a_late_command_coasts_then_the_next_late_one_holds_where_the_coast_went():
    cell = Cell(deadline_s=0.010)
    cell.gateway(Lifecycle.TEACHING)
    cell.tick()  # servo on requested: a new servo-on period begins
    js, _ = cell.cycle()
    assert cell.command(js, Q0 + 0.001, 0.2)[0] == COMMAND
    cell.t += 0.004
    cell.gateway(Lifecycle.TEACHING)
    cell.cycle()
    cell.t += 0.0021
    coast = commands(cell.tick())
    assert cell.core.pending.answer == COAST and not any(f.hold for f in coast)
    np.testing.assert_allclose([f.q_cmd_rad for f in coast], Q0 + 0.001 + 0.2 * 0.004, atol=2e-6)
    cell.t += 0.010  # the next cycle is late too: two cycles after the forwarded command
    cell.gateway(Lifecycle.TEACHING)
    js, _ = cell.cycle()
    assert js.flags & FLAG_PREV_COAST
    cell.t += 0.0021
    hold = commands(cell.tick())
    assert all(f.hold for f in hold) and cell.core.pending.answer == HOLD
    # where the controller was sent last: a hold at the forwarded command would pull it back
    np.testing.assert_allclose([f.q_cmd_rad for f in hold], Q0 + 0.001 + 0.2 * 0.004, atol=2e-6)


@pytest.mark.parametrize(
    ("q_offset", "dq", "reason"),
    [(0.06, 0.0, "out_of_range"), (0.0, 1.01, "out_of_range")],
)
def test_an_implausible_command_is_refused_and_its_cycle_held(q_offset, dq, reason):
    cell = Cell(max_following_error_rad=0.05, max_velocity_rad_s=1.0)
    cell.gateway(Lifecycle.TEACHING)
    js, _ = cell.cycle()
    answer, frames = cell.command(js, Q0 + q_offset, dq)
    assert answer == HOLD and all(f.hold for f in frames)
    assert cell.core.rejected[reason] == 1


def test_a_garbled_command_is_counted_and_answers_nothing():
    cell = Cell()
    cell.gateway(Lifecycle.TEACHING)
    cell.cycle()
    result = cell.core.on_command(b"LTJC\x02garbage", cell.t)
    assert result.frames == [] and result.command is None
    assert cell.core.rejected["bad_message"] == 1


def test_closing_frames_brake_first_then_hold_the_waiting_cycle():
    cell = Cell()
    cell.gateway(Lifecycle.TEACHING)
    cell.cycle()
    frames = [cell.proto.decode(m) for m in cell.core.closing_frames()]
    assert frames[0] == HostRequestFrame(HostRequest.BRAKE, frames[0].counter)
    assert all(f.hold for f in frames[1:]) and len(frames) == 1 + N


def moving(cell: Cell, dq: float = 0.2) -> np.ndarray:
    """Teach: one command moving every joint at ``dq`` from Q0; the position it sent. (The
    cells of these tests have no speed monitor: every joint at 0.2 rad/s moves the datasheet
    arm's tool at 633 mm/s.)"""
    cell.gateway(Lifecycle.TEACHING)
    cell.tick()
    js, _ = cell.cycle()
    assert cell.command(js, Q0, dq)[0] == COMMAND
    return Q0.copy()


def follow(cell: Cell, state: Lifecycle, cycles: int, q: np.ndarray, **io) -> list:
    """``cycles`` cycles, the gateway announcing ``state`` each, the measured position the
    last command sent (a drive following it); the command sets answered at once."""
    sets = []
    for _ in range(cycles):
        cell.t += PERIOD_US * 1e-6
        cell.gateway(state, **io)
        _, frames = cell.cycle(q)
        sent = commands(frames)
        if sent:
            sets.append(sent)
            q = np.array([f.q_cmd_rad for f in sent])
    return sets


def test_releasing_the_enabling_device_ramps_the_command_to_standstill_then_holds():
    """Stop category 2: the velocity falls linearly to zero in |dq| / deceleration (0.2 rad/s
    at 1 rad/s²: 0.2 s, 50 cycles of 4 ms) along the last command's path, then a hold at the
    ramp's end, dq·T/2 = 20 mrad further on."""
    cell = Cell(stop_deceleration_rad_s2=1.0, hand_guiding_max_speed_m_s=0.0)
    q = moving(cell, 0.2)
    sets = follow(cell, Lifecycle.TEACHING, 60, q, enabling=False)
    assert len(sets) == 60, "every cycle of the stop answered at once"
    ramp = [s for s in sets if not any(f.hold for f in s)]
    held = [s for s in sets if all(f.hold for f in s)]
    assert len(ramp) == 50 and len(held) == 10 and sets[:50] == ramp
    dq = np.array([[f.dq_cmd_rad_s for f in s] for s in ramp])
    q_cmd = np.array([[f.q_cmd_rad for f in s] for s in ramp])
    np.testing.assert_allclose(dq[:, 0], 0.2 * (1.0 - np.arange(50) / 50), atol=1e-4)
    step = np.diff(q_cmd[:, 0]) / 0.004
    assert np.all(step > -1e-3) and np.all(np.diff(step) < 1e-2), "slows down, never reverses"
    end = Q0 + 0.2 * 0.004 + 0.5 * 0.2 * 0.2
    np.testing.assert_allclose([f.q_cmd_rad for f in held[-1]], end, atol=2e-6)
    assert cell.core.health(cell.t)["ramped"] == 50
    assert cell.core.desired_request(cell.t) == HostRequest.SERVO_ON


def test_every_joint_of_a_controlled_stop_ends_at_the_same_time_within_its_deceleration():
    from drivers.can.stop_ramp import StopRamp

    dq0 = np.array([0.3, -0.1, 0.05, 0.0, 0.2, -0.4])
    decel = np.array([1.0, 0.5, 2.0, 1.0, 0.4, 4.0])
    ramp = StopRamp.start(10, Q0, dq0, decel, 0.002)
    assert ramp.duration_s == pytest.approx(0.5)  # joint 5: 0.2 / 0.4
    qs, dqs = zip(*[ramp.at(10 + k)[:2] for k in range(300)], strict=True)
    dqs = np.array(dqs)
    assert np.all(np.abs(np.diff(dqs, axis=0)) / 0.002 <= decel + 1e-9)
    assert np.all(dqs[:250] * dq0 >= 0) and not dqs[250:].any()
    np.testing.assert_allclose(qs[-1], Q0 + 0.25 * dq0)
    direction = (np.array(qs[1:]) - Q0) / np.linalg.norm(dq0)
    np.testing.assert_allclose(direction / np.linalg.norm(direction, axis=1)[:, None],
                               np.tile(dq0 / np.linalg.norm(dq0), (299, 1)), atol=1e-9)  # fmt: skip


def test_a_fault_during_the_ramp_holds_at_once_where_the_ramp_had_got_to():
    cell = Cell(stop_deceleration_rad_s2=1.0, hand_guiding_max_speed_m_s=0.0)
    q = moving(cell, 0.2)
    sets = follow(cell, Lifecycle.TEACHING, 10, q, enabling=False)
    assert cell.core.pending.answer == RAMP
    reached = np.array([f.q_cmd_rad for f in sets[-1]])
    after = follow(cell, Lifecycle.TEACHING, 3, reached, enabling=False, estop_ok=False)
    assert all(f.hold for s in after for f in s), "the e-stop chain opened: no more ramp"
    # held where the ramp was on the cycle the fault was seen
    np.testing.assert_allclose([f.q_cmd_rad for f in after[0]], reached + 0.004 * 0.2 * 0.8,
                               atol=2e-5)  # fmt: skip


def test_the_operators_stop_keeps_the_servo_on_through_the_ramp_then_brakes():
    """Stop category 1: STOPPED while the arm moves ramps it to standstill under power."""
    cell = Cell(stop_deceleration_rad_s2=2.0, hand_guiding_max_speed_m_s=0.0)
    q = moving(cell, 0.2)
    follow(cell, Lifecycle.STOPPED, 5, q)
    assert cell.core.pending.answer == RAMP
    assert cell.core.desired_request(cell.t) == HostRequest.SERVO_ON
    follow(cell, Lifecycle.STOPPED, 25, q)  # 0.1 s: the ramp has ended
    assert cell.core.pending.answer == HOLD
    assert cell.core.desired_request(cell.t) == HostRequest.BRAKE


def test_the_operators_stop_between_two_cycles_waits_for_the_ramp_not_the_brakes():
    """The stop arrives, and the driver decides its servo request, before the next cycle
    starts the ramp: the servo stays on (it asked for the brakes at once, and the arm
    stopped hard, until the fault campaign caught it)."""
    cell = Cell(stop_deceleration_rad_s2=2.0, hand_guiding_max_speed_m_s=0.0)
    q = moving(cell, 0.2)
    cell.t += 0.001
    cell.gateway(Lifecycle.STOPPED)
    requests = [f for f in cell.tick() if isinstance(f, HostRequestFrame)]
    assert all(f.request == HostRequest.SERVO_ON for f in requests), requests
    assert cell.core.desired_request(cell.t) == HostRequest.SERVO_ON
    follow(cell, Lifecycle.STOPPED, 1, q)
    assert cell.core.pending.answer == RAMP
    cell.t += 1.0  # long after: a stop that never ramped would not keep the servo on
    cell.gateway(Lifecycle.STOPPED)
    follow(cell, Lifecycle.STOPPED, 40, q)
    assert cell.core.desired_request(cell.t) == HostRequest.BRAKE


def test_a_hold_the_drives_do_not_keep_trips_the_standstill_monitor_and_the_brakes():
    cell = Cell(standstill_settle_s=0.1, standstill_band_rad=0.02, standstill_confirm_cycles=3)
    cell.gateway(Lifecycle.READY)
    cell.tick()
    follow(cell, Lifecycle.READY, 40, Q0)  # held where it was: within the band
    assert cell.core.standstill.trip is None
    q = Q0.copy()
    for _ in range(10):  # the arm sags 5 mrad per cycle under a hold set
        q[1] -= 0.005
        cell.t += 0.004
        cell.gateway(Lifecycle.READY)
        cell.cycle(q)
    health = cell.core.health(cell.t)
    assert health["standstill_trip"] and "joint 2" in health["standstill_trip"]
    assert cell.core.desired_request(cell.t) == HostRequest.BRAKE
    for _ in range(2):  # the gateway has stopped the cell, the arm on its brakes: cleared
        cell.t += 0.004
        cell.gateway(Lifecycle.FAULT)
        cell.cycle(q)
    assert cell.core.health(cell.t)["standstill_trip"] is None


def test_joint_state_pack_equals_the_dataclass_encoding():
    rng = np.random.default_rng(3)
    q, dq, i, qc, dqc = rng.normal(size=(5, N))
    ref = JointState(70001, 12.5, ControllerState.EXTERNAL, 6, q, dq, i, qc, dqc, 0.004)
    fast = JointState.pack(70001, 12.5, 2, 6, 0.004, *(v.tolist() for v in (q, dq, i, qc, dqc)))
    assert fast == ref.to_bytes()


def test_histogram_percentiles_are_within_one_bin_of_numpy():
    rng = np.random.default_rng(7)
    samples = rng.gamma(4.0, 100e-6, size=20000)
    h = Histogram(bin_s=5e-6, span_s=0.02)
    for s in samples:
        h.add(float(s))
    h.add(float("nan"))  # not a sample
    h.add(-1e-6)  # clock skew: not a sample
    assert h.n == samples.size
    for p in (50, 99, 99.9):
        nearest_rank = np.percentile(samples, p, method="inverted_cdf")
        assert 0.0 <= h.percentile_s(p) - nearest_rank <= 5e-6 + 1e-12  # its bin's upper edge
    assert h.summary()["max_us"] == pytest.approx(samples.max() * 1e6, abs=0.1)
    assert Histogram().summary()["p50_us"] is None


def test_a_command_past_the_drivers_joint_limits_is_refused_and_the_cycle_held():
    """The driver's own joint limits (the description's less [can] joint_limit_margin_rad),
    behind the control law's soft walls: a command that would put a joint within the margin
    of its limit is not forwarded; the cycle is held where the arm is."""
    from control.robot.description import load_description

    upper = load_description().upper_rad
    cell = Cell()
    q = Q0.copy()
    q[2] = upper[2] - 0.02  # inside the driver's range, near the top of joint 3
    cell.gateway(Lifecycle.TEACHING)
    js, _ = cell.cycle(q=q)
    assert cell.command(js, q)[0] == COMMAND
    beyond = q.copy()
    beyond[2] = upper[2] - 0.005  # within 0.01 rad of the limit (and 0.015 from q)
    cell.t += 0.004
    cell.gateway(Lifecycle.TEACHING)
    js, _ = cell.cycle(q=q)
    answer, frames = cell.command(js, beyond)
    assert answer == HOLD and cell.core.rejected["out_of_range"] == 1
    held = commands(frames)
    assert len(held) == N and all(f.hold for f in held)
    assert held[2].q_cmd_rad == pytest.approx(q[2], abs=1e-5)


def test_an_older_or_conflicting_lifecycle_message_is_dropped_and_counted():
    """A late "teaching" (lower seq, or the same seq with an older stamp) must not undo a
    "stopped"; the same seq naming another state is not what the gateway sends."""
    cell = Cell()
    cell.gateway(Lifecycle.TEACHING)
    js, _ = cell.cycle()
    assert cell.command(js, Q0)[0] == COMMAND
    cell.t += 0.004
    cell.core.on_lifecycle(LifecycleMsg(Lifecycle.STOPPED, 7, cell.t).to_bytes(), cell.t)
    late = LifecycleMsg(Lifecycle.TEACHING, 6, cell.t).to_bytes()  # sent before the stop
    cell.core.on_lifecycle(late, cell.t)
    refresh_before = LifecycleMsg(Lifecycle.STOPPED, 7, cell.t - 0.01).to_bytes()
    cell.core.on_lifecycle(refresh_before, cell.t)
    cell.core.on_lifecycle(LifecycleMsg(Lifecycle.TEACHING, 7, cell.t).to_bytes(), cell.t)
    cell.core.on_lifecycle(LifecycleMsg(Lifecycle.STOPPED, 7, cell.t + 0.05).to_bytes(), cell.t)
    js, sent = cell.cycle()
    assert all(f.hold for f in commands(sent))  # still stopped: held at once
    assert cell.command(js, Q0)[0] != COMMAND
    dropped = cell.core.health(cell.t)["lifecycle_dropped"]
    assert dropped == {"out_of_order": 2, "conflicting": 1}


def error_frame(cls: int, data: bytes = bytes(8)):
    import can

    return can.Message(arbitration_id=cls, is_extended_id=False, is_error_frame=True, data=data)


def test_a_bus_off_latches_a_bus_fault_until_the_bus_works_and_the_cell_is_stopped():
    from drivers.can.bus_errors import CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_RESTARTED

    cell = Cell(bus_error_window_s=0.5)
    cell.gateway(Lifecycle.TEACHING)
    cell.tick()
    js, _ = cell.cycle()
    assert cell.command(js, Q0)[0] == COMMAND
    cell.core.on_frame(error_frame(CAN_ERR_CRTL, bytes([0, 0x20, 0, 0, 0, 0, 0, 0])), cell.t)
    assert cell.core.bus.fault is None and cell.core.bus.error_passive == 1
    cell.core.on_frame(error_frame(CAN_ERR_BUSOFF), cell.t)
    health = cell.core.health(cell.t)
    assert "bus-off" in health["bus_fault"] and health["bus_off"] == 1
    assert cell.core.desired_request(cell.t) == HostRequest.BRAKE
    cell.t += 0.1  # the kernel restarts the interface (restart-ms) and frames flow again
    cell.core.on_frame(error_frame(CAN_ERR_RESTARTED), cell.t)
    with pytest.raises(AssertionError, match="completes it"):
        cell.cycle()  # the cycle an error frame came in is dropped (the adapter's rule)
    sets = follow(cell, Lifecycle.TEACHING, 200, Q0)  # 0.8 s of cycles, still teaching
    js, _ = cell.cycle()
    answer, _ = cell.command(js, Q0)
    assert answer == "" and cell.core.rejected["blocked_bus"] == 1
    assert all(f.hold for s in sets for f in s), "held while the fault is latched"
    assert cell.core.bus.fault is not None, "the bus alone never re-arms the cell"
    follow(cell, Lifecycle.FAULT, 2, Q0)  # the gateway has stopped the cell: cleared
    assert cell.core.health(cell.t)["bus_fault"] is None
    assert cell.core.health(cell.t)["bus_restarts"] == 1


def test_a_burst_of_bus_errors_latches_a_fault_and_scattered_ones_do_not():
    from drivers.can.bus_errors import CAN_ERR_PROT

    cell = Cell(bus_error_limit=5, bus_error_window_s=1.0)
    cell.gateway(Lifecycle.READY)
    for _ in range(8):  # one every 0.3 s: never 5 within a second
        cell.t += 0.3
        cell.core.on_frame(error_frame(CAN_ERR_PROT), cell.t)
    assert cell.core.bus.fault is None and cell.core.bus.error_frames == 8
    for _ in range(5):
        cell.t += 0.01
        cell.core.on_frame(error_frame(CAN_ERR_PROT), cell.t)
    assert "5 CAN error frames within 1 s" in cell.core.bus.fault
    assert "protocol violation" in cell.core.bus.fault
    assert cell.core.blocked(cell.t) in ("blocked_bus", "blocked_lifecycle")
