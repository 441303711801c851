"""Pose-scheduled cylinder pressures (``[control] pressure_schedule``, control/pressure_schedule.py)
on the virtual cell, every part its own process, as the paper's Fig. 14 shows them: while the
painter pushes the arm through a range of poses, the set-points the valves receive follow the
pose, the measured pressures follow the set-points, and the motors carry less of the static
load on J3 than at the fixed set-points. Judged from the simulator's truth log (the valves'
set-points as received over Modbus, the pressures and currents as the plant has them)."""

from __future__ import annotations

import numpy as np
import pytest
from test_stack import teaching_rows

from sim_bridge.commission import commissioned_stack

pytestmark = pytest.mark.stack

SCHEDULED = {"control": {"pressure_schedule": True}}


def test_scheduled_set_points_follow_the_pose_and_the_pressures_follow_them(tmp_path):
    operator = {"mode": "force", "force_n": [30.0, 0.0, -30.0], "start_s": 0.5,
                "duration_s": 2.5}  # fmt: skip
    with commissioned_stack(
        tmp_path, sim_overrides={"operator": operator}, cell_overrides=SCHEDULED
    ) as stack:
        stack.start()
        stack.start_teaching()
        truth = stack.wait_teaching(11.0, 45.0)
        stack.request("stop")
    rows = teaching_rows(truth)
    t = truth["t_s"][rows] - truth["t_s"][rows[0]]
    sets = np.stack([truth["p2_set"][rows], truth["p3_set"][rows]], axis=1)
    meas = np.stack([truth["p2"][rows], truth["p3"][rows]], axis=1)
    q = np.stack([truth[f"q{j}"][rows] for j in (2, 3)], axis=1)
    moved = np.abs(q - q[0]).max(axis=0)
    late = t >= 10.0  # the arm stopped after the push, the set-points settled
    lag = np.abs(meas[late] - sets[late]).max(axis=0)
    print(f"pressure schedule: J2/J3 moved {np.round(moved, 3)} rad; set-points from "
          f"{np.round(sets[0], 2)} to {np.round(sets[-1], 2)} bar (range "
          f"{np.round(sets.min(axis=0), 2)}-{np.round(sets.max(axis=0), 2)}); measured "
          f"within {np.round(lag, 3)} bar of them over the last second")  # fmt: skip
    assert moved.max() > 0.05, "the push did not move J2 or J3"
    # the set-points left the fixed 6/4 bar for the pose's and moved with it
    assert np.abs(sets[-1] - [6.0, 4.0]).max() > 0.3, sets[-1]
    assert np.ptp(sets, axis=0).max() > 0.3
    # and never faster than the rate limit (2 bar/s by default; published at 10 Hz, so over
    # half a second plus one publication's step), the valves' range kept
    later = np.searchsorted(t, t + 0.5)
    ok = later < len(t)
    span = t[later[ok]] - t[ok]
    change = np.abs(sets[later[ok]] - sets[ok]).max(axis=1)
    # (the control process's clock against the plant's, and Modbus polling, jitter by a step)
    assert np.all(change <= 2.0 * (span + 0.2) + 1e-6), f"set-point moved {change.max()} bar"
    assert sets.min() >= 0.5 - 1e-6 and sets.max() <= 8.0 + 1e-6
    # the gas follows (the paper's Fig. 14; its lag is 0.25 s, so a 2 bar/s ramp runs 0.5 bar
    # ahead of it): once the set-points have (nearly) settled, within 0.1 bar
    assert np.ptp(sets[late], axis=0).max() < 0.2, "the set-points were still ramping"
    assert lag.max() < 0.1, f"measured pressure {lag} bar from the set-point"
