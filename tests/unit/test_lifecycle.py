from gateway.lifecycle import LifecycleMachine, Observations
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
    assert m.update(healthy(enabling=True, max_speed_rad_s=0.01)) == Lifecycle.READY
    assert m.update(healthy(enabling=True, max_speed_rad_s=None)) == Lifecycle.READY
    assert (
        m.update(healthy(enabling=True, max_speed_rad_s=1e-4, still_for_s=0.1)) == Lifecycle.READY
    )
    assert m.update(healthy(enabling=True, max_speed_rad_s=1e-4)) == Lifecycle.TEACHING


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
    m.plan_finished("other", True, "")
    assert m.state == Lifecycle.IDENTIFYING
    m.plan_finished("p", True, "")
    assert m.state == Lifecycle.READY
    m.identify({"plan_id": "q"}, healthy(enabling=True))
    assert m.update(healthy(enabling=False)) == Lifecycle.READY
