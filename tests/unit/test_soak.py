"""The soak benchmark's script and its quiet-rest figure (sim_bridge/soak.py), and the hand
that lets go in the operator's windows (sim_bridge/operator.py)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.config import OperatorScript
from sim_bridge.operator import Operator
from sim_bridge.soak import DWELL_S, LEAD_S, MOVE_S, REST_S, SETTLE_S, STROKE_M, quiet_peak, strokes


def test_the_strokes_go_out_and_back_and_the_hand_rests_at_each_end():
    points, rests = strokes(60.0)
    assert points[0] == [0.0, 0.0, 0.0, 0.0] and points[-1][0] >= 60.0
    assert {p[1] for p in points} == {0.0, STROKE_M}
    assert rests[0] == (LEAD_S + MOVE_S + DWELL_S, LEAD_S + MOVE_S + DWELL_S + REST_S)
    assert all(b - a == pytest.approx(REST_S) for a, b in rests)
    for a, b in rests:  # the target stands still through a rest
        before = [p for p in points if p[0] <= a][-1]
        after = next(p for p in points if p[0] >= b)
        assert before[1:] == after[1:]


def test_a_creep_late_in_a_rest_is_caught_and_the_glide_after_letting_go_is_not():
    t = np.arange(0.0, 20.0, 0.004)
    truth = {"t_s": t, "teaching": (t >= 1.0).astype(float), "tool_y": np.zeros_like(t),
             "tool_z": np.zeros_like(t)}  # fmt: skip
    rests = [(5.0, 8.0)]  # after the onset at 1 s: 6-9 s, judged from 7 s
    glide = (t > 6.0) & (t < 6.0 + SETTLE_S - 0.1)
    truth["tool_x"] = np.cumsum(np.where(glide, 0.05 * 0.004, 0.0))
    assert quiet_peak(truth, rests) == 0.0
    creep = (t > 8.2) & (t < 8.9)
    truth["tool_x"] = np.cumsum(np.where(creep, 0.02 * 0.004, 0.0))
    assert quiet_peak(truth, rests) == pytest.approx(0.02, rel=1e-6)


def test_the_hand_lets_go_in_its_windows_and_takes_hold_again():
    script = OperatorScript(mode="force", force_n=(10.0, 0.0, 0.0), start_s=0.0, duration_s=10.0,
                            ramp_s=0.0, hand_off_windows_s=((2.0, 3.0),))  # fmt: skip
    op = Operator(script)
    op.onset_s = 0.0

    class Plant:
        t_s = 0.0

    plant = Plant()
    forces = []
    for t in (1.0, 2.5, 3.5):
        plant.t_s = t
        forces.append(op.hand(plant)[0])  # type: ignore[arg-type]
    assert forces == [10.0, 0.0, 10.0]
