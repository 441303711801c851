"""The per-cycle form of the control law computes the physics its reference form states.

Each controller cycle runs the compiled cycle (control/rt/src/law/zero_moment.rs, through
:meth:`ZeroMomentController.answer`); :meth:`ZeroMomentController.desired_torque` and
:meth:`OuterLoop.step` state the same physics on arrays (the model's array methods, on
pinocchio). These tests pin one to the other on random states, piece by piece and for whole
runs, so a later optimisation cannot change what the loop computes without failing here.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest
from example_cell import EXAMPLE_MODEL, example_cell

from control.cell_config import load_control_config
from control.declared_model import DeclaredModel
from control.model.cylinders import cylinder_torque_nm
from control.zero_moment_law import ZeroMomentController
from gateway.errors import ConfigError, MessageError
from gateway.message_factories import make_joint_state
from gateway.messages import ControllerState, JointCommand

#: the stiction dither's fade in and out [s] (control/rt/src/law/zero_moment.rs STICTION_FADE_S)
FADE_S = 0.25
#: equal to rounding: a few ulps of torques up to ~1e4 N·m, commands of ~1 rad
RTOL, ATOL = 1e-12, 1e-9


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    return load_control_config(example_cell(tmp_path_factory.mktemp("cell")))[0]


@pytest.fixture(scope="module")
def at_once(cfg):
    """``cfg`` engaging on the first state (these tests are about the cycle's physics)."""
    return dataclasses.replace(cfg, engage_rest_states=0)


@pytest.fixture(scope="module")
def model(cfg) -> DeclaredModel:
    return DeclaredModel.load(cfg.model)


def random_states(model: DeclaredModel, rng: np.random.Generator, count: int):
    """(q, dq, p) of ``count`` samples: q across the whole range and a little beyond (the soft
    limits' walls), dq from rest through the friction deadband to fast, pressures 0–10 bar."""
    lower, upper = model.desc.lower_rad, model.desc.upper_rad
    for k in range(count):
        q = rng.uniform(lower - 0.05, upper + 0.05)
        scale = (1e-4, 1e-3, 0.05, 1.0)[k % 4]
        dq = rng.normal(0.0, scale, model.n)
        if k % 7 == 0:
            dq[rng.integers(model.n)] = 0.0
        yield q, dq, rng.uniform(0.0, 10.0, 2)


def test_cylinders_per_cycle_equal_eqs_10_and_12_on_arrays(model):
    rng = np.random.default_rng(2)
    for q, _, p in random_states(model, rng, 500):
        got = model.point.cylinder_torques_nm(q.tolist(), p.tolist())
        want = cylinder_torque_nm(q, p, model.desc)
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=ATOL)
        assert [j for j, t in enumerate(got) if t != 0.0] == [1, 2]  # J2 and J3 only


def test_model_cycle_torques_equal_the_array_methods(model):
    """The compiled model (control/rt/src/point_model.rs): the static part is gravity less
    the cylinders, the moving part eq. (15) alone."""
    rng = np.random.default_rng(3)
    for q, dq, p in random_states(model, rng, 300):
        static, friction = model.cycle_torques_nm(q, dq.tolist(), p.tolist())
        want = model.gravity_nm(q) - model.cylinder_nm(q, p)
        np.testing.assert_allclose(static, want, rtol=RTOL, atol=ATOL)
        np.testing.assert_allclose(friction, model.friction_nm(q, dq), rtol=RTOL, atol=ATOL)


def test_outer_loop_per_cycle_equals_eq21_step(cfg, model):
    ctl = ZeroMomentController(cfg, model)
    ref = copy.deepcopy(ctl.loop)
    rng = np.random.default_rng(4)
    for k, (q, dq, _) in enumerate(random_states(model, rng, 500)):
        tau = rng.normal(0.0, (50.0, 300.0, 3000.0)[k % 3], model.n)  # to beyond the limits
        dt = (0.002, 0.004, 0.008, 0.2)[k % 4]
        q_cmd, dq_cmd = ctl.loop.step_floats(q.tolist(), dq.tolist(), tau.tolist(), dt)
        want = ref.step(q, dq, tau, dt)
        np.testing.assert_allclose(q_cmd, want.q_cmd_rad, rtol=RTOL, atol=ATOL)
        np.testing.assert_allclose(dq_cmd, want.dq_cmd_rad_s, rtol=RTOL, atol=ATOL)
        np.testing.assert_allclose(ctl.loop.offset_rad, ref.offset_rad, rtol=RTOL, atol=ATOL)
    assert np.any(np.abs(ref.offset_rad) == ref.max_offset_rad), "limits never reached"


