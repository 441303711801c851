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


def test_a_loop_slower_than_the_target_under_the_emulation_lowers_the_factor():
    # 2026-12-05: this machine's loop 0.30 s alone, 1.83 s at 5.46x, 1.62 s asked
    factor = slow_machine.corrected_factor(5.46, 1.83, 1.62, 0.30)
    assert 1.0 < factor < 5.46
    # at that factor, the window less the cost read from the timing gives the target
    cost = 1.0 / 5.46 - 0.30 / 1.83
    assert 0.30 / (1.0 / factor - cost) == pytest.approx(1.62)


def test_a_loop_faster_than_the_target_raises_the_factor():
    assert slow_machine.corrected_factor(3.0, 1.0, 1.62, 0.30) > 3.0


def test_a_loop_within_the_tolerance_keeps_the_factor():
    near = 1.62 * (1.0 + 0.5 * slow_machine.CALIBRATION_TOLERANCE)
    assert slow_machine.corrected_factor(3.0, near, 1.62, 0.5) is None


def test_a_correction_never_speeds_the_machine_up_nor_passes_the_limit():
    assert slow_machine.corrected_factor(1.2, 3.0, 1.0, 0.9) == 1.0
    assert slow_machine.corrected_factor(19.0, 0.5, 1.62, 0.1) == slow_machine.MAX_FACTOR


def test_a_correction_from_no_time_is_refused():
    with pytest.raises(ValueError, match="loop times must be > 0"):
        slow_machine.corrected_factor(3.0, 0.0, 1.62, 0.3)
