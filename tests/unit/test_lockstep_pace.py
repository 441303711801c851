"""sim_bridge.lockstep_pace: the lock-step plant never runs faster than its pace, also after
it fell behind it."""

from __future__ import annotations

import pytest

from sim_bridge.lockstep_pace import LockstepPace

PERIOD_S = 0.008
SPEEDUP = 3.0


def test_a_plant_at_the_pace_waits_for_the_wall_clock():
    pace = LockstepPace(SPEEDUP, PERIOD_S / SPEEDUP, wall_s=100.0, plant_s=0.0)
    # the cycle at plant time 8 ms may start 8/3 ms after the start, not before
    assert pace.wait_s(PERIOD_S, 100.0) == pytest.approx(PERIOD_S / SPEEDUP)
    assert pace.wait_s(PERIOD_S, 100.0 + PERIOD_S / SPEEDUP) == 0.0


def test_one_late_answer_within_the_slack_is_caught_up_without_a_restart():
    pace = LockstepPace(SPEEDUP, PERIOD_S / SPEEDUP, wall_s=0.0, plant_s=0.0)
    late = 0.5 * PERIOD_S / SPEEDUP
    assert pace.wait_s(PERIOD_S, PERIOD_S / SPEEDUP + late) == 0.0
    assert pace.restarts == 0
    # the next cycle waits the rest of its share: the pace is kept over the two
    assert pace.wait_s(2 * PERIOD_S, PERIOD_S / SPEEDUP + late) == pytest.approx(
        PERIOD_S / SPEEDUP - late
    )


def test_a_plant_far_behind_goes_on_at_the_pace_from_there_instead_of_racing_to_catch_up():
    pace = LockstepPace(SPEEDUP, PERIOD_S / SPEEDUP, wall_s=0.0, plant_s=0.0)
    stall_s = 0.3  # the product answered 0.3 s late
    assert pace.wait_s(PERIOD_S, stall_s) == 0.0
    assert pace.restarts == 1
    # the cycles after it start no faster than the pace allows, from the stall's end
    for k in range(1, 50):
        wall = stall_s + (k - 1) * PERIOD_S / SPEEDUP
        assert pace.wait_s(PERIOD_S + k * PERIOD_S, wall) == pytest.approx(PERIOD_S / SPEEDUP)
    assert pace.restarts == 1


def test_a_speedup_that_is_not_positive_is_refused():
    with pytest.raises(ValueError, match="speedup 0"):
        LockstepPace(0.0, 0.001, 0.0, 0.0)