def _law_alone(at_once):
    """``at_once`` with the law alone: no tool speed limit (it scales a fast command), no eq.
    (28), no inertia compensation and no stiction dither (their own tests)."""
    return dataclasses.replace(
        at_once, max_tool_speed_m_s=0.0, omega_adaptation_per_s=0.0, inertia_compensation=0.0,
        stiction_dither=0.0,
    )  # fmt: skip


def _state(cycle, q, dq, q_cmd=None, period=0.004, flags=2, current=None):
    return make_joint_state(cycle, 1.0, ControllerState.EXTERNAL, flags, q, dq,
                            np.zeros(len(q)) if current is None else current,
                            q if q_cmd is None else q_cmd, dq, period)  # fmt: skip


def test_cycle_equals_desired_torque_then_eq21_over_a_run(at_once, model):
    """Whole cycles, the outer loop's state carried along: the compiled cycle and the
    reference (desired_torque with the cycle's friction ramps, then OuterLoop.step) give the
    same torque and commands."""
    ctl = ZeroMomentController(_law_alone(at_once), model)
    ref = copy.deepcopy(ctl.loop)
    rng = np.random.default_rng(5)
    walls = 0
    for cycle, (q, dq, p) in enumerate(random_states(model, rng, 2000), start=1):
        st = _state(cycle, q, dq, q_cmd=q + 0.001)
        q_cmd, dq_cmd = ctl.answer(st, tuple(p))
        if cycle == 1:
            ref.reset(st.q_cmd_rad - st.q_rad)
        tau = ctl.desired_torque(q, dq, p)
        want = ref.step(q, dq, tau, 0.004)
        np.testing.assert_allclose(ctl.tau_d_nm, tau, rtol=RTOL, atol=ATOL)
        np.testing.assert_allclose(q_cmd, want.q_cmd_rad, rtol=RTOL, atol=ATOL)
        np.testing.assert_allclose(dq_cmd, want.dq_cmd_rad_s, rtol=RTOL, atol=ATOL)
        walls += bool(np.any((q > ctl.upper) | (q < ctl.lower)))
    assert walls > 100, "the soft limits were hardly exercised"


def test_update_answers_with_the_reference_command(at_once, model):
    """The law itself: the tool speed limit (which scales a fast command), eq. (28) and the
    inertia compensation (their own tests) are off here."""
    at_once = _law_alone(at_once)
    ctl = ZeroMomentController(at_once, model)
    ref = ZeroMomentController(at_once, model)
    rng = np.random.default_rng(6)
    for cycle, (q, dq, p) in enumerate(random_states(model, rng, 200), start=100):
        st = make_joint_state(cycle, 1.0, ControllerState.EXTERNAL, 2, q, dq, np.zeros(6),
                              q + 0.001, dq, 0.004)  # fmt: skip
        cmd = ctl.update(st, tuple(p), 2.0)
        if not ref.engaged:
            ref.loop.reset(st.q_cmd_rad - st.q_rad)
            ref.engaged = True
        ref._cycle.ramps = ctl._cycle.ramps  # the friction ramps of this cycle's pose
        want = ref.loop.step(q, dq, ref.desired_torque(q, dq, p), 0.004)
        assert (cmd.cycle, cmd.state_stamp_s, cmd.sent_stamp_s) == (cycle, 1.0, 2.0)
        np.testing.assert_allclose(cmd.q_cmd_rad, want.q_cmd_rad, rtol=RTOL, atol=ATOL)
        np.testing.assert_allclose(cmd.dq_cmd_rad_s, want.dq_cmd_rad_s, rtol=RTOL, atol=ATOL)


def test_identified_model_cycle_torques_equal_its_array_methods(tmp_path):
    from control.identification.model import IdentifiedModel
    from control.identification.rigid import RobotRegressor
    from control.identification.terms import FrictionTerm
    from gateway.robot.description import load_description
    from gateway.robot.urdf import to_urdf

    declared = DeclaredModel.load(EXAMPLE_MODEL)
    desc = load_description()
    xml = to_urdf(desc)
    reg = RobotRegressor(xml, tuple(desc.gravity_m_s2))
    terms = [FrictionTerm(j, "eq15", 0.01, desc.gear_ratios[j]) for j in range(6)]
    coefs = [np.array([20.0, 30.0, 1.0, 0.5, 0.2, 0.1, 1.0, 0.5, 60.0, 2.0])] * 6
    meta = {"urdf_xml": xml, "cylinders_removed": True}
    IdentifiedModel(reg, reg.base.base_values(reg.parameters()), "eq15", terms, coefs,
                    metadata=meta).save(tmp_path / "model.json")  # fmt: skip
    model = DeclaredModel.load(tmp_path / "model.json")
    rng = np.random.default_rng(7)
    for q, dq, p in random_states(declared, rng, 50):
        static, friction = model.cycle_torques_nm(q, dq.tolist(), p.tolist())
        want = model.gravity_nm(q) - model.cylinder_nm(q, p)
        np.testing.assert_allclose(static, want, rtol=RTOL, atol=ATOL)
        np.testing.assert_allclose(friction, model.friction_nm(q, dq), rtol=RTOL, atol=ATOL)


