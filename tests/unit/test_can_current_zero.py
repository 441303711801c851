"""The current sensors' zero (drivers/can/current_zero.py): the mean of the newest cycles
reported with the servo power off, after the settle cycles, frozen while powered."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.can.current_zero import CurrentZero


def test_the_zero_is_the_mean_of_the_newest_unpowered_cycles_after_settling():
    z = CurrentZero(2, window=3, settle=1)
    z.update(np.array([5.0, 5.0]), servo_power=False)  # settling: the filter's powered ticks
    assert z.samples == 0 and not z.offset_a.any()
    for v in (1.0, 2.0, 3.0, 4.0):
        z.update(np.array([v, -v]), servo_power=False)
    np.testing.assert_allclose(z.offset_a, [3.0, -3.0])  # the newest three
    z.update(np.array([100.0, 100.0]), servo_power=True)
    np.testing.assert_allclose(z.correct(np.array([10.0, 0.0])), [7.0, 3.0])
    z.update(np.array([100.0, 100.0]), servo_power=False)  # settling again after power-off
    np.testing.assert_allclose(z.offset_a, [3.0, -3.0])
    z.update(np.array([np.nan, 0.0]), servo_power=False)  # a NaN never enters the mean
    np.testing.assert_allclose(z.offset_a, [3.0, -3.0])


def test_a_zero_window_disables_it_and_negative_sizes_are_refused():
    z = CurrentZero(1, window=0, settle=0)
    z.update(np.array([0.5]), servo_power=False)
    assert z.samples == 0 and z.correct(np.array([1.0]))[0] == 1.0
    with pytest.raises(ValueError, match="window"):
        CurrentZero(1, window=-1, settle=0)
