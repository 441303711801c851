"""Cylinder set-points scheduled from the pose (control/pressure_schedule.py): each cylinder
takes its share of the model's static load where its lever allows, within the valves' range,
and the set-points move slowly; the control process follows the pose in teaching and replay,
ramps back to the fixed set-points for identification and holds them otherwise."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from example_cell import example_cell

from control.cell_config import load_control_config
from control.model.cylinders import cylinder_torque_nm
from control.pressure_schedule import PressureSchedule, ScheduleSettings
from control.process import ControlProcess
from gateway.config import ConfigError
from gateway.messages import Lifecycle, LifecycleMsg
from gateway.robot.description import load_description

DESC = load_description()


def schedule(**settings) -> PressureSchedule:
    return PressureSchedule(DESC.cylinders, ScheduleSettings(**settings), (6.0, 4.0))


def test_each_cylinder_takes_its_share_of_the_static_load_where_its_lever_allows():
    """Over random poses and loads: where the pressure asked for is within the range, the
    cylinder carries ``share`` of its joint's load, less where its lever is short (the ridge);
    at the top of the range less; at the bottom, only where its share is less than the least
    pressure gives or gravity pulls the other way."""
    sched = schedule(share=0.8, min_bar=0.5, max_bar=8.0)
    rng = np.random.default_rng(0)
    inside = 0
    for _ in range(500):
        q = rng.uniform(DESC.lower_rad, DESC.upper_rad)
        static = rng.normal(0.0, 400.0, 6)
        p = np.array(sched.target_bar(q.tolist(), static.tolist()))
        assert np.all((p >= 0.5) & (p <= 8.0))
        tau = cylinder_torque_nm(q, p, DESC)
        for k, spec in enumerate(DESC.cylinders):
            j = spec.joint_index
            lever = cylinder_torque_nm(q, np.eye(2)[k], DESC)[j]  # N·m per bar
            if 0.5 < p[k] < 8.0:  # the ridge: share · lever² / (lever² + L²) of the load
                assert tau[j] / static[j] == pytest.approx(0.8 * lever**2 / (lever**2 + 25.0))
                inside += 1
            else:  # clipped: what the ridge asks for is beyond the range's end
                asked = 0.8 * static[j] * lever / (lever**2 + 25.0)
                assert (p[k] == 8.0 and asked >= 8.0) or (p[k] == 0.5 and asked <= 0.5)
    assert inside > 100


def test_the_pressure_changes_side_only_where_the_lever_is_nothing():
    """The crank's lever crosses zero near the upright: on the side where the cylinder holds
    against gravity it is asked for the most, on the other for the least, and the change
    happens where its lever is under 1 N·m/bar (a few N·m whatever the pressure)."""
    sched = schedule(share=0.8, min_bar=0.0, max_bar=8.0)
    static = [0.0, 600.0, 200.0, 0.0, 0.0, 0.0]
    spec = DESC.cylinders[0]
    for q2 in np.arange(-0.4, 0.4, 0.001):
        q = [0.0, q2, 0.3, 0.0, 0.0, 0.0]
        p = sched.target_bar(q, static)[0]
        lever = cylinder_torque_nm(np.array(q), np.array([1.0, 0.0]), DESC)[spec.joint_index]
        if 0.0 < p < 8.0:
            assert abs(lever) < 1.0, (q2, lever, p)
        else:
            assert (p == 8.0) == (lever > 0)


def test_the_set_points_move_through_a_filter_and_a_rate_limit():
    sched = schedule(time_constant_s=1.0, rate_bar_per_s=2.0)
    sched.update([6.0, 4.0], 0.0)  # the clock starts
    p = sched.update([0.5, 8.0], 0.1)
    assert p[0] == pytest.approx(6.0 - 0.2) and p[1] == pytest.approx(4.0 + 0.2)  # rate limit
    t = 0.1
    for _ in range(100):  # 10 s: the filter settles
        t += 0.1
        p = sched.update([0.5, 8.0], t)
    np.testing.assert_allclose(p, [0.5, 8.0], atol=0.01)
    assert sched.update([float("nan"), 2.0], t + 0.1)[0] == p[0]  # no target: stays
    held = sched.hold(t + 100.0)  # held for 100 s, then the next update moves 0.1 s worth
    assert sched.update([0.5, 2.0], t + 100.1)[1] >= held[1] - 0.2 - 1e-12
    back = [sched.update(None, t + 101 + k) for k in range(20)][-1]  # None: the fixed ones
    np.testing.assert_allclose(back, [6.0, 4.0], atol=0.01)


@pytest.mark.parametrize(
    ("key", "value"),
    [("pressure_schedule_share", 1.5), ("pressure_schedule_range_bar", (5.0, 2.0)),
     ("pressure_schedule_range_bar", (0.0, 12.0)), ("pressure_schedule_rate_bar_per_s", 0.0)],
)  # fmt: skip
def test_a_bad_schedule_setting_is_refused_naming_it(tmp_path, key, value):
    cfg, _ = load_control_config(example_cell(tmp_path))
    with pytest.raises(ConfigError, match=key):
        dataclasses.replace(cfg, **{key: value})


def test_the_control_process_follows_the_pose_while_held_or_moving_and_holds_at_rest(tmp_path):
    """READY (the drives hold the arm): the set-points follow the pose; teaching with the arm
    at rest: they hold; teaching with the arm moving: they follow; STOPPED: they hold;
    identification: back to the fixed ones."""
    cfg, bus = load_control_config(example_cell(tmp_path))
    fixed = ControlProcess(dataclasses.replace(cfg, pressure_schedule=False), bus)
    assert fixed.schedule is None and fixed.pressure_setpoints(0.0) == cfg.pressure_setpoint_bar
    proc = ControlProcess(dataclasses.replace(cfg, pressure_schedule=True), bus)
    assert proc.schedule is not None
    q = np.array([0.0, -0.2, 0.4, 0.0, 0.5, 0.0])  # J2 leaning back: its crank has a lever
    static, _ = proc.ctl.model.cycle_torques_nm(q, [0.0] * 6, [0.0, 0.0])
    target = proc.schedule.target_bar(q.tolist(), static)
    assert np.abs(np.subtract(target, [6.0, 4.0])).min() > 0.5

    def run(state, seconds, t0, moving=False):
        proc._last_state = (0, q, np.full(6, 0.05 if moving else 0.001))  # the newest pose
        out = None
        for k in range(round(seconds / 0.1)):
            now = t0 + 0.1 * k
            proc.lifecycle, proc.lifecycle_rx_s = LifecycleMsg(state, 1, now), now
            out = proc.pressure_setpoints(now)
        return out

    assert run(Lifecycle.STOPPED, 2.0, 0.0) == (6.0, 4.0)  # braked: held where they were
    partway = run(Lifecycle.READY, 0.5, 2.0)
    assert partway != (6.0, 4.0)  # the drives hold the arm: following the pose
    assert run(Lifecycle.TEACHING, 3.0, 2.5) == pytest.approx(partway)  # at rest: held
    np.testing.assert_allclose(run(Lifecycle.TEACHING, 10.0, 5.5, moving=True), target,
                               atol=0.02)  # fmt: skip
    assert run(Lifecycle.STOPPED, 2.0, 15.5) == pytest.approx(target, abs=0.02)
    np.testing.assert_allclose(run(Lifecycle.IDENTIFYING, 10.0, 17.5), (6.0, 4.0), atol=0.02)