def test_non_finite_torque_is_refused_not_sent(at_once, model):
    """A state the model cannot evaluate raises MessageError (the process then sends nothing
    and disengages), whether the float path produces NaN or math refuses the input."""
    cfg = at_once
    ctl = ZeroMomentController(cfg, model)
    q = np.array([1e308, 0.1, 0.2, 0.0, 0.0, 0.0])  # finite, but the wall spring overflows
    states = [make_joint_state(cycle, 0.0, ControllerState.EXTERNAL, 2, q, np.zeros(6),
                               np.zeros(6), q, np.zeros(6), 0.004) for cycle in (1, 2)]  # fmt: skip
    ctl.update(states[0], (6.0, 4.0), 0.0)  # -inf torque: velocity clipped, offset now NaN
    with pytest.raises(MessageError, match="q_cmd_rad"):
        ctl.update(states[1], (6.0, 4.0), 0.0)

    # a pressure the model cannot take (NaN: the cylinder's torque is not finite)
    fresh = ZeroMomentController(cfg, model)
    st = make_joint_state(1, 0.0, ControllerState.EXTERNAL, 2, np.zeros(6), np.zeros(6),
                          np.zeros(6), np.zeros(6), np.zeros(6), 0.004)  # fmt: skip
    with pytest.raises(MessageError, match=r"model torque undefined.*joint 2 is not finite"):
        fresh.update(st, (math.nan, 4.0), 0.0)


def test_process_answers_each_state_stamped_at_receipt_and_at_sending(tmp_path):
    """The control process's callback, as the benchmark drives it (no bus): one command per
    state, carrying when the state arrived and, later, when the command was sent."""
    from control import bench_loop

    ticks = iter(range(1_000_000, 2_000_000))
    proc, pub = bench_loop.make_process(example_cell(tmp_path))
    proc.clock = lambda: next(ticks) * 1e-3  # 1 ms per reading
    sent = []
    pub.put = sent.append
    for payload in bench_loop.joint_states(proc, 5):
        bench_loop._refresh(proc)
        proc._on_state(bench_loop._Sample(bench_loop._Payload(payload)))
    cmds = [JointCommand.from_bytes(b) for b in sent]
    assert [c.cycle for c in cmds] == [0, 1, 2, 3, 4]
    assert all(0 < c.state_rx_stamp_s < c.sent_stamp_s for c in cmds)


def test_benchmark_runs_and_every_call_commands(tmp_path):
    from control import bench_loop

    result = bench_loop.run(example_cell(tmp_path), calls=300, warmup=30)
    assert result["calls"] == 300 and result["on_state"]["median_us"] > 0


def test_the_drive_holding_the_arm_calibrates_omega_before_teaching(cfg, model):
    """At rest the driver's hold gives ``K i = K K_I (q_c - q)`` (eq. 19): over the hold's
    states the control process learns K K_I and starts teaching with the ω̂ whose static gain
    K K_I ω̂ / Υ̂_I is 1, even though the commissioned ω is 10 % off and the current noisy."""
    from gateway.messages import FLAG_PREV_HOLD

    ctl = ZeroMomentController(cfg, model)
    k = np.array([j.drive_gain_nm_per_a for j in model.desc.joints])
    upsilon = np.array(cfg.upsilon_i_per_s)
    kki = 1.1 * upsilon / np.array(cfg.omega_rad_s_per_nm)  # the drive's true K K_I
    q = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
    load = np.array([50.0, 2000.0, 800.0, 12.0, 9.0, 3.0])  # held static torque [N·m]
    offset = load / kki
    rng = np.random.default_rng(3)
    hold = ControllerState.HOLD
    for c in range(64):
        current = (load + rng.normal(0.0, [0.9, 1.3, 0.8, 0.2, 0.2, 0.1])) / k
        st = make_joint_state(c, 0.0, hold, FLAG_PREV_HOLD | 2, q, np.zeros(6), current,
                              q + offset, np.zeros(6), 0.008)  # fmt: skip
        ctl.observe_hold(st)
    assert len(ctl.hold) == 64
    ctl.answer(st, (6.0, 4.0))  # teaching starts from that hold
    np.testing.assert_allclose(ctl.loop.omega * kki / upsilon, 1.0, rtol=0.01)
    # a moving arm is no hold: the average starts again
    moving = make_joint_state(99, 0.0, hold, FLAG_PREV_HOLD | 2, q, np.full(6, 0.1),
                              np.zeros(6), q, np.zeros(6), 0.008)  # fmt: skip
    ctl.observe_hold(moving)
    assert len(ctl.hold) == 0


