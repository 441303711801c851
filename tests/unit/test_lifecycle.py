from dataclasses import replace

import pytest

from gateway.lifecycle import CONTROLLER_RESET_UPDATES, LifecycleMachine, Limits, Observations
from gateway.messages import ControllerState, Lifecycle


def healthy(**kw) -> Observations:
    base = dict(
        joint_state_age_s=0.01,
        io_age_s=0.02,
        controller_state=ControllerState.HOLD,
        enabling=False,
        estop_ok=True,
        max_speed_rad_s=0.0,
        still_for_s=1.0,
        servo_on_for_s=5.0,
    )
    return Observations(**{**base, **kw})


def test_starts_stopped_and_start_needs_healthy_links():
    m = LifecycleMachine()
    assert m.state == Lifecycle.STOPPED
    ok, msg = m.command("start", healthy(joint_state_age_s=None))
    assert not ok and "joint state" in msg
    assert m.state == Lifecycle.STOPPED
    ok, _ = m.command("start", healthy())
    assert ok and m.state == Lifecycle.READY


def test_teaching_only_while_enabling_is_held_and_servo_on():
    m = LifecycleMachine()
    m.command("start", healthy())
    assert (
        m.update(healthy(enabling=True, controller_state=ControllerState.BRAKED)) == Lifecycle.READY
    )
    assert m.update(healthy(enabling=True)) == Lifecycle.TEACHING
    assert m.update(healthy(enabling=False)) == Lifecycle.READY


def test_enabling_alone_never_starts_teaching_from_stopped():
    m = LifecycleMachine()
    assert m.update(healthy(enabling=True)) == Lifecycle.STOPPED


def test_lost_link_faults_and_reset_needs_cause_gone():
    m = LifecycleMachine()
    m.command("start", healthy())
    m.update(healthy(enabling=True))
    assert m.update(healthy(enabling=True, joint_state_age_s=0.5)) == Lifecycle.FAULT
    assert "joint state" in m.reason
    ok, _ = m.command("start", healthy())
    assert not ok and m.state == Lifecycle.FAULT
    ok, _ = m.command("reset", healthy(io_age_s=None))
    assert not ok and m.state == Lifecycle.FAULT
    ok, _ = m.command("reset", healthy())
    assert ok and m.state == Lifecycle.STOPPED


def test_estop_and_dead_process_fault_from_teaching():
    for obs in (healthy(estop_ok=False), healthy(dead_processes=("control",))):
        m = LifecycleMachine()
        m.command("start", healthy())
        m.update(healthy(enabling=True))
        assert m.update(obs) == Lifecycle.FAULT


def test_estop_while_stopped_is_a_fault():
    m = LifecycleMachine()
    assert m.update(healthy(estop_ok=False)) == Lifecycle.FAULT


def test_stop_from_anywhere_but_fault():
    m = LifecycleMachine()
    m.command("start", healthy())
    m.update(healthy(enabling=True))
    ok, _ = m.command("stop", healthy(enabling=True))
    assert ok and m.state == Lifecycle.STOPPED
    m.fault("test")
    ok, msg = m.command("stop", healthy())
    assert ok and m.state == Lifecycle.FAULT and "reset" in msg


def test_unknown_command_refused():
    ok, msg = LifecycleMachine().command("jump", healthy())
    assert not ok and "unknown" in msg


def test_seq_increments_on_every_change():
    m = LifecycleMachine()
    s0 = m.seq
    m.command("start", healthy())
    assert m.seq == s0 + 1
    m.update(healthy())
    assert m.seq == s0 + 1


def test_teaching_waits_for_standstill_after_servo_on():
    m = LifecycleMachine()
    m.command("start", healthy())
    assert m.update(healthy(enabling=True, still_for_s=0.0)) == Lifecycle.READY
    assert m.update(healthy(enabling=True, max_speed_rad_s=None)) == Lifecycle.READY
    assert (
        m.update(healthy(enabling=True, max_speed_rad_s=1e-4, still_for_s=0.1)) == Lifecycle.READY
    )
    assert m.update(healthy(enabling=True, max_speed_rad_s=1e-4)) == Lifecycle.TEACHING


