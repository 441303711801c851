"""The sensorless admittance (control/rt/src/law/admittance.rs, as control._rt): the reference
it integrates, and the controller that estimates the hand's
torque from the motor current and commands the vendor loop with it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from example_cell import example_cell

from control import _rt
from control.admittance_law import DRIVE_SETTLE_CYCLES, AdmittanceController
from control.cell_config import load_control_config
from control.declared_model import DeclaredModel
from gateway.errors import ConfigError
from gateway.message_factories import make_joint_state
from gateway.messages import FLAG_PREV_COAST, FLAG_PREV_HOLD, ControllerState

N = 6
DT = 0.004


def law(**kw) -> _rt.Admittance:
    args = {"mass_fraction": 0.5, "damping": [20.0] * N, "band_nm": [2.0] * N,
            "filter_hz": 5.0, "max_velocity": [1.0] * N} | kw  # fmt: skip
    return _rt.Admittance(**args)


def test_a_hand_torque_inside_the_dead_zone_leaves_the_arm_where_it_is():
    a = law()
    q0 = np.linspace(-0.3, 0.3, N)
    a.reset(q0)
    rng = np.random.default_rng(1)
    mass = np.diag([50.0, 200.0, 80.0, 1.0, 1.0, 0.3])
    for _ in range(2000):  # 8 s of noise and a steady error, each below the band
        a.step(rng.uniform(-1.9, 1.9, N), np.zeros(N), mass, DT)
    np.testing.assert_array_equal(a.q_r, q0)
    np.testing.assert_array_equal(a.dq_r, np.zeros(N))


def test_a_steady_push_reaches_the_speed_the_damping_allows_beyond_the_band():
    a = law()
    a.reset(np.zeros(N))
    mass = np.diag([50.0, 40.0, 80.0, 1.0, 1.0, 0.3])
    push = np.array([0.0, 12.0, 0.0, -4.0, 0.0, 0.0])
    for _ in range(round(8.0 / DT)):  # time constant α M / D: 1 s on J2; filter 0.03 s
        a.step(push, np.zeros(N), mass, DT)
    want = np.sign(push) * np.maximum(np.abs(push) - 2.0, 0.0) / 20.0
    np.testing.assert_allclose(a.dq_r, want, atol=0.01 * np.abs(want).max())
    assert a.q_r[1] > 0 and a.q_r[3] < 0 and a.q_r[0] == 0.0


def test_the_implicit_damping_is_stable_at_any_step_and_the_speed_is_capped():
    a = law(mass_fraction=0.01, max_velocity=[0.5] * N)
    a.reset(np.zeros(N))
    mass = np.eye(N)
    for dt in (0.004, 0.1, 1.0):
        for _ in range(50):
            a.step(np.full(N, 7.0), np.zeros(N), mass, dt)
            assert np.all(np.abs(a.dq_r) <= 0.5)
    a.reset(np.zeros(N))
    for _ in range(500):
        a.step(np.full(N, 1e4), np.zeros(N), mass, DT)
    np.testing.assert_allclose(a.dq_r, 0.5)


def test_a_wall_pushes_back_with_no_hand():
    a = law()
    a.reset(np.zeros(N))
    walls = np.zeros(N)
    walls[2] = -30.0
    for _ in range(100):
        a.step(np.zeros(N), walls, np.eye(N) * 10, DT)
    assert a.dq_r[2] < 0 and np.count_nonzero(a.dq_r) == 1


BAD_SETTINGS = [{"mass_fraction": 0.0}, {"filter_hz": float("nan")}, {"band_nm": [1.0] * 5},
                {"damping": [-1.0] * N}]  # fmt: skip


@pytest.mark.parametrize("kw", BAD_SETTINGS)
def test_bad_settings_are_refused(kw):
    with pytest.raises(ValueError):
        law(**kw)


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    return example_cell(tmp_path_factory.mktemp("cell"))


@pytest.fixture(scope="module")
def stiction_cfg(cell):
    """The defaults: the engagement probe and the stick zone on; the start-up dither off (these
    fake arms' currents carry the model's torque, not what else a command asks of the drive:
    tests/unit/test_startup_dither.py drives it)."""
    base = load_control_config(cell)[0]
    return dataclasses.replace(base, strategy="admittance", engage_rest_states=0,
                               admittance_dither=0.0)  # fmt: skip


@pytest.fixture(scope="module")
def cfg(stiction_cfg):
    """The law alone: no probe (b is the residual at rest), no stick zone."""
    return dataclasses.replace(stiction_cfg, admittance_probe_speed_rad_s=0.0,
                               admittance_stick_zone=0.0)  # fmt: skip


def state(k: int, q, current, q_cmd=None, dq=None, flags=0):
    q = np.asarray(q, dtype=float)
    dq = np.zeros(N) if dq is None else np.asarray(dq, dtype=float)
    return make_joint_state(k, 0.004 * k, ControllerState.EXTERNAL, flags, q, dq,
                            np.asarray(current), q if q_cmd is None else q_cmd, np.zeros(N),
                            0.004)  # fmt: skip


#: the arm's pose and the cylinders' pressures [bar] of the controller tests
Q0 = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
P_BAR = (6.0, 4.0)


def at_rest(cfg):
    """(model, controller, drive gains [N·m/A], pose, pressures, the static load there the
    drives carry with no hand [N·m])."""
    model = DeclaredModel.load(cfg.model)
    ctl = AdmittanceController(cfg, model)
    k_nm_per_a = np.array([j.drive_gain_nm_per_a for j in model.desc.joints])
    static = model.gravity_nm(Q0) - model.cylinder_nm(Q0, np.array(P_BAR))
    return model, ctl, k_nm_per_a, Q0.copy(), P_BAR, static


def test_the_controller_holds_still_when_the_current_carries_the_model_and_follows_a_lift(cfg):
    """The drives' current carries exactly the model's static load: no hand, no motion, and
    the command leads the arm by the offset the vendor loop holds that load with. Then J2's
    current drops by 40 N·m (a hand lifting the arm): the reference moves J2 up (+), and only
    J2 and the joints its inertia couples to. The arm follows the reference a cycle late (the
    example cell's delay is 0), its current the model's static load there and the torque that
    accelerates it, less the hand's: an arm held still under a reference that runs off carries
    no torque to accelerate, which the law reads as a hand pushing along the acceleration; the
    reference then rang at the offset limit, its speed's sign at the last cycle a matter of
    the damping (session 96: negative with the admittance's own damping)."""
    model, ctl, k_nm_per_a, q0, p, static = at_rest(cfg)
    adm = ctl.admittance
    current = static / k_nm_per_a
    for k in range(1, 200):
        q_cmd, dq_cmd = ctl.answer(state(k, q0, current), p)
    offset = ctl.loop.omega * static / ctl.loop.upsilon_i
    np.testing.assert_allclose(q_cmd, q0 + offset, atol=1e-12)
    np.testing.assert_allclose(dq_cmd, 0.0, atol=1e-12)
    lift = np.zeros(N)
    lift[1] = 40.0
    for k in range(200, 300):
        q, dq = np.array(adm.q_r), np.array(adm.dq_r)
        load = model.gravity_nm(q) - model.cylinder_nm(q, np.array(p)) - lift
        load = load + ctl.mass(q) @ np.array(adm.ddq_r)  # what accelerating it takes
        q_cmd, dq_cmd = ctl.answer(state(k, q, load / k_nm_per_a, dq=dq), p)
    assert dq_cmd[1] > 1e-3, dq_cmd
    assert ctl.admittance.q_r[1] > q0[1]
    # never more than the offset limit ahead of the arm (the controller faults beyond it)
    assert np.all(np.abs(np.array(q_cmd) - q) <= np.array(cfg.max_offset_rad) + 1e-12)


def lifted_then(
    cfg, step_nm: float, flags: int = 0, skip: int = 0, extra_states: int = 0
) -> tuple[float, float]:
    """A hand lifts J2 (its current 40 N·m under the model's static load at the arm's pose)
    for 0.4 s, the arm following its reference; then one state (``flags``; ``skip`` cycles
    the law never saw before it) and the ``delay + DRIVE_SETTLE_CYCLES`` after it (and
    ``extra_states`` more) carry ``step_nm`` more on J2 against the motion, as a drive
    stepping its command's speed to zero does. J2's hand torque estimate τ̂_h before that
    state and after those [N·m]."""
    model, ctl, k_nm_per_a, q0, p, _ = at_rest(cfg)
    adm = ctl.admittance
    lift = np.zeros(N)
    lift[1] = 40.0

    def follow(k, extra=0.0, flags=0):
        q = np.array(adm.q_r) if k > 1 else q0
        static = model.gravity_nm(q) - model.cylinder_nm(q, np.array(p))
        current = (static - lift * (k >= 100) + extra) / k_nm_per_a
        ctl.answer(state(k, q, current, dq=adm.dq_r, flags=flags), p)

    for k in range(1, 200):  # engaged at rest (b is the residual there), lifted from k = 100
        follow(k)
    before = adm.tau_h[1]
    step = np.zeros(N)
    step[1] = step_nm
    first = 200 + skip
    follow(first, step, flags)
    window = cfg.command_delay_cycles + 1 + DRIVE_SETTLE_CYCLES
    for k in range(first + 1, first + window + extra_states):
        follow(k, step)
    return before, adm.tau_h[1]


def test_currents_a_cycle_the_drive_held_or_coasted_drove_are_not_read_as_a_hand(cfg):
    """A cycle the law did not command in time is one the drive held (or coasted): the hold
    steps the command's speed to zero, and the vendor loop's answer is tens of N·m against the
    motion for a few cycles. Read as a hand, it brakes or reverses the reference (on a
    release, the driver's stop then continued the reversal and ran the arm back 4-14 mm,
    2026-12-03); the law keeps its estimate over the states the drive's step drove, flagged
    (FLAG_PREV_HOLD, FLAG_PREV_COAST) or after cycles it never saw, and reads the current
    again after them."""
    before, read = lifted_then(cfg, 150.0)
    assert before > 20.0, "the lift reads as a push up"
    assert read < before - 50.0, "a law that reads the step's current takes it for a hand"
    for flags, skip in ((FLAG_PREV_HOLD, 0), (FLAG_PREV_COAST, 0), (0, 3)):
        assert lifted_then(cfg, 150.0, flags, skip) == (before, before), (flags, skip)
    # one state later the current counts again
    assert lifted_then(cfg, 150.0, FLAG_PREV_HOLD, extra_states=1)[1] < before - 10.0


def test_a_cell_config_naming_an_unknown_strategy_is_refused(cell, tmp_path):
    text = cell.read_text().replace("[control]", '[control]\nstrategy = "telepathy"', 1)
    bad = tmp_path / "cell.toml"
    bad.write_text(text)
    for f in cell.parent.iterdir():
        if f.name != "cell.toml" and f.is_file():
            (tmp_path / f.name).write_bytes(f.read_bytes())
    with pytest.raises(ConfigError, match="strategy"):
        load_control_config(bad)


def test_the_reference_keeps_the_tool_and_the_flange_under_the_hand_guiding_speed(cfg):
    """A push far beyond anything a hand does: the reference's joint speeds would carry the
    tool at metres per second; the tool point and the flange stay at the configured limit
    (within the 2 % the limit's cached Jacobians allow, control/zero_moment_law.py
    SPEED_JACOBIAN_STEP_RAD)."""
    from control.model.dynamics import RigidBodyModel

    model, ctl, k_nm_per_a, q0, p, static = at_rest(cfg)
    kin = RigidBodyModel.from_description(model.desc)
    current = static / k_nm_per_a
    for k in range(1, 50):
        ctl.answer(state(k, q0, current), p)
    shoved = current - np.array([400.0, 0.0, 0.0, 0.0, 30.0, 10.0]) / k_nm_per_a
    fastest = 0.0
    for k in range(50, 400):
        ctl.answer(state(k, q0, shoved), p)
        q_r, dq_r = ctl.admittance.q_r, ctl.admittance.dq_r
        twist = kin.tool_jacobian_world(q_r) @ dq_r
        rot = kin.world_T_tool(q_r)[:3, :3]
        flange = twist[:3] - np.cross(
            twist[3:], rot @ np.array(model.desc.tool.position_in_link6_m)
        )
        fastest = max(fastest, np.linalg.norm(twist[:3]), np.linalg.norm(flange))
    assert fastest == pytest.approx(cfg.max_tool_speed_m_s, rel=0.02)
    assert cfg.max_tool_speed_m_s == 0.22


def test_a_guided_arm_that_only_creeps_settles_and_then_needs_the_static_zone_again():
    """Static zone 5 N·m (the noise), kinetic 2 N·m (the model): a 6 N·m push breaks J2
    away; a 2.2 N·m push after it (a model error at the new pose, say) creeps below
    SETTLE_RAD_S, so within SETTLE_S the arm is at rest and stays."""
    a = law(rest_factor=10.0)
    a.reset(np.zeros(N), noise_std_nm=np.full(N, 5.0 / 3.5))
    np.testing.assert_allclose(a.band, 5.0)
    mass = np.eye(N) * 20.0
    push = np.zeros(N)
    push[1] = 6.0
    for _ in range(250):
        a.step(push, np.zeros(N), mass, DT)
    assert a.moving and a.dq_r[1] > 0.05
    push[1] = 2.2
    steps = 0
    while a.moving and steps < 2000:
        a.step(push, np.zeros(N), mass, DT)
        steps += 1
    assert not a.moving, "the creep kept the arm guided"
    assert steps * DT < 2.0 + _rt.ADMITTANCE_SETTLE_S
    for _ in range(500):
        a.step(push, np.zeros(N), mass, DT)
    assert a.dq_r[1] == pytest.approx(0.0, abs=1e-9)


def test_the_probe_takes_the_models_error_free_of_what_friction_carried_at_rest():
    """J1 slides after sticking a while at each reversal: residual = error − friction ·
    direction − a hand's spring on the probe's offset (+ noise); J2 never slides: it keeps
    its residual at rest beyond its friction level."""
    probe = _rt.EngageProbe(np.full(2, 0.01), 0.5, DT, 2e-3)
    offset = np.array(probe.offset)
    assert len(probe) == 4 * 31 + 1 and np.allclose(offset[-1], 0.0, atol=1e-15)
    assert np.all(np.abs(offset).max(axis=0) < 0.01 * 0.125 + 1e-12)
    assert offset[:, 0].max() == pytest.approx(-offset[:, 0].min())
    rng = np.random.default_rng(3)
    error, friction, carried = 4.0, 30.0, -25.0
    lag = 0
    for k, way in enumerate(probe.cruise):
        lag = lag + 1 if way and lag < 4 else 0 if not way else lag  # stuck the first 4
        sliding = way != 0 and lag >= 4
        dq = np.array([way * 0.01 if sliding else 0.0, 0.0])
        r1 = error - friction * way if sliding else error - carried
        grip = -2e4 * offset[k, 0]  # a hand holding the tool on a spring [N·m/rad]
        probe.observe(k, dq, np.array([r1 + grip + rng.normal(0, 0.5), 7.0]))
    n_pos, n_neg = probe.samples()[0]
    assert min(n_pos, n_neg) >= _rt.PROBE_MIN_SAMPLES and probe.samples()[1] == (0, 0)
    b, kept = probe.bias(np.array([error - carried, 7.0]), np.array([friction, 5.0]))
    assert b[0] == pytest.approx(error, abs=0.5)
    assert kept == [1] and b[1] == pytest.approx(2.0)


def test_with_stiction_a_load_share_the_friction_may_carry_is_no_hand(stiction_cfg):
    """The controller probes at engagement (the arm follows the probe, the current carries
    the model, a 5 N·m error and the friction against the motion); then at rest a share of
    the load within the friction level moves nothing, and the same torque read while J2
    slides is a hand."""
    model, ctl, k_nm_per_a, q0, p, static = at_rest(stiction_cfg)
    level = ctl.friction_level_nm(q0)
    assert level[1] > 2.0, "the example model needs friction on J2 for this test"
    error = np.full(N, 5.0)
    dq_cmd = np.zeros(N)
    k = 0
    assert ctl.engagement() == {"phase": "idle"}
    left = []  # the probe's time still to run, as the operator's status shows it
    while k < 400 and (k < 5 or ctl.probing):
        k += 1
        # the arm follows each command a cycle late (the example cell's delay is 0)
        tau = static + error + level * np.sign(dq_cmd)
        _, dq_new = ctl.answer(state(k, q0, tau / k_nm_per_a, dq=dq_cmd), p)
        dq_cmd = np.array(dq_new)
        if (phase := ctl.engagement())["phase"] == "probing":
            left.append(phase["left_s"])
    assert not ctl.probing, "the probe did not end"
    assert ctl.engagement() == {"phase": "following"}
    assert left and left[0] == pytest.approx(stiction_cfg.admittance_probe_s, abs=0.02)
    assert np.all(np.diff(left) <= 0) and left[-1] <= 0.02, left[-3:]  # (0.01 s steps)
    np.testing.assert_allclose(ctl.bias, -error, atol=1e-9)
    share = np.zeros(N)
    share[1] = 0.8 * level[1]
    for i in range(k + 1, k + 200):
        _, dq_cmd = ctl.answer(state(i, q0, (static + error + share) / k_nm_per_a), p)
    assert not ctl.admittance.moving and np.all(np.array(dq_cmd) == 0.0)
    sliding = np.zeros(N)
    sliding[1] = 0.01  # a hand pushes J2 up: the drive gives that much less
    adm = ctl.admittance
    for i in range(k + 200, k + 300):
        # the arm follows the reference and carries what accelerating it takes (held still,
        # the missing torque reads as a hand: the lift test above)
        q = np.array(adm.q_r)
        load = model.gravity_nm(q) - model.cylinder_nm(q, np.array(p))
        tau = load + error - share + model.friction_nm(q, sliding) + ctl.mass(q) @ adm.ddq_r
        _, dq_cmd = ctl.answer(state(i, q, tau / k_nm_per_a, dq=sliding), p)
    assert ctl.admittance.moving and dq_cmd[1] > 0.0
    ctl.disengage()
    assert ctl.engagement() == {"phase": "idle"}


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("admittance_stick", "glue", "admittance_stick"),
        ("admittance_hold_rad_s", -1e-3, "admittance_hold_rad_s"),
        ("admittance_hold_rad_s", float("nan"), "admittance_hold_rad_s"),
    ],
)
def test_a_bad_stick_or_hold_is_refused_by_name(stiction_cfg, key, value, match):
    with pytest.raises(ConfigError, match=match):
        dataclasses.replace(stiction_cfg, **{key: value})


