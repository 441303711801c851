"""Assist cylinders, eqs. (10) and (12): values, the assist sign, and the pressure inverse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from control.model.cylinders import cylinder_torque_nm, pressure_for_torque
from control.model.dynamics import RigidBodyModel
from gateway.robot.description import CylinderSpec, RobotDescription, load_description

J2, J3 = 1, 2


@pytest.fixture(scope="module")
def desc() -> RobotDescription:
    return load_description()


def _q(**angles_deg: float) -> np.ndarray:
    q = np.zeros(6)
    for name, deg in angles_deg.items():
        q[int(name[1]) - 1] = math.radians(deg)
    return q


def test_piston_area_matches_the_paper(desc):
    assert desc.cylinders[0].piston_area_m2 == pytest.approx(7.854e-3, rel=1e-4)  # S2, eq. (9)


def test_eq10_against_hand_calculation(desc):
    # q2 = 40°, P2 = 6 bar: φ = π - θ2 = 140°, sin φ = 0.6427876, cos φ = -0.7660444,
    # |B2C2| = sqrt(0.125² + 0.335² + 2·0.125·0.335·0.7660444) = 0.4381852 m (eq. 5),
    # F2 = P2 S2 = 6e5 · 7.853982e-3 = 4712.389 N,
    # T2 = 4712.389 · 0.125 · 0.335 · 0.6427876 / 0.4381852 = 289.4715 N·m (eq. 10).
    tau = cylinder_torque_nm(_q(j2=40.0), [6.0, 0.0], desc)
    assert abs(tau[J2]) == pytest.approx(289.4715, rel=1e-6)
    assert tau[J2] == pytest.approx(desc.cylinders[0].torque_sign * 289.4715, rel=1e-6)
    assert np.count_nonzero(tau) == 1
    # eq. (10) vanishes with the upper arm upright and is odd in q2.
    assert cylinder_torque_nm(_q(), [6.0, 0.0], desc)[J2] == pytest.approx(0.0, abs=1e-12)
    assert cylinder_torque_nm(_q(j2=-40.0), [6.0, 0.0], desc)[J2] == pytest.approx(-tau[J2])


def test_eq12_against_hand_calculation(desc):
    # P3 S3 |A3B3| = 4e5 · 7.853982e-3 · 0.1 = 314.1593 N·m at q3 = 0; × cos 60° = 157.0796.
    tau0 = cylinder_torque_nm(_q(), [0.0, 4.0], desc)
    tau60 = cylinder_torque_nm(_q(j3=60.0), [0.0, 4.0], desc)
    assert abs(tau0[J3]) == pytest.approx(314.1593, rel=1e-6)
    assert abs(tau60[J3]) == pytest.approx(157.0796, rel=1e-6)
    assert np.count_nonzero(tau0) == 1


@pytest.mark.parametrize(("joint", "q"), [(J2, _q(j2=40.0)), (J2, _q(j2=-40.0)), (J3, _q())])
def test_cylinders_assist_against_gravity_at_nominal_pressure(desc, joint, q):
    g = RigidBodyModel.from_description(desc).gravity_nm(q)
    holding = g - cylinder_torque_nm(q, desc.nominal_pressures_bar, desc)
    assert abs(holding[joint]) < abs(g[joint])


def test_torque_is_vectorized_over_samples(desc):
    rng = np.random.default_rng(12)
    q = rng.uniform(desc.lower_rad, desc.upper_rad, size=(50, 6))
    p = rng.uniform(0.0, 7.0, size=(50, 2))
    batched = cylinder_torque_nm(q, p, desc)
    assert batched.shape == (50, 6)
    for k in (0, 25, 49):
        np.testing.assert_allclose(cylinder_torque_nm(q[k], p[k], desc), batched[k])
    assert np.all(batched[:, [0, 3, 4, 5]] == 0.0)
    # One pressure vector for many configurations broadcasts.
    broadcast = cylinder_torque_nm(q, p[0], desc)
    np.testing.assert_allclose(broadcast[3], cylinder_torque_nm(q[3], p[0], desc))


def test_torque_is_linear_in_pressure(desc):
    q = _q(j2=25.0, j3=-20.0)
    t1 = cylinder_torque_nm(q, [1.0, 1.0], desc)
    np.testing.assert_allclose(cylinder_torque_nm(q, [6.0, 4.0], desc), t1 * [1, 6, 4, 1, 1, 1])


def test_pressure_for_torque_inverts_the_torque(desc):
    rng = np.random.default_rng(4)
    q = rng.uniform(desc.lower_rad, desc.upper_rad, size=(100, 6))
    q[:, J2] = np.where(np.abs(q[:, J2]) < 0.05, 0.3, q[:, J2])  # stay clear of T2 = 0
    p = rng.uniform(0.0, 7.0, size=(100, 2))
    tau = cylinder_torque_nm(q, p, desc)
    np.testing.assert_allclose(pressure_for_torque(q, tau, desc), p, rtol=1e-10, atol=1e-10)


def test_pressure_for_torque_is_nan_without_lever(desc):
    p = pressure_for_torque(_q(j2=0.0, j3=0.0), np.full(6, 100.0), desc)
    assert math.isnan(p[0])
    assert p[1] == pytest.approx(100.0 / (1e5 * 7.853981634e-3 * 0.1))  # bar, torque_sign +1


def test_accepts_a_list_of_specs(desc):
    specs = [CylinderSpec(2, "j3_lever", 0.1, 0.1, 1.0, 4.0)]
    tau = cylinder_torque_nm(np.zeros(6), [4.0], specs)
    assert tau[2] == pytest.approx(314.1592653589793)
