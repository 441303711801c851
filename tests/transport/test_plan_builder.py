"""Plans built off the cycle (control/plan_builder.py): the replay path is built in a worker
process while the player answers every cycle with a hold where the plan starts; the built plan
is the one built in place; a refused plan and a worker that dies fail the plan with the reason;
a plan that takes too long fails and the arm was held all along."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
from example_program import write_program

from control.plan_builder import PlanBuilder, PlanRefused, build_parts
from control.plan_player import PlanPlayer
from control.plan_worker import WORKER_NICENESS
from gateway.message_factories import make_joint_state
from gateway.messages import FLAG_PREV_HOLD, FLAG_SERVO_POWER, ControllerState
from gateway.robot.description import load_description

PERIOD_S = 0.008
Q_HELD = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
#: a worker process starts (a fresh interpreter, numpy, pinocchio) and builds a short replay
#: path well within this on the slowest machine of our class [s]
BUILD_TIMEOUT_S = 60.0


def _state(cycle: int):
    z = np.zeros(6)
    return make_joint_state(cycle, 0.0, ControllerState.EXTERNAL, FLAG_SERVO_POWER, Q_HELD, z, z,
                            Q_HELD, z, PERIOD_S)  # fmt: skip


def _replay_plan(tmp_path) -> dict:
    """The replay plan of a short taught program written into ``tmp_path``."""
    program = tmp_path / "p.jsonl"
    write_program(program, np.array([0.1, 0.2, 0.3, 0.0, -0.3, 0.0]))
    return {"plan_id": "r", "replay": {"program": str(program), "speed_m_s": 0.1}}


@pytest.fixture
def builder():
    b = PlanBuilder()
    b.start()
    yield b
    b.close()


def _until_not_planning(player: PlanPlayer, first_cycle: int) -> tuple[int, list]:
    """Cycles fed (one per PERIOD_S of wall time, as the driver would) until the player left
    ``planning``, and what it answered meanwhile."""
    held, cycle, deadline = [], first_cycle, time.monotonic() + BUILD_TIMEOUT_S
    while time.monotonic() < deadline:
        cycle += 1
        out = player.command(_state(cycle))
        if player.state != "planning":
            return cycle, held
        held.append(out)
        time.sleep(PERIOD_S)
    raise AssertionError(f"still planning after {BUILD_TIMEOUT_S} s")


def test_a_replay_is_built_in_the_worker_while_every_cycle_is_answered_with_a_hold(
    tmp_path, builder
):
    desc = load_description()
    plan = _replay_plan(tmp_path)
    player = PlanPlayer(desc.lower_rad, desc.upper_rad, desc, builder)
    player.start(plan, _state(100), PERIOD_S)
    assert player.state == "planning" and player.report()["state"] == "planning"
    _, held = _until_not_planning(player, 100)
    assert player.state == "running", player.reason
    assert held, "the plan was built before the next cycle: nothing shows it ran elsewhere"
    for q, dq in held:  # every cycle meanwhile: the pose the robot holds, at rest
        np.testing.assert_array_equal(q, Q_HELD)
        np.testing.assert_array_equal(dq, np.zeros(6))
    # the worker's plan is the one built in place
    in_place = PlanPlayer(desc.lower_rad, desc.upper_rad, desc)
    in_place.start(plan, _state(100), PERIOD_S)
    np.testing.assert_array_equal(player.q, in_place.q)
    np.testing.assert_array_equal(player.dq, in_place.dq)
    assert player.segments == in_place.segments
    assert player.report()["planning_s"] > 0


def _until_polled(player: PlanPlayer) -> None:
    """Poll as the control process's slow loop does (every 0.1 s) until not planning."""
    deadline = time.monotonic() + BUILD_TIMEOUT_S
    while player.state == "planning" and time.monotonic() < deadline:
        player.poll()
        time.sleep(0.1)