def test_teaching_engages_once_the_arm_rests_in_the_hold_or_after_the_longest_wait(cfg, model):
    """An arm still settling in the driver's hold gives no calibration of ω̂: the controller
    holds on where the driver holds (position echoed, zero velocity) until the arm has rested
    ``engage_rest_states`` states, calibrating from those, or ``engage_max_wait_states`` passed."""
    from gateway.messages import FLAG_PREV_HOLD

    cfg = dataclasses.replace(cfg, engage_rest_states=4, engage_max_wait_states=10)
    ctl = ZeroMomentController(cfg, model)
    q = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
    held = q + 0.001

    def state(c, dq, flags=2):
        return make_joint_state(c, 0.0, ControllerState.EXTERNAL, flags, q, np.full(6, dq),
                                np.ones(6), held, np.zeros(6), 0.008)  # fmt: skip

    q_cmd, dq_cmd = ctl.answer(state(1, 0.01, FLAG_PREV_HOLD | 2), (6.0, 4.0))  # settling
    np.testing.assert_array_equal(q_cmd, held)
    assert dq_cmd == [0.0] * 6 and not ctl.engaged
    for c in range(2, 5):  # three states at rest under our own hold: one short
        ctl.answer(state(c, 0.0), (6.0, 4.0))
    assert not ctl.engaged and len(ctl.hold) == 3
    ctl.answer(state(5, 0.0), (6.0, 4.0))
    assert ctl.engaged  # the fourth resting state: calibrated and teaching

    ctl.disengage()
    ctl.hold.clear()
    for c in range(10, 20):  # never at rest: hold on for at most 10 states
        ctl.answer(state(c, 0.01), (6.0, 4.0))
        assert not ctl.engaged
    ctl.answer(state(20, 0.01), (6.0, 4.0))
    assert ctl.engaged


def test_the_predictors_inverse_inertia_is_recomputed_only_after_the_arm_moved(cfg, model):
    from control.model.dynamics import RigidBodyModel
    from control.zero_moment_law import INERTIA_STEP_RAD

    ctl = ZeroMomentController(dataclasses.replace(cfg, command_delay_cycles=1), model)
    rigid = RigidBodyModel.from_description(model.desc)
    q = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
    first = ctl.inverse_inertia(q)
    want = np.linalg.inv(rigid.mass_matrix(q, include_armature=True))
    np.testing.assert_allclose(first, want, rtol=1e-12)
    # within the step: the cached one, to the bit (M⁻¹ there differs by ~1e-3)
    np.testing.assert_array_equal(ctl.inverse_inertia(q + 0.5 * INERTIA_STEP_RAD), first)
    moved = q + np.array([0.0, 2.0 * INERTIA_STEP_RAD, 0.0, 0.0, 0.0, 0.0])
    again = ctl.inverse_inertia(moved)
    assert not np.allclose(again, first, rtol=1e-6)
    np.testing.assert_allclose(
        again, np.linalg.inv(rigid.mass_matrix(moved, include_armature=True)), rtol=1e-12
    )


class _NegatedFriction:
    """``model`` whose friction pushes along the motion (an identification's artefact, as a
    negative static friction fitted on a wrist from one slow run): never compensated. Its
    compiled form has eq. (15)'s coefficients negated (control/rt/src/friction.rs: the first
    ten of a row scale the torque; the last three are its speeds and gear ratio)."""

    def __init__(self, model: DeclaredModel) -> None:
        from control import _rt
        from control.rt_tables import point_model_table, to_json

        self._m = model
        table = point_model_table(model.desc, rigid=model.rigid, friction_rows=model.friction.rows)
        for entry in table["friction"]:
            entry["row"][:10] = [-v for v in entry["row"][:10]]
        self.point = _rt.PointModel(to_json(table))

    def __getattr__(self, name):
        return getattr(self._m, name)

    def friction_nm(self, q, dq):
        return -self._m.friction_nm(q, dq)


