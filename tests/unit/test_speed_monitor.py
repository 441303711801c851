"""Hand guiding's speed monitor in the CAN driver (drivers/can/speed_monitor.py, issue 10):
from measured positions alone, it trips on the tool or the flange going faster than 250 mm/s
while teaching or replaying; the driver then holds every cycle, asks for the brakes and the
gateway faults."""

from __future__ import annotations

import numpy as np
import pytest
from test_can_core import Q0, Cell, commands

from drivers.can.adapter import HostRequest
from drivers.can.config import CanDriverConfig
from drivers.can.core import HOLD
from drivers.can.speed_monitor import SpeedMonitor, datasheet_points
from gateway.errors import ConfigError
from gateway.lifecycle import Lifecycle, LifecycleMachine, Observations
from gateway.messages import ControllerState

PERIOD_S = 0.004


def _points(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A toy arm: the tool point is q[:3], the flange q[:3] + q[3:]."""
    return q[:3].copy(), q[:3] + q[3:]


def _run(monitor: SpeedMonitor, velocity: np.ndarray, cycles: int, start: int = 0):
    q = np.zeros(6)
    trip = None
    for k in range(cycles):
        trip = monitor.update(start + k, q + velocity * k * PERIOD_S, PERIOD_S)
    return trip


def test_a_tool_over_the_limit_trips_and_one_under_it_does_not():
    monitor = SpeedMonitor(_points, 0.25, window=3, confirm=2)
    assert _run(monitor, np.array([0.0, 0.24, 0.0, 0.0, 0.0, 0.0]), 50) is None
    assert monitor.peak_m_s == pytest.approx(0.24)
    monitor.reset()
    trip = _run(monitor, np.array([0.0, 0.18, 0.18, 0.0, 0.0, 0.0]), 50)  # 0.255 m/s
    assert trip is not None and trip.point == "tool"
    assert trip.speed_m_s == pytest.approx(0.18 * np.sqrt(2)) and trip.cycle == 4
    assert "255 mm/s" in trip.message() and "250 mm/s" in trip.message()


def test_the_flange_is_watched_too_when_the_tool_turns_about_its_point():
    monitor = SpeedMonitor(_points, 0.25)
    trip = _run(monitor, np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0]), 20)
    assert trip is not None and trip.point == "flange"


def test_a_single_cycle_over_the_limit_is_not_a_trip_and_a_gap_is_no_speed():
    monitor = SpeedMonitor(_points, 0.25, window=1, confirm=2)
    q = np.zeros(6)
    monitor.update(0, q, PERIOD_S)
    jump = q.copy()
    jump[0] = 0.002  # 0.5 m/s for one cycle (an encoder glitch), then still
    assert monitor.update(1, jump, PERIOD_S) is None
    assert monitor.update(2, jump, PERIOD_S) is None
    monitor.gap()
    far = jump.copy()
    far[0] = 1.0  # where the arm is after the controller stopped servoing: not a speed
    assert monitor.update(40, far, PERIOD_S) is None
    assert monitor.update(41, far, PERIOD_S) is None


def test_a_trip_stays_until_reset():
    monitor = SpeedMonitor(_points, 0.25)
    assert _run(monitor, np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0]), 10) is not None
    assert monitor.update(100, np.zeros(6), PERIOD_S) is not None
    monitor.reset()
    assert monitor.trip is None and monitor.update(101, np.zeros(6), PERIOD_S) is None


def test_the_datasheet_points_put_the_flange_behind_the_tool():
    points = datasheet_points()
    tool, flange = points(Q0)
    assert 0.05 < np.linalg.norm(tool - flange) < 1.0


def _teach_and_turn_j1(cell: Cell, state: Lifecycle, speed_rad_s: float, cycles: int):
    q = Q0.copy()
    answers = []
    for _ in range(cycles):
        cell.gateway(state)
        cell.t += PERIOD_S
        js, _ = cell.cycle(q=q)
        answers.append(cell.command(js, q)[0])
        q = q + np.array([speed_rad_s * PERIOD_S, 0, 0, 0, 0, 0])
    return answers


def test_the_driver_brakes_once_the_arm_outruns_hand_guiding_and_clears_when_teaching_ends():
    cell = Cell()
    assert cell.core.speed is not None
    answers = _teach_and_turn_j1(cell, Lifecycle.TEACHING, 0.05, 20)  # a slow turn
    assert set(answers) == {"command"}
    health = cell.core.health(cell.t)
    assert health["speed_trip"] is None and 0.0 < health["speed_peak_m_s"] < 0.25
    answers = _teach_and_turn_j1(cell, Lifecycle.TEACHING, 1.0, 20)  # the tool at ~1 m/s
    assert answers[:3] == ["command"] * 3 and set(answers[6:]) == {""}
    assert cell.core.rejected["blocked_speed"] >= 14
    here = cell.core.feedback.q_rad  # where the turn has got the arm
    _, frames = cell.cycle(q=here)  # a tripped driver holds every cycle at once
    held = commands(frames)
    assert len(held) == 6 and all(f.hold and f.dq_cmd_rad_s == 0.0 for f in held)
    assert cell.core.pending.answer == HOLD
    assert "mm/s" in cell.core.health(cell.t)["speed_trip"]
    # the brakes, not a rigid hold the hand outrunning it would fight into a power cut
    assert cell.core.desired_request(cell.t) == HostRequest.BRAKE
    cell.gateway(Lifecycle.FAULT)  # the gateway faults on the trip...
    cell.cycle(q=here)
    assert cell.core.health(cell.t)["speed_trip"] is None  # ...which clears it for a reset


def test_identification_runs_faster_than_hand_guiding_unmonitored():
    cell = Cell()
    answers = _teach_and_turn_j1(cell, Lifecycle.IDENTIFYING, 1.0, 20)
    assert set(answers) == {"command"} and cell.core.health(cell.t)["speed_trip"] is None


def test_no_monitor_when_the_limit_is_zero_and_a_limit_past_1_m_s_is_refused():
    assert Cell(hand_guiding_max_speed_m_s=0.0).core.speed is None
    with pytest.raises(ConfigError, match="hand_guiding_max_speed_m_s"):
        CanDriverConfig(
            transport={"interface": "virtual", "channel": "x"}, hand_guiding_max_speed_m_s=2.0
        )


@pytest.mark.parametrize(
    ("field", "trip", "named"),
    [
        ("speed_trip", "the tool moved at 262 mm/s", "speed monitor"),
        ("standstill_trip", "joint 2 left its hold by 25.0 mrad", "standstill monitor"),
        ("bus_fault", "the CAN interface went bus-off", "CAN bus"),
    ],
)
def test_the_gateway_faults_on_the_trip_and_resets_once_it_is_cleared(field, trip, named):
    """The CAN driver's latched trips (speed and standstill monitors, bus fault): each faults
    the cell with what it measured, and a reset is refused while it stands."""
    machine = LifecycleMachine()
    ok = Observations(0.01, 0.01, ControllerState.EXTERNAL, True, True, max_speed_rad_s=0.0,
                      still_for_s=5.0)  # fmt: skip
    machine.command("start", ok)
    machine.update(ok)
    assert machine.state == Lifecycle.TEACHING
    tripped = Observations(0.01, 0.01, ControllerState.EXTERNAL, True, True,
                           driver_trips={field: trip})  # fmt: skip
    machine.update(tripped)
    assert machine.state == Lifecycle.FAULT and trip in machine.reason
    assert named in machine.reason
    accepted, message = machine.command("reset", tripped)
    assert not accepted and named in message
    assert machine.command("reset", ok)[0] and machine.state == Lifecycle.STOPPED
