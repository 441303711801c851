"""Lost command cycles and their policy (drivers/can/lost_cycles.py, issue 10): counted only
when forwarding was allowed, answered by coasting or holding as configured, and N in a row or
M within a window stop the arm and latch until the cell is stopped."""

from __future__ import annotations

import numpy as np
import pytest
from test_can_core import PERIOD_US, Q0, Cell, commands

from drivers.can.config import CanDriverConfig
from drivers.can.core import COAST, COMMAND, HOLD, RAMP
from drivers.can.lost_cycles import LostCycles
from gateway.errors import ConfigError
from gateway.lifecycle import Lifecycle

PERIOD_S = PERIOD_US * 1e-6


def test_n_lost_in_a_row_trip_and_a_forwarded_cycle_breaks_the_run():
    lost = LostCycles(max_consecutive=3, max_per_window=0, window_s=1.0)
    assert lost.record(True, 0.0) is None and lost.record(True, 0.004) is None
    assert lost.record(False, 0.008) is None  # a command came: the run starts again
    assert lost.record(True, 0.012) is None and lost.record(True, 0.016) is None
    trip = lost.record(True, 0.020)
    assert trip is not None and trip.message() == "3 command cycles lost in a row"
    assert lost.record(False, 0.024) is None and lost.trip is trip, "a trip stays"
    lost.reset()
    assert lost.trip is None and lost.lost == 5


def test_m_lost_within_the_window_trip_when_none_are_in_a_row():
    lost = LostCycles(max_consecutive=3, max_per_window=4, window_s=1.0)
    for k in range(3):  # every other cycle lost, 0.3 s apart: 3 within a second
        assert lost.record(True, 0.3 * k) is None
        assert lost.record(False, 0.3 * k + 0.004) is None
    assert lost.record(True, 1.2) is None, "the first one has left the window"
    trip = lost.record(True, 1.25)
    assert (
        trip is not None
        and trip.rule == "window"
        and "4 command cycles lost within 1 s" in (trip.message())
    )


def test_zero_turns_a_rule_off_and_nonsense_is_refused():
    lost = LostCycles(0, 0, 1.0)
    assert all(lost.record(True, 0.001 * k) is None for k in range(1000))
    with pytest.raises(ValueError, match="window"):
        LostCycles(1, 1, 0.0)
    transport = {"interface": "virtual", "channel": "x"}
    with pytest.raises(ConfigError, match=r"lost_cycle_answer.*'brake'"):
        CanDriverConfig(transport=transport, lost_cycle_answer="brake")
    with pytest.raises(ConfigError, match="lost_cycles_max_consecutive"):
        CanDriverConfig(transport=transport, lost_cycles_max_consecutive=-1)


def _teach(cell: Cell, dq: float = 0.0) -> np.ndarray:
    cell.gateway(Lifecycle.TEACHING)
    cell.tick()
    js, _ = cell.cycle()
    assert cell.command(js, Q0, dq)[0] == COMMAND
    return Q0.copy()


def _miss(cell: Cell, q: np.ndarray, **io) -> str:
    """One cycle whose command never comes: the driver answers at the deadline; its answer."""
    cell.t += PERIOD_S
    cell.gateway(Lifecycle.TEACHING, **io)
    cell.cycle(q)
    cell.t += 0.0021  # past the answer deadline, half the period
    cell.tick()
    cell.t -= 0.0021
    return cell.core.pending.answer


def test_the_driver_holds_and_latches_after_n_lost_cycles_until_the_cell_is_stopped():
    cell = Cell(lost_cycles_max_consecutive=5, hand_guiding_max_speed_m_s=0.0)
    q = _teach(cell)
    answers = [_miss(cell, q) for _ in range(5)]
    assert answers[0] == COAST and answers[-1] == HOLD  # coasting ends at deadline_s
    health = cell.core.health(cell.t)
    assert health["lost_cycles"] == 5 and health["lost_cycles_trip"] == (
        "5 command cycles lost in a row"
    )
    cell.t += PERIOD_S
    cell.gateway(Lifecycle.TEACHING)
    js, frames = cell.cycle(q)
    assert all(f.hold for f in commands(frames)), "held at once, no longer waiting"
    assert cell.command(js, Q0)[0] == "" and cell.core.rejected["blocked_lost"] == 1
    cell.t += PERIOD_S
    cell.gateway(Lifecycle.FAULT)  # the gateway faults on the trip: the cell is stopped
    cell.cycle(q)
    assert cell.core.health(cell.t)["lost_cycles_trip"] is None


def test_a_link_losing_every_other_cycle_trips_the_window_rule_and_the_arm_ramps_to_rest():
    cell = Cell(
        lost_cycles_max_consecutive=5,
        lost_cycles_max_per_window=4,
        lost_cycles_window_s=1.0,
        hand_guiding_max_speed_m_s=0.0,
        stop_deceleration_rad_s2=1.0,
    )
    q = _teach(cell, 0.2)
    for _ in range(4):
        assert _miss(cell, q) == COAST
        cell.t += PERIOD_S
        cell.gateway(Lifecycle.TEACHING)
        js, _ = cell.cycle(q)
        if cell.core.lost.trip is None:
            assert cell.command(js, q, 0.2)[0] == COMMAND
    assert "4 command cycles lost within 1 s" in cell.core.health(cell.t)["lost_cycles_trip"]
    assert cell.core.pending.answer == RAMP, "stopped as for a released enabling device"


def test_blocked_cycles_are_not_lost_and_hold_answers_never_coast():
    cell = Cell(lost_cycles_max_consecutive=3, lost_cycle_answer="hold")
    q = _teach(cell, 0.2)
    assert _miss(cell, q) == HOLD, "no extrapolation asked for"
    for _ in range(10):  # the enabling device released: the driver stops the arm, not lost
        _miss(cell, q, enabling=False)
    assert cell.core.lost.lost == 1 and cell.core.lost.trip is None