def test_teaching_waits_until_the_servo_has_been_on_for_the_settle_time():
    """The drives' hold rings after servo-on; the law calibrates on the hold when it takes
    over, so teaching waits for ``servo_settle_s`` of servo on however still the arm is, and
    a servo-off restarts the wait."""
    m = LifecycleMachine(Limits(servo_settle_s=1.0))
    m.command("start", healthy())
    for on_s in (0.0, 0.4, 0.99):
        assert m.update(healthy(enabling=True, servo_on_for_s=on_s)) == Lifecycle.READY, on_s
    assert m.update(healthy(enabling=True, servo_on_for_s=1.0)) == Lifecycle.TEACHING


def test_teaching_is_blocked_while_the_model_lacks_the_arms_load_but_identify_is_not():
    m = LifecycleMachine()
    m.command("start", healthy())
    problem = "joint 3 holds 700.0 N·m at rest but the model expects 600.0 N·m"
    assert m.update(healthy(enabling=True, load_problem=problem)) == Lifecycle.READY
    assert m.reason == f"teaching blocked: {problem}"
    ok, _ = m.identify({"plan_id": "p"}, healthy(enabling=True, load_problem=problem))
    assert ok and m.state == Lifecycle.IDENTIFYING
    m.plan_finished("p", True, "done")
    assert m.update(healthy(enabling=True)) == Lifecycle.TEACHING


def test_identify_needs_enabling_and_ends_back_in_ready():
    m = LifecycleMachine()
    m.command("start", healthy())
    ok, msg = m.identify({"plan_id": "p"}, healthy())
    assert not ok and "enabling" in msg
    ok, _ = m.identify({"plan_id": "p"}, healthy(enabling=True))
    assert ok and m.state == Lifecycle.IDENTIFYING
    # the control process's progress reports reach the status; another plan's do not
    m.plan_progress("p", 0.25, "multisine/1")
    m.plan_progress("other", 0.9, "x")
    assert m.plan_result is not None
    assert (m.plan_result["progress"], m.plan_result["segment"]) == (0.25, "multisine/1")
    m.plan_finished("other", True, "")
    assert m.state == Lifecycle.IDENTIFYING
    m.plan_finished("p", True, "")
    assert m.state == Lifecycle.READY
    m.plan_progress("p", 0.5, "late")  # a report after the end changes nothing
    assert m.plan_result is not None and m.plan_result["state"] == "done"
    assert "progress" not in m.plan_result
    m.identify({"plan_id": "q"}, healthy(enabling=True))
    assert m.update(healthy(enabling=False)) == Lifecycle.READY


def test_play_problems_name_a_still_arm_on_its_brakes_until_servo_on():
    """The arm is still on its brakes before the controller reports servo-on: the status's
    play problems name the servo until then, and are empty exactly when identify starts."""
    m = LifecycleMachine()
    braked = healthy(enabling=True, controller_state=ControllerState.BRAKED, servo_on_for_s=0.0)
    assert m.play_problems(braked) == ["a plan needs state ready, not stopped"]
    m.command("start", healthy())
    assert m.play_problems(braked) == ["robot controller is not servo-on yet"]
    assert m.identify({"plan_id": "p"}, braked) == (False, "robot controller is not servo-on yet")
    assert m.play_problems(healthy(enabling=True)) == []
    assert m.identify({"plan_id": "p"}, healthy(enabling=True))[0]


def test_replay_needs_enabling_stops_on_release_and_ends_back_in_ready():
    m = LifecycleMachine()
    ok, msg = m.play(Lifecycle.REPLAYING, {"plan_id": "r"}, healthy(enabling=True))
    assert not ok and "replay needs state ready" in msg
    m.command("start", healthy())
    ok, msg = m.play(Lifecycle.REPLAYING, {"plan_id": "r"}, healthy())
    assert not ok and "enabling" in msg
    ok, msg = m.play(Lifecycle.REPLAYING, {"plan_id": "r"}, healthy(enabling=True))
    assert ok and m.state == Lifecycle.REPLAYING and "taught program r" in msg
    assert m.command("start", healthy(enabling=True)) == (True, "already replaying")
    assert m.update(healthy(enabling=False)) == Lifecycle.READY
    assert m.reason == "replaying aborted: enabling device released"
    assert m.plan_result == {"plan_id": "r", "state": "aborted", "reason": m.reason}
    m.play(Lifecycle.REPLAYING, {"plan_id": "s"}, healthy(enabling=True))
    m.plan_finished("s", True, "")
    assert (m.state, m.reason) == (Lifecycle.READY, "plan s done")
    assert m.plan_result is not None and m.plan_result["state"] == "done"
    m.play(Lifecycle.REPLAYING, {"plan_id": "t"}, healthy(enabling=True))
    assert m.plan_result is not None and m.plan_result["state"] == "running"
    assert m.update(healthy(enabling=True, estop_ok=False)) == Lifecycle.FAULT
    assert m.plan_result["state"] == "aborted" and "e-stop" in m.plan_result["reason"]