def test_friction_that_does_not_oppose_motion_is_not_compensated(at_once, model):
    bad = _NegatedFriction(model)
    ctl = ZeroMomentController(_law_alone(at_once), bad)
    rng = np.random.default_rng(8)
    for cycle, (q, dq, p) in enumerate(random_states(model, rng, 200), start=1):
        q = np.clip(q, ctl.lower, ctl.upper)  # away from the walls: the load and damping only
        want = model.gravity_nm(q) - model.cylinder_nm(q, p) - ctl.damping * dq
        np.testing.assert_allclose(ctl.desired_torque(q, dq, p), want, rtol=RTOL, atol=ATOL)
        ctl.answer(_state(cycle, q, dq), tuple(p))
        np.testing.assert_allclose(ctl.tau_d_nm, want, rtol=RTOL, atol=ATOL)


def test_the_inner_loop_dither_adds_its_sinusoid_to_the_desired_torque(cfg, model):
    """[control].inner_loop_dither_a: K times that current, at 4.0 + 0.4 j Hz per joint, is
    added to the desired torque (control/rt/src/law/inner_estimate.rs); its length is checked."""
    amp = (0.03, 0.02, 0.03, 0.01, 0.01, 0.05)
    cfg = dataclasses.replace(_law_alone(cfg), engage_rest_states=0)
    plain = ZeroMomentController(dataclasses.replace(cfg, inner_loop_dither_a=()), model)
    dithered = ZeroMomentController(dataclasses.replace(cfg, inner_loop_dither_a=amp), model)
    k = np.array([j.drive_gain_nm_per_a for j in model.desc.joints])
    q, dq, p, dt = model.desc.lower_rad * 0.0 + 0.1, np.zeros(model.n), [5.0, 3.0], 0.008
    diffs = []
    for cycle in range(1, 251):  # 2 s
        plain.answer(_state(cycle, q, dq, period=dt), p)
        dithered.answer(_state(cycle, q, dq, period=dt), p)
        diffs.append(np.array(dithered.tau_d_nm) - np.array(plain.tau_d_nm))
    diffs = np.array(diffs)
    np.testing.assert_allclose(np.abs(diffs).max(axis=0), k * np.array(amp), rtol=0.02)
    np.testing.assert_allclose(diffs.mean(axis=0), 0.0, atol=0.05 * k.max() * max(amp))
    for j in range(model.n):  # the frequency of joint j + 1: zero crossings over 2 s
        crossings = np.sum(np.diff(np.sign(diffs[:, j])) != 0)
        assert abs(crossings / 2 / 2.0 - (4.0 + 0.4 * j)) < 0.3
    with pytest.raises(ConfigError, match="inner_loop_dither_a has 2 values"):
        ZeroMomentController(dataclasses.replace(cfg, inner_loop_dither_a=(0.1, 0.1)), model)


def test_the_online_inner_loop_estimate_runs_only_when_asked_for(cfg, model):
    assert ZeroMomentController(cfg, model).inner_estimate is None
    on = ZeroMomentController(dataclasses.replace(cfg, inner_loop_estimate=True), model)
    assert on.inner_estimate is not None
    np.testing.assert_allclose(on.inner_estimate.omega_rad_s_per_nm, cfg.omega_rad_s_per_nm)


