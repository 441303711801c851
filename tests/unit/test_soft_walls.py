"""The admittance's soft walls (control/rt/src/law/admittance/soft_walls.rs): a spring past the soft
limit, and a damper on the speed deeper into it, critical for the inertia the reference renders."""

from __future__ import annotations

import numpy as np
import pytest

from control import _rt
from control._rt import wall_torque_nm as compiled_walls

K = 2000.0  # [N·m/rad], the virtual cell's wall_stiffness_nm_per_rad
DT = 0.008  # [s], 125 Hz
LOWER, UPPER = np.array([-1.0]), np.array([1.0])


def wall_torque_nm(*args) -> np.ndarray:
    """The compiled walls' torque as an array."""
    return np.asarray(compiled_walls(*args))


def test_a_joint_inside_its_limits_feels_no_wall_whatever_its_speed():
    tau = wall_torque_nm(np.array([0.99]), np.array([0.5]), LOWER, UPPER, K, np.array([30.0]), DT)
    assert tau.tolist() == [0.0]


def test_past_a_limit_the_wall_pushes_back_by_its_depth_and_damps_a_speed_deeper_critically():
    inertia = np.array([30.0, 30.0])
    q, dq = np.array([1.01, -1.02]), np.array([0.0, 0.0])
    lower, upper = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    at_rest = wall_torque_nm(q, dq, lower, upper, K, inertia, DT)
    np.testing.assert_allclose(at_rest, [-K * 0.01, K * 0.02])
    deeper = wall_torque_nm(q, np.array([0.1, -0.1]), lower, upper, K, inertia, DT)
    critical = 2.0 * np.sqrt(K * 30.0)
    np.testing.assert_allclose(deeper - at_rest, [-critical * 0.1, critical * 0.1])
    # on the way out, the spring alone
    out = wall_torque_nm(q, np.array([-0.1, 0.1]), lower, upper, K, inertia, DT)
    np.testing.assert_allclose(out, at_rest)


def test_a_light_joints_wall_damper_never_takes_more_than_its_speed_in_one_step():
    """J6's rendered inertia is about 0.01 kg·m²: a critical damper (9 N·m·s/rad) would
    reverse its speed within a step; it is held to α M / dt."""
    inertia = np.array([0.01])
    tau = wall_torque_nm(np.array([1.01]), np.array([1.0]), LOWER, UPPER, K, inertia, DT)
    damper = -(tau[0] + K * 0.01)
    assert damper == pytest.approx(0.01 / DT)


def test_a_bad_step_is_refused():
    with pytest.raises(ValueError, match="step"):
        wall_torque_nm(np.array([0.0]), np.array([0.0]), LOWER, UPPER, K, np.array([1.0]), 0.0)


def ring(damped: bool) -> np.ndarray:
    """One joint of 100 kg·m² rendered at α = 0.3 with the light damping a painter feels (5
    N·m·s/rad) is pushed by 20 N·m past its dead zone into its upper wall, which acts on a
    measured position two cycles behind the reference (the vendor loop's lag). The reference's
    speed per step over 4 s."""
    law = _rt.Admittance(mass_fraction=0.3, damping=[5.0], band_nm=[1.0], filter_hz=5.0,
                         max_velocity=[1.0])  # fmt: skip
    law.reset([0.99])
    mass = [[100.0]]
    seen = [0.99, 0.99]
    inertia = np.array([0.3 * 100.0])
    speeds = []
    for _ in range(round(4.0 / DT)):
        q = np.array([seen[-2]])
        dq_r = np.array(law.dq_r)
        walls = (
            wall_torque_nm(q, dq_r, LOWER, UPPER, K, inertia, DT)
            if damped
            else -K * np.maximum(q - UPPER, 0.0)
        )
        q_r, dq = law.step([21.0], walls.tolist(), mass, DT)
        seen.append(q_r[0])
        speeds.append(dq[0])
    return np.abs(np.array(speeds))


def test_a_hand_pushing_into_a_damped_wall_comes_to_rest_where_an_undamped_one_rings():
    """The wall's equilibrium is 10 mrad deep (20 N·m past the band over 2,000 N·m/rad). The
    undamped wall is the case the damper is for: it still rings in the last second."""
    last_second = round(1.0 / DT)
    undamped, damped = ring(False), ring(True)
    print(f"peak speed in the last second: spring alone {undamped[-last_second:].max():.4f}, "
          f"damped {damped[-last_second:].max():.6f} rad/s")  # fmt: skip
    assert undamped[-last_second:].max() > 0.05
    assert damped[-last_second:].max() < 1e-3
