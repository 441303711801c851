"""The plan player times a plan's building on the wall clock, not in controller cycles: the
worker computes in wall time, and a lock-stepped virtual plant runs its cycles faster than the
clock (control/plan_player.py ``PlanPlayer._planned``)."""

from __future__ import annotations

import numpy as np

from control.plan_player import PlanPlayer
from gateway.message_factories import make_joint_state
from gateway.messages import FLAG_SERVO_POWER, ControllerState
from gateway.robot.description import load_description

PERIOD_S = 0.008
Q_HELD = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])


class _NeverDone:
    """A plan builder whose plan is never built (the worker busy for ever)."""

    def submit(self, *args) -> int:
        return 1

    def poll(self, job: int):
        return None


def _state(cycle: int):
    z = np.zeros(6)
    return make_joint_state(cycle, 0.0, ControllerState.EXTERNAL, FLAG_SERVO_POWER, Q_HELD, z, z,
                            Q_HELD, z, PERIOD_S)  # fmt: skip


def test_cycles_run_faster_than_the_clock_do_not_fail_a_plan_in_building():
    desc = load_description()
    now = [100.0]
    player = PlanPlayer(desc.lower_rad, desc.upper_rad, desc, _NeverDone(), clock=lambda: now[0])
    player.start({"plan_id": "p"}, _state(0), PERIOD_S)
    # cycles for 1.5 times the limit within 3/8 of it on the clock, as a 4x lock-stepped plant
    cycles = int(1.5 * PlanPlayer.MAX_PLANNING_S / PERIOD_S)
    for k in range(1, cycles + 1):
        now[0] = 100.0 + k * PERIOD_S / 4.0
        q, dq = player.command(_state(k))
        assert player.state == "planning", k
        np.testing.assert_array_equal(q, Q_HELD)  # held where the plan starts, at rest
        assert not dq.any()
    assert abs(player.planning_s - cycles * PERIOD_S / 4.0) < 1e-6
    # the clock passes the limit: the plan fails, nothing more is sent for it
    now[0] = 100.0 + PlanPlayer.MAX_PLANNING_S + 0.01
    assert player.command(_state(cycles + 1)) is None
    assert player.state == "failed" and "not planned within" in player.reason
