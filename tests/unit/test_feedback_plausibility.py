"""drivers/can/plausibility.py: measured positions that jump further than the arm can move."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.can.plausibility import FeedbackPlausibility

PERIOD_S = 0.004


def test_steps_within_the_speed_are_taken_and_a_jump_drops_one_cycle():
    p = FeedbackPlausibility(max_speed_rad_s=5.0)  # 0.02 rad a 4 ms cycle
    q = np.zeros(6)
    assert p.check(1, q, PERIOD_S) is None
    assert p.check(2, q + 0.019, PERIOD_S) is None
    glitch = q + 0.019
    glitch[3] += 0.5
    why = p.check(3, glitch, PERIOD_S)
    assert why is not None and "J4" in why and "cycle 3" in why
    assert p.check(4, q + 0.05, PERIOD_S) is None  # two cycles from the reference: 0.04 + 0.0001
    assert p.dropped == 1


def test_the_allowance_grows_with_the_cycles_between_so_a_lasting_offset_is_taken():
    p = FeedbackPlausibility(max_speed_rad_s=5.0)
    assert p.check(10, np.zeros(2), PERIOD_S) is None
    offset = np.array([0.1, 0.0])  # re-homed: five cycles' worth
    assert [p.check(c, offset, PERIOD_S) is None for c in range(11, 17)] == [
        False,
        False,
        False,
        False,
        True,  # cycle 15: 5 cycles × 0.02 rad + tolerance
        True,
    ]


@pytest.mark.parametrize("period_s", [0.0, -1.0])
def test_without_a_period_or_with_the_check_off_everything_is_taken(period_s):
    p = FeedbackPlausibility(max_speed_rad_s=5.0)
    assert p.check(1, np.zeros(3), PERIOD_S) is None
    assert p.check(2, np.full(3, 9.0), period_s) is None
    off = FeedbackPlausibility(max_speed_rad_s=0.0)
    assert off.check(1, np.zeros(3), PERIOD_S) is None
    assert off.check(2, np.full(3, 9.0), PERIOD_S) is None
