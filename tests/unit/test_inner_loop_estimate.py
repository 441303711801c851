"""The online inner-loop estimate (control/rt/src/law/inner_estimate.rs, control._rt)
finds a PI loop's gains from its averaged current, starting from commissioned values that are
wrong."""

from __future__ import annotations

import numpy as np
import pytest

from control import _rt

K = np.array([46.2, 66.2, 39.0, 11.2, 11.2, 5.6])  # datasheet torque constants [N·m/A]
KP0 = np.array([224.0, 375.0, 226.0, 12.1, 10.3, 5.0])
KI0 = KP0 * 32.0
INERTIA = np.array([120.0, 150.0, 40.0, 1.2, 1.0, 0.3])


def guided_motion(kp, ki, seconds, period=0.004, ticks=4, noise_a=0.02, seed=0, delay=1):
    """A PI-driven arm (the drive's eq. 19 at 1 kHz, the reference extrapolated over each
    cycle, the current averaged per cycle with noise and an offset), pushed by a hand, its
    commands from an outer loop that asks for a small drifting torque: yields the estimator's
    inputs per cycle (command that drove the cycle, q at its start and end, mean current)."""
    rng = np.random.default_rng(seed)
    n = kp.size
    q, dq = np.zeros(n), np.zeros(n)
    offset_a = rng.normal(0, 0.02, n)
    pending = [(q.copy(), np.zeros(n))] * (delay + 1)
    freqs = rng.uniform(0.2, 1.5, (3, n))
    phases = rng.uniform(0, 2 * np.pi, (3, n))
    dt = period / ticks
    t = 0.0
    for _ in range(round(seconds / period)):
        q_cmd, dq_cmd = pending[0]
        q0, dq0 = q.copy(), dq.copy()
        i_sum = np.zeros(n)
        for k in range(ticks):
            ref = q_cmd + dq_cmd * k * dt
            i = kp * (dq_cmd - dq) + ki * (ref - q)
            i_sum += i
            hand = INERTIA * 2.0 * np.sum(np.sin(2 * np.pi * freqs * t + phases), axis=0)
            ddq = (K * i + hand - 5.0 * dq) / INERTIA
            dq = dq + ddq * dt
            q = q + dq * dt
            t += dt
        current = i_sum / ticks + offset_a + rng.normal(0, noise_a, n)
        yield q_cmd, dq_cmd, q0, q.copy(), current, dq0, dq.copy()
        # the outer loop: follow the arm with a command offset for a slowly varying torque
        tau = 0.5 * K * np.sin(0.3 * t + np.arange(n))
        e = tau / (K * KP0 * 32.0)
        pending = [*pending[1:], (q + e, dq.copy())]


@pytest.mark.parametrize("scale", [(1.3, 0.7), (0.6, 1.4)])
def test_the_gains_are_found_within_5_percent_after_20_s_of_guided_motion(scale):
    kp, ki = KP0 * scale[0], KI0 * scale[1]
    est = _rt.InnerLoopEstimator(KP0, KI0, K)
    for *row, dq0, dq1 in guided_motion(kp, ki, 20.0):
        est.update(*row, 0.004, dq_start=dq0, dq_end=dq1, ticks=4)
    np.testing.assert_allclose(est.kp_hat_a_s_per_rad, kp, rtol=0.05)
    np.testing.assert_allclose(est.ki_hat_a_per_rad, ki, rtol=0.05)
    np.testing.assert_allclose(est.omega_rad_s_per_nm, 1 / (K * kp), rtol=0.05)
    np.testing.assert_allclose(est.upsilon_i_per_s, ki / kp, rtol=0.05)
    assert np.all(np.array(est.rel_std) < 0.05)


def test_without_motion_it_keeps_what_it_had():
    est = _rt.InnerLoopEstimator(KP0, KI0, K)
    q = np.zeros(6)
    for _ in range(5000):
        est.update(q, q, q, q, np.zeros(6), 0.004)
    np.testing.assert_allclose(est.kp_hat_a_s_per_rad, KP0)
    np.testing.assert_allclose(est.ki_hat_a_per_rad, KI0)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="one value per joint"):
        _rt.InnerLoopEstimator(KP0, KI0[:3], K)
    with pytest.raises(ValueError, match="> 0"):
        _rt.InnerLoopEstimator(-KP0, KI0, K)
    with pytest.raises(ValueError, match="memory_s"):
        _rt.InnerLoopEstimator(KP0, KI0, K, memory_s=0.0)


def test_cycles_the_drive_did_not_run_as_logged_are_rejected():
    """A few cycles whose logged command is not what the drive ran (17 A off on J1 in a stack
    run) would throw a least-squares estimate far off; they are skipped."""
    kp, ki = KP0 * 1.2, KI0 * 0.9
    est = _rt.InnerLoopEstimator(KP0, KI0, K)
    for c, (*row, dq0, dq1) in enumerate(guided_motion(kp, ki, 20.0, seed=3)):
        if c in (2000, 2001, 2002):  # mid-run: three cycles whose command was replaced
            row[1] = row[1] + np.array([0.05, 0.02, 0.02, 0.5, 0.5, 0.5])
        est.update(*row, 0.004, dq_start=dq0, dq_end=dq1, ticks=4)
    np.testing.assert_allclose(est.kp_hat_a_s_per_rad, kp, rtol=0.05)
    np.testing.assert_allclose(est.ki_hat_a_per_rad, ki, rtol=0.05)
    rejected = np.array(est.rejected)
    assert np.all(rejected >= 1) and np.all(rejected <= 10)
