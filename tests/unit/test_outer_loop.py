"""Eq. (21) against the inner loop of eq. (19): with exact ω and Υ_I the torque the closed loop
delivers converges to the desired torque."""

import numpy as np
import pytest

from control.outer_loop import OuterLoop

K = np.array([46.21, 66.18, 39.0])
KP = np.array([224.4, 375.3, 226.0])
KI = np.array([7479.0, 12510.0, 7532.0])


def inner_loop_torque(k, kp, ki, q, dq, q_cmd, dq_cmd):
    """The vendor's PI loop, eq. (19)–(20): the torque it produces [N·m]."""
    return k * (-kp * (dq - dq_cmd) - ki * (q - q_cmd))


def make_loop(omega=None, upsilon=None) -> OuterLoop:
    return OuterLoop(
        1.0 / (K * KP) if omega is None else omega,
        KI / KP if upsilon is None else upsilon,
        max_offset_rad=np.full(3, 0.05),
        max_velocity_rad_s=np.full(3, 2.0),
    )


def test_delivered_torque_converges_to_desired_with_exact_gains():
    loop = make_loop()
    q, dq = np.array([0.1, -0.2, 0.3]), np.zeros(3)
    tau_d = np.array([300.0, -800.0, 150.0])
    for _ in range(200):
        cmd = loop.step(q, dq, tau_d, 0.004)
    tau = inner_loop_torque(K, KP, KI, q, dq, cmd.q_cmd_rad, cmd.dq_cmd_rad_s)
    np.testing.assert_allclose(tau, tau_d, rtol=1e-6)


def test_wrong_gain_estimate_scales_the_torque():
    # eq. (23): with ω̂ = 2ω the loop delivers twice the desired torque.
    loop = make_loop(omega=2.0 / (K * KP))
    q, dq, tau_d = np.zeros(3), np.zeros(3), np.array([100.0, 100.0, 100.0])
    for _ in range(300):
        cmd = loop.step(q, dq, tau_d, 0.004)
    tau = inner_loop_torque(K, KP, KI, q, dq, cmd.q_cmd_rad, cmd.dq_cmd_rad_s)
    np.testing.assert_allclose(tau, 2 * tau_d, rtol=1e-6)


def test_offset_is_clamped_and_flagged():
    loop = make_loop()
    cmd = None
    for _ in range(500):
        cmd = loop.step(np.zeros(3), np.zeros(3), np.array([1e6, 0.0, 0.0]), 0.004)
    assert cmd is not None
    assert abs(cmd.q_cmd_rad[0]) <= 0.05 + 1e-12
    assert cmd.saturated[0] and not cmd.saturated[1]


def test_reset_gives_bumpless_takeover():
    loop = make_loop()
    loop.reset(np.array([0.001, -0.002, 0.0]))
    cmd = loop.step(np.zeros(3), np.zeros(3), np.zeros(3), 0.004)
    np.testing.assert_allclose(cmd.q_cmd_rad, [0.001, -0.002, 0.0])


def test_rejects_non_positive_gains():
    with pytest.raises(ValueError, match="positive"):
        make_loop(omega=np.array([1.0, 0.0, 1.0]))
