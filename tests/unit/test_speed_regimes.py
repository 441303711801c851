"""Where in speed a model's friction was measured, and the raw error by speed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from control.identification.speed_regimes import (
    TEACHING_RAD_S,
    friction_coverage,
    raw_by_speed,
    scored_velocity,
)

STICK = 2e-3


def test_coverage_gives_the_speeds_slid_at_the_reversals_and_none_for_a_joint_that_never_slid():
    t = np.linspace(0.0, 10.0, 2001)
    moving = 0.1 * np.sin(2 * np.pi * 0.5 * t)  # 5 periods: 10 reversals (one at the end)
    still = np.zeros_like(t)
    dq = np.column_stack([moving, still])
    sliding = (np.abs(dq) >= STICK).astype(float)
    cover = friction_coverage(dq, sliding, STICK)
    lo, hi = cover[0]["speed_range_rad_s"]
    assert STICK <= lo < 0.01 and 0.099 < hi <= 0.1
    assert cover[0]["reversals"] == 9
    slid = np.abs(moving[np.abs(moving) >= STICK])
    assert cover[0]["teaching_share"] == pytest.approx(np.mean(slid < TEACHING_RAD_S))
    assert cover[0]["rest_share"] == pytest.approx(np.mean(np.abs(moving) < STICK))
    assert cover[1] == {
        "sliding_rows": 0,
        "rest_share": 1.0,
        "reversals": 0,
        "speed_range_rad_s": None,
        "teaching_share": None,
    }


def test_the_raw_error_is_split_by_the_measured_speed_of_each_row_and_declined_rows_are_left_out():
    dq = np.array([[0.0], [0.001], [0.01], [0.02], [0.5], [1.0], [0.01]])
    err = np.array([[1.0], [3.0], [2.0], [2.0], [4.0], [4.0], [np.nan]])
    answered = np.isfinite(err).all(axis=1)
    out = raw_by_speed({"rms_after": err, "rms_plain_ls": 2 * err}, dq, answered, STICK)
    assert out["teaching_below_rad_s"] == pytest.approx(math.radians(2.0))
    assert out["rest"]["rms_after"] == [pytest.approx(math.sqrt(5.0))]
    assert out["teaching"]["rms_after"] == [pytest.approx(2.0)]
    assert out["faster"]["rms_plain_ls"] == [pytest.approx(8.0)]
    assert out["rest"]["share"] == [pytest.approx(2 / 6)]
    assert out["teaching"]["share"] == [pytest.approx(2 / 6)]
    none_fast = raw_by_speed({"rms_after": err[:4]}, dq[:4], answered[:4], STICK)
    assert none_fast["faster"]["rms_after"] == [None] and none_fast["faster"]["share"] == [0.0]


def test_a_file_without_velocity_columns_is_sorted_by_its_positions_derivative():
    class File:
        def __init__(self, t, q, dq):
            self.t, self.q, self.dq = t, q, dq

    t = np.linspace(0.0, 1.0, 101)
    q = np.column_stack([0.3 * t, np.zeros_like(t)])
    keep = np.zeros(t.size, dtype=bool)
    keep[10:20] = True
    v = scored_velocity([File(t, q, None), File(t, q, np.ones_like(q))], [keep, keep])
    assert v.shape == (20, 2)
    np.testing.assert_allclose(v[:10, 0], 0.3)
    np.testing.assert_allclose(v[10:], 1.0)