def test_the_hold_speed_is_per_joint_a_float_holds_every_joint_and_a_wrong_length_is_refused():
    a = law()
    assert a.hold_rad_s == [0.0] * N
    a.hold_rad_s = 0.004
    assert a.hold_rad_s == [0.004] * N
    a.hold_rad_s = [0.0, 0.02, 0.0, 0.0, 0.0, 0.01]
    assert a.hold_rad_s == [0.0, 0.02, 0.0, 0.0, 0.0, 0.01]
    with pytest.raises(ValueError, match="2 values for 6 joints"):
        a.hold_rad_s = [0.01, 0.01]
    with pytest.raises(ValueError, match="must be >= 0"):
        a.hold_rad_s = [0.0, -0.01, 0.0, 0.0, 0.0, 0.0]


def test_with_the_stribeck_hold_each_joint_is_held_below_its_models_stribeck_speed(
    cfg, monkeypatch
):
    """The controller asks control/stribeck_speed.py (tested on its own) with its model, the
    home pose and its dead zone, and holds each joint below the faster of that and the floor.
    The example's declared model has no Stribeck fall (its sign is as wide as its decay)."""
    model = DeclaredModel.load(cfg.model)
    floor = dataclasses.replace(cfg, admittance_hold_rad_s=0.004)
    assert AdmittanceController(floor, model).admittance.hold_rad_s == [0.004] * N
    on = dataclasses.replace(floor, admittance_hold_stribeck=True)
    assert AdmittanceController(on, model).admittance.hold_rad_s == [0.004] * N
    asked = []

    def speeds(m, q, band):
        asked.append((m, q.tolist(), band.tolist()))
        return np.array([0.0, 0.02, 0.003, 0.0, 0.01, 0.0])

    monkeypatch.setattr("control.admittance_law.stribeck_speeds", speeds)
    ctl = AdmittanceController(on, model)
    assert ctl.admittance.hold_rad_s == [0.004, 0.02, 0.004, 0.004, 0.01, 0.004]
    assert asked == [(model, [0.0] * N, ctl.admittance.base_band)]