def test_a_velocity_command_past_the_tool_speed_limit_is_scaled_down_to_it(at_once, model):
    """Hand guiding's limit in the command path: whatever the law asks, the velocity command
    sent never moves the tool point or the flange faster than the cycle's target (the limit,
    less SPEED_FEEDBACK_GAIN × what the predicted speed exceeds it by), and a slow one passes
    unchanged."""
    from control.model.dynamics import RigidBodyModel

    kin = RigidBodyModel.from_description(model.desc)
    free = dataclasses.replace(at_once, max_tool_speed_m_s=0.0)
    rng = np.random.default_rng(8)
    limited = 0
    for cycle, (q, dq, p) in enumerate(random_states(model, rng, 200), start=100):
        ctl, ref = ZeroMomentController(at_once, model), ZeroMomentController(free, model)
        st = make_joint_state(cycle, 1.0, ControllerState.EXTERNAL, 2, q, dq, np.zeros(6),
                              q + 0.001, dq, 0.004)  # fmt: skip
        got = np.array(ctl.update(st, tuple(p), 2.0).dq_cmd_rad_s)
        want = np.array(ref.update(st, tuple(p), 2.0).dq_cmd_rad_s)
        twist = kin.tool_jacobian_world(q) @ got
        rot = kin.world_T_tool(q)[:3, :3]
        tool = np.array(model.desc.tool.position_in_link6_m)
        flange = twist[:3] - np.cross(twist[3:], rot @ tool)
        fastest = max(np.linalg.norm(twist[:3]), np.linalg.norm(flange))
        target = ctl.speed_target_m_s
        assert 0.0 <= target <= at_once.max_tool_speed_m_s
        assert fastest <= target * (1 + 1e-9) + 1e-12
        if np.allclose(got, want, rtol=RTOL, atol=ATOL):
            continue
        limited += 1
        assert fastest == pytest.approx(target, rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(got, want * (got @ want) / (want @ want), rtol=1e-9)
    assert 20 < limited < 200, limited


def test_the_speed_target_falls_by_three_times_the_excess_of_the_arms_speed(at_once, model):
    """SPEED_FEEDBACK_GAIN: under the limit the target is the limit; over it by e, the limit
    less 3 e, never below zero; a NaN speed leaves the limit as it is."""
    from control.zero_moment_law import SPEED_FEEDBACK_GAIN

    ctl = ZeroMomentController(at_once, model)
    limit = at_once.max_tool_speed_m_s
    q = np.array(model.desc.lower_rad) * 0.0 + 0.3
    direction = np.array([1.0, 0.5, -0.3, 0.2, 0.1, 0.1])
    unit = direction / ctl.point_speed(q, direction)  # moves the fastest point at 1 m/s
    assert ctl.speed_target(q, 0.5 * limit * unit) == limit
    assert ctl.speed_target(q, (limit + 0.02) * unit) == pytest.approx(
        limit - SPEED_FEEDBACK_GAIN * 0.02
    )
    assert ctl.speed_target(q, 10.0 * unit) == 0.0
    assert ctl.speed_target(q, np.full(6, np.nan)) == limit


def test_friction_compensation_ramps_in_over_the_speed_the_loop_delay_allows(at_once, model):
    """friction_ramps: per joint, factor × (delay + 1) cycles × the model's friction level ×
    (M⁻¹)ⱼⱼ; a joint at half its ramp above the deadband gets half the model's friction,
    one past it all of it, and a factor of 0 compensates in full at once."""
    cfg = dataclasses.replace(at_once, max_tool_speed_m_s=0.0, friction_ramp_factor=2.0)
    ctl = ZeroMomentController(cfg, model)
    q = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
    st = make_joint_state(1, 1.0, ControllerState.EXTERNAL, 2, q, np.zeros(6), np.zeros(6),
                          q + 0.001, np.zeros(6), 0.004)  # fmt: skip
    ctl.update(st, (6.0, 4.0), 2.0)
    level = ctl.friction_level_nm(q)
    assert np.all(level > 0.0)
    m_inv = ctl.inverse_inertia(q)
    lag = (cfg.command_delay_cycles + 1) * 0.004
    ramps = np.array(ctl._cycle.ramps)  # the ramps of the cycle at rest at q
    np.testing.assert_allclose(ramps, 2.0 * lag * level * np.diag(m_inv))
    assert np.all(ramps > 0.0)
    dead = cfg.friction_deadband_rad_s
    p = np.array([6.0, 4.0])
    ctl.damping[:] = 0.0
    off = dataclasses.replace(cfg, friction_ramp_factor=0.0)
    full = ZeroMomentController(off, model)
    full.damping[:] = 0.0
    for j in range(6):
        for fraction, share in ((0.5, 0.5), (1.5, 1.0)):
            dq = np.zeros(6)
            dq[j] = dead + fraction * ramps[j]
            got = ctl.desired_torque(q, dq, p) - ctl.desired_torque(q, np.zeros(6), p)
            want = full.desired_torque(q, dq, p) - full.desired_torque(q, np.zeros(6), p)
            assert got[j] == pytest.approx(share * want[j], rel=1e-9, abs=1e-12)
    full.update(st, (6.0, 4.0), 2.0)
    assert full._cycle.ramps == [0.0] * 6


def test_a_negative_friction_ramp_factor_is_refused(tmp_path):
    cell = example_cell(tmp_path, friction_ramp_factor=-1.0)
    with pytest.raises(ConfigError, match="friction_ramp_factor"):
        load_control_config(cell)


def test_friction_is_compensated_in_full_while_a_positioning_joint_slides_past_its_ramp():
    """GuidedFriction: the wrists' motion alone is no guiding (a chatter of theirs must not
    switch the ramp off); J2 past its ramp is, until J1-J3 have been slow for hold_s."""
    from control._rt import GuidedFriction

    g = GuidedFriction(0.3)
    ramps = [0.01, 0.01, 0.01, 0.1, 0.1, 0.1]
    wrists = np.array([0.0, 0.0, 0.0, 0.5, 0.5, 0.5])
    assert not any(g.update(wrists, ramps, 0.004) for _ in range(100))
    j2 = np.array([0.0, 0.02, 0.0, 0.0, 0.0, 0.0])
    assert g.update(j2, ramps, 0.004)
    slow = np.array([0.005, 0.005, 0.005, 0.0, 0.0, 0.0])
    held = [g.update(slow, ramps, 0.004) for _ in range(100)]
    assert all(held[:74]) and not any(held[75:])
    assert not GuidedFriction(0.0).update(j2, ramps, 0.004)


def test_inertia_compensation_gives_its_share_of_m_qdd(at_once, model):
    """``inertia_compensation``: a steady acceleration of the measured velocity earns the
    configured share of M(q) q̈ once its low-pass has settled; a gap starts it again from zero,
    and with the share at 0 nothing is added."""
    share = dataclasses.replace(
        at_once, inertia_compensation=0.4, inertia_compensation_hz=10.0, max_tool_speed_m_s=0.0
    )
    ctl = ZeroMomentController(share, model)
    q = np.array([0.2, -0.3, 0.4, 0.1, -0.2, 0.3])
    accel = np.array([0.5, -0.3, 0.8, 1.0, -1.0, 2.0])
    period = 0.004
    for k in range(200):  # 0.8 s: 50 time constants of the 10 Hz low-pass
        ctl.answer(_state(100 + k, q, accel * k * period), (6.0, 4.0))
    want = 0.4 * ctl.inertia(q) @ accel
    np.testing.assert_allclose(ctl._cycle.tau_inertia_nm, want, rtol=1e-6)
    assert np.all(np.abs(want) > 0.01)
    # a gap: the acceleration over it is not known, so nothing is compensated at first
    ctl.answer(_state(100 + 500, q, accel * 500 * period), (6.0, 4.0))
    np.testing.assert_array_equal(ctl._cycle.tau_inertia_nm, 0.0)
    # and the cycle's command carries it: same state, with and without the share
    plain = ZeroMomentController(
        dataclasses.replace(at_once, max_tool_speed_m_s=0.0, inertia_compensation=0.0), model
    )
    comp = ZeroMomentController(
        dataclasses.replace(share, max_tool_speed_m_s=0.0, inertia_compensation=0.9), model
    )
    for c in range(3):
        dq = accel * c * period
        st = make_joint_state(100 + c, 1.0, ControllerState.EXTERNAL, 2, q, dq, np.zeros(6),
                              q, dq, period)  # fmt: skip
        plain.update(st, (6.0, 4.0), 2.0)
        comp.update(st, (6.0, 4.0), 2.0)
    assert np.all(np.sign(comp.tau_d_nm - plain.tau_d_nm) == np.sign(comp._cycle.tau_inertia_nm))
    assert np.any(np.abs(comp.tau_d_nm - plain.tau_d_nm) > 0.01)


def test_the_stiction_dither_swings_a_joint_at_rest_while_the_arm_is_guided(at_once, model):
    """[control].stiction_dither: while the arm is guided (a positioning joint slides) and
    stiction_dither_hold_s after, a joint at rest gets a sine of that share of the model's
    friction level at stiction_dither_hz, added to the desired torque; none on the sliding
    joint, none on an arm nobody guides, none with the share at 0; the settings are checked."""
    cfg = dataclasses.replace(at_once, max_tool_speed_m_s=0.0, stiction_dither_hold_s=1.0)
    plain = ZeroMomentController(dataclasses.replace(cfg, stiction_dither=0.0), model)
    dithered = ZeroMomentController(
        dataclasses.replace(cfg, stiction_dither=0.5, stiction_dither_hz=4.0), model
    )
    q, p, dt = np.array([0.0, 0.2, 0.3, 0.0, -0.3, 0.0]), (6.0, 4.0), 0.008
    rest, slide = np.zeros(model.n), np.zeros(model.n)
    slide[0] = 0.05  # J1 slides (beyond its friction ramp: the arm is guided); the others rest
    # 1 s untouched, 2 s guided, then 2 s at rest again: (dq, seconds)
    script = [(rest, 1.0), (slide, 2.0), (rest, 2.0)]
    torque, diffs, t, cycle = [], [], [], 0
    for dq, seconds in script:
        for _ in range(round(seconds / dt)):
            cycle += 1
            plain.answer(_state(cycle, q, dq, period=dt), p)
            dithered.answer(_state(cycle, q, dq, period=dt), p)
            torque.append(dithered._cycle.stiction_torque_nm)
            diffs.append(np.array(dithered.tau_d_nm) - np.array(plain.tau_d_nm))
            t.append(cycle * dt)
    torque, diffs, t = np.array(torque), np.array(diffs), np.array(t)
    level = np.array(dithered._cycle.friction_level)
    assert np.all(level[1:] > 0)
    np.testing.assert_array_equal(torque[t <= 1.0], 0.0)  # nobody guides the arm
    guided = (t > 1.0 + FADE_S) & (t <= 3.0)
    np.testing.assert_array_equal(torque[guided, 0], 0.0)  # the sliding joint
    swing = np.abs(torque[guided, 1:]).max(axis=0)
    np.testing.assert_allclose(swing, 0.5 * level[1:], rtol=0.02)
    np.testing.assert_allclose(torque[guided].mean(axis=0), 0.0, atol=0.03 * level.max())
    for j in range(1, model.n):  # 4 Hz: zero crossings
        crossings = np.sum(np.diff(np.sign(torque[guided, j])) != 0)
        assert abs(crossings / 2 / (guided.sum() * dt) - 4.0) < 0.3
    # held on for stiction_dither_hold_s after the guiding (the guided switch's own hold
    # first), then faded out
    assert np.abs(torque[(t > 3.3) & (t <= 4.0)]).max() > 0.3 * level[1:].min()
    np.testing.assert_array_equal(torque[t > 3.0 + 0.3 + 1.0 + FADE_S + dt], 0.0)
    # it reaches the command through the desired torque (the outer loop's step, eq. 21)
    np.testing.assert_allclose(diffs, torque, atol=1e-9)
    for bad in ({"stiction_dither": 1.0}, {"stiction_dither": -0.1},
                {"stiction_dither_hz": 0.0}, {"stiction_dither": float("nan")},
                {"stiction_dither_hold_s": -1.0}):  # fmt: skip
        with pytest.raises(ConfigError, match="stiction_dither"):
            dataclasses.replace(cfg, **bad)


def test_inertia_compensation_settings_are_checked(at_once):
    bad_settings = (
        {"inertia_compensation": 1.0},
        {"inertia_compensation": -0.1},
        {"inertia_compensation_hz": 0.0},
        {"inertia_compensation": float("nan")},
    )
    for bad in bad_settings:
        with pytest.raises(ConfigError, match="inertia_compensation"):
            dataclasses.replace(at_once, **bad)


def test_tool_speed_scale_keeps_the_tool_and_the_flange_under_the_limit(at_once, model):
    """The speed limit's Jacobians against finite differences of the tool point's and the
    flange's positions (nominal kinematics, pinocchio's, not the compiled chain the law uses):
    exact where they were computed, and within 2 % of the speed anywhere within
    SPEED_JACOBIAN_STEP_RAD of there (the cache's reach)."""
    from control.model.dynamics import RigidBodyModel
    from control.zero_moment_law import SPEED_JACOBIAN_STEP_RAD

    ctl = ZeroMomentController(at_once, model)
    kin = RigidBodyModel.from_description(model.desc)
    p6 = np.array(model.desc.tool.position_in_link6_m)

    def points(q):
        pose = kin.world_T_tool(q)
        return pose[:3, 3], pose[:3, 3] - pose[:3, :3] @ p6

    def speeds(q, dq, h=1e-6):
        ahead, behind = points(q + dq * h), points(q - dq * h)
        return [float(np.linalg.norm(a - b)) / (2 * h) for a, b in zip(ahead, behind, strict=True)]

    rng = np.random.default_rng(11)
    limit = at_once.max_tool_speed_m_s
    lower, upper = model.desc.lower_rad, model.desc.upper_rad
    for _ in range(40):
        q = rng.uniform(lower, upper)
        dq = rng.normal(0.0, 0.3, model.n)
        for moved in (0.0, SPEED_JACOBIAN_STEP_RAD):
            at = q + rng.uniform(-moved, moved, model.n)
            fastest = max(speeds(at, dq))
            scale = ctl.tool_speed_scale(at, dq)
            want = min(1.0, limit / fastest)
            np.testing.assert_allclose(scale, want, rtol=1e-5 if moved == 0.0 else 0.02)
            if scale < 1.0:  # scaled down, the fastest of the two points runs at the limit
                assert max(speeds(at, dq * scale)) == pytest.approx(limit, rel=0.02)
