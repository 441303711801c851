"""tests/slow_machine.py's factor for a target loop time: what the machine lacks, never a
speed-up, never beyond what the kernel lets the spinners take."""

from __future__ import annotations

import pytest
import slow_machine


def test_the_factor_is_the_ratio_of_the_loop_times():
    assert slow_machine.factor_for(0.54, 1.62) == pytest.approx(3.0)


def test_a_machine_already_that_slow_is_not_slowed_and_none_is_sped_up():
    assert slow_machine.factor_for(1.8, 1.62) == 1.0


def test_the_factor_stops_at_the_emulations_limit():
    assert slow_machine.factor_for(0.01, 1.62) == slow_machine.MAX_FACTOR


@pytest.mark.parametrize("loop_s, target_s", [(0.0, 1.62), (0.5, 0.0), (-1.0, 1.0)])
def test_a_loop_time_that_is_no_time_is_refused(loop_s, target_s):
    with pytest.raises(ValueError, match="loop times must be > 0"):
        slow_machine.factor_for(loop_s, target_s)