def test_a_controller_fault_while_stopped_is_a_fault_that_reset_clears():
    m = LifecycleMachine()
    faulted = healthy(controller_state=ControllerState.FAULT)
    assert m.update(faulted) == Lifecycle.FAULT  # e.g. its host heartbeat lost in a crash
    assert "reset to clear it" in m.reason
    ok, msg = m.command("reset", replace(faulted, estop_ok=False))
    assert not ok and "e-stop" in msg and "controller" not in msg
    ok, _ = m.command("reset", faulted)  # the CAN driver forwards it as RESET_FAULT
    assert ok and m.state == Lifecycle.STOPPED
    for _ in range(CONTROLLER_RESET_UPDATES - 1):
        assert m.update(faulted) == Lifecycle.STOPPED  # the controller's reset on its way
    assert m.update(healthy(controller_state=ControllerState.BRAKED)) == Lifecycle.STOPPED
    assert m.command("start", healthy())[0]


def test_a_controller_that_stays_in_fault_after_reset_faults_again():
    m = LifecycleMachine()
    faulted = healthy(controller_state=ControllerState.FAULT)
    m.update(faulted)
    m.command("reset", faulted)
    states = {m.update(faulted) for _ in range(CONTROLLER_RESET_UPDATES + 1)}
    assert states == {Lifecycle.STOPPED, Lifecycle.FAULT} and m.state == Lifecycle.FAULT


def test_a_controller_fault_is_named_with_its_cause_once_the_can_driver_tells_it():
    """The FAULT comes with the joint state, its cause with the CAN driver's health up to a
    health period later: the reason names the cause once it is known, and only once."""
    m = LifecycleMachine()
    assert m.command("start", healthy())[0]
    faulted = healthy(controller_state=ControllerState.FAULT)
    assert m.update(faulted) == Lifecycle.FAULT
    assert m.reason == "robot controller reports FAULT"
    seq = m.seq
    cause = "J2 left operation enabled on its own (switched on)"
    told = replace(faulted, controller_fault_text=cause)
    assert m.update(told) == Lifecycle.FAULT
    assert m.reason == f"robot controller reports FAULT ({cause})" and m.seq == seq + 1
    m.update(replace(faulted, controller_fault_text="J2 heartbeat lost (0.16 s)"))
    assert m.reason == f"robot controller reports FAULT ({cause})", "the first cause stays"
    assert m.link_problems(told) == [f"robot controller reports FAULT ({cause})"]
    stopped = LifecycleMachine()  # faulted while stopped: the cause and the way out
    stopped.update(told)
    assert stopped.reason == f"robot controller reports FAULT ({cause}); reset to clear it"


@pytest.mark.parametrize(
    ("field", "trip", "named"),
    [
        ("speed_trip", "the tool moved at 262 mm/s", "speed monitor"),
        ("standstill_trip", "joint 2 left its hold by 25.0 mrad", "standstill monitor"),
        ("bus_fault", "the CAN interface went bus-off", "CAN bus"),
    ],
)
def test_the_gateway_faults_on_the_trip_and_resets_once_it_is_cleared(field, trip, named):
    """The CAN driver's latched trips (speed and standstill monitors, bus fault): each faults
    the cell with what it measured, and a reset is refused while it stands."""
    machine = LifecycleMachine()
    ok = Observations(0.01, 0.01, ControllerState.EXTERNAL, True, True, max_speed_rad_s=0.0,
                      still_for_s=5.0, servo_on_for_s=5.0)  # fmt: skip
    machine.command("start", ok)
    machine.update(ok)
    assert machine.state == Lifecycle.TEACHING
    tripped = Observations(0.01, 0.01, ControllerState.EXTERNAL, True, True,
                           driver_trips={field: trip})  # fmt: skip
    machine.update(tripped)
    assert machine.state == Lifecycle.FAULT and trip in machine.reason
    assert named in machine.reason
    accepted, message = machine.command("reset", tripped)
    assert not accepted and named in message
    assert machine.command("reset", ok)[0] and machine.state == Lifecycle.STOPPED
