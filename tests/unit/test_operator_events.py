"""The simulated operator's release and e-stop in motion (``event_min_speed_m_s``): once due,
they wait for a cycle by which the tool has moved that fast over each of the last two 0.1 s;
without it
they happen at their time, moving or not."""

from __future__ import annotations

import numpy as np

from sim_bridge.config import OperatorScript
from sim_bridge.operator import Operator

PERIOD_S = 0.008


def _run(script: OperatorScript, speeds_m_s: list[float]) -> tuple[float | None, float | None]:
    """Cycles with the tool moving along x at each speed in turn (one per cycle, from onset
    at t = 0): the sim times the enabling device was first released and the e-stop opened."""
    op = Operator(script)
    x, released, estop = 0.0, None, None
    op.mark_onset(0.0, np.zeros(3))
    for k, v in enumerate(speeds_m_s, start=1):
        t = k * PERIOD_S
        x += v * PERIOD_S
        op.observe(t, np.array([x, 0.0, 0.0]))
        if released is None and not op.enabling(t):
            released = t
        if estop is None and op.estop_pressed(t):
            estop = t
    return released, estop


def test_a_due_release_waits_for_the_tool_to_move_and_an_estop_too():
    script = OperatorScript(release_after_s=0.2, estop_after_s=0.3, event_min_speed_m_s=0.1)
    still, moving = [0.0] * 100, [0.15] * 100  # 0.8 s at rest, then 0.8 s at 0.15 m/s
    released, estop = _run(script, still + moving)
    # due at 0.2 and 0.3 s; the first of the two 0.1 s means reaches 0.1 m/s 0.167 s after
    # the tool starts
    assert released is not None and estop is not None
    assert 0.8 + 0.16 <= released <= 0.8 + 0.18 and estop == released


def test_a_tool_that_never_moves_fast_enough_is_never_released():
    script = OperatorScript(release_after_s=0.2, event_min_speed_m_s=0.1)
    assert _run(script, [0.09] * 200) == (None, None)


def test_without_a_minimum_speed_the_events_happen_at_their_time():
    script = OperatorScript(release_after_s=0.2, estop_after_s=0.3)
    released, estop = _run(script, [0.0] * 100)
    assert abs(released - 0.2) < PERIOD_S and abs(estop - 0.3) < PERIOD_S