def test_while_planning_the_compiled_loop_holds_the_pose_at_rest_then_plays_the_plan(
    tmp_path, builder
):
    """The compiled slot (what the control process's compiled loop answers the cycles with)
    holds the pose the plan starts from, at rest, while the worker builds; the driver holding
    those commands longer than a plan's pause limit does not fail it; the slow loop's poll
    puts the built plan there."""
    desc = load_description()
    player = PlanPlayer(desc.lower_rad, desc.upper_rad, desc, builder)
    player.start(_replay_plan(tmp_path), _state(100), PERIOD_S)
    held_cycles = int(2 * PlanPlayer.MAX_PAUSE_S / PERIOD_S)
    for k in range(1, held_cycles + 1):  # every command held by the driver (late, say)
        sample = player.play.command(100 + k, FLAG_SERVO_POWER | (FLAG_PREV_HOLD if k > 1 else 0))
        assert sample is not None, k
        np.testing.assert_array_equal(sample[0], Q_HELD)
        assert not any(sample[1])
    assert player.state == "planning"
    _until_polled(player)
    assert player.state == "running", player.reason
    status = player.play.status()
    assert status is not None and status[0] == "running" and status[3] == len(player.q) > 1


def test_a_plan_refused_while_planning_leaves_the_compiled_loop_nothing_to_send(builder):
    desc = load_description()
    player = PlanPlayer(desc.lower_rad, desc.upper_rad, desc, builder)
    plan = {"plan_id": "bad", "replay": {"program": "/nonexistent.jsonl", "speed_m_s": 0.1}}
    player.start(plan, _state(100), PERIOD_S)
    assert player.play.command(101, FLAG_SERVO_POWER) is not None  # held while planning
    _until_polled(player)
    assert player.state == "failed" and "cannot read program" in player.reason
    assert player.play.status() is None
    assert player.play.command(102, FLAG_SERVO_POWER) is None


def test_a_refused_plan_fails_with_the_reason_and_nothing_moves(builder):
    desc = load_description()
    player = PlanPlayer(desc.lower_rad, desc.upper_rad, desc, builder)
    plan = {"plan_id": "bad", "replay": {"program": "/nonexistent.jsonl", "speed_m_s": 0.1}}
    player.start(plan, _state(100), PERIOD_S)
    cycle, _ = _until_not_planning(player, 100)
    assert player.state == "failed" and "cannot read program" in player.reason
    assert player.command(_state(cycle + 1)) is None


def test_a_plan_not_built_in_time_fails_and_the_arm_was_held(builder, tmp_path):
    desc = load_description()
    plan = _replay_plan(tmp_path)
    player = PlanPlayer(desc.lower_rad, desc.upper_rad, desc, builder)
    player.MAX_PLANNING_S = 0.0  # any plan takes longer than no time
    player.start(plan, _state(100), PERIOD_S)
    out = player.command(_state(101))
    assert player.state == "failed" and "not planned within" in player.reason
    assert out is None


def test_a_worker_that_dies_fails_the_plan_and_the_next_plan_gets_a_new_one(builder, tmp_path):
    desc = load_description()
    plan = _replay_plan(tmp_path)
    player = PlanPlayer(desc.lower_rad, desc.upper_rad, desc, builder)
    player.start(plan, _state(100), PERIOD_S)
    assert builder._proc is not None
    builder._proc.kill()
    builder._proc.wait(5.0)
    _until_not_planning(player, 100)
    assert player.state == "failed" and "process ended" in player.reason
    player.start({**plan, "plan_id": "r2"}, _state(200), PERIOD_S)
    _until_not_planning(player, 200)
    assert player.state == "running", player.reason


def _niceness(pid: int) -> int:
    stat = Path(f"/proc/{pid}/stat").read_text()
    return int(stat[stat.rfind(")") + 2 :].split()[16])  # field 19: nice


def test_the_worker_runs_below_the_cycle(builder):
    """The worker lowers its own priority before its imports (control/plan_worker.py): the
    scheduler prefers the cycle's processes over it, even while it starts."""
    assert builder._proc is not None
    expected = min(os.nice(0) + WORKER_NICENESS, 19)
    deadline = time.monotonic() + BUILD_TIMEOUT_S
    while _niceness(builder._proc.pid) != expected and time.monotonic() < deadline:
        time.sleep(0.001)
    assert _niceness(builder._proc.pid) == expected
    assert os.nice(0) == expected - WORKER_NICENESS or expected == 19  # the owner's unchanged


def test_build_parts_names_what_was_wrong():
    desc = load_description()
    with pytest.raises(PlanRefused, match="replay speed"):
        build_parts({"replay": {"program": "p.jsonl", "speed_m_s": 9.0}}, Q_HELD,
                    desc.lower_rad, desc.upper_rad, PERIOD_S, 0.05, desc,
                    {"max_speed_m_s": 0.25, "max_joint_speed_rad_s": 0.3,
                     "max_point_speed_m_s": 0.2})  # fmt: skip
