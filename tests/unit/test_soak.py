"""The soak benchmark's script and its quiet-dwell figure (sim_bridge/soak.py)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.soak import DWELL_S, LEAD_S, MOVE_S, QUIET_S, STROKE_M, dwells, quiet_peak, strokes


def test_the_strokes_go_out_and_back_with_a_dwell_at_each_end():
    points = strokes(30.0)
    assert points[0] == [0.0, 0.0, 0.0, 0.0] and points[-1][0] >= 30.0
    xs = {p[1] for p in points}
    assert xs == {0.0, STROKE_M}
    windows = dwells(points)
    assert windows[0] == (LEAD_S + MOVE_S, LEAD_S + MOVE_S + DWELL_S)
    assert all(b - a == pytest.approx(DWELL_S) for a, b in windows)
    assert len(windows) == len(points) // 2 - 1


def test_a_creep_in_the_tail_of_a_dwell_is_caught_and_one_before_it_is_not():
    t = np.arange(0.0, 20.0, 0.004)
    x = np.zeros_like(t)
    truth = {"t_s": t, "teaching": (t >= 1.0).astype(float), "tool_x": x,
             "tool_y": np.zeros_like(t), "tool_z": np.zeros_like(t)}  # fmt: skip
    window = [(5.0, 8.0)]  # after the onset at 1 s: 6-9 s
    creep = (t > 6.2) & (t < 7.5)  # moving before the dwell's last second only
    truth["tool_x"] = np.cumsum(np.where(creep, 0.05 * 0.004, 0.0))
    assert quiet_peak(truth, window) == 0.0
    late = (t > 9.0 - QUIET_S + 0.2) & (t < 8.9)
    truth["tool_x"] = np.cumsum(np.where(late, 0.02 * 0.004, 0.0))
    assert quiet_peak(truth, window) == pytest.approx(0.02, rel=1e-6)
