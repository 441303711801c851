"""The Smith predictor over the command delay (control/rt/src/law/delay.rs), closed with eq. (21)
around a one-joint drive and arm that are not the predictor's model: the vendor's PI loop of eq.
(19) at a 1 kHz servo tick, each command applied ``d`` cycles after the state it answers,
velocity noise, and an inertia and loop gains the product has only estimates of."""

from __future__ import annotations

import numpy as np
import pytest

from control._rt import DelayPredictor, OuterLoop

K, KP, KI = 66.18, 375.3, 12510.0  # a J2-sized drive [N·m/A, A s/rad, A/rad]
J = 230.0  # the arm's inertia about the joint [kg·m²]
SERVO_S = 0.001


def push(delay, predicted, period=0.008, j_model=J, gain_model=1.0, kp=KP, ki=KI, j=J,
         force_nm=20.0, seconds=3.0, seed=0):  # fmt: skip
    """Weightless arm (τ_d = 0) pushed with ``force_nm`` from 0.2 s: (speed reached over the
    ideal speed of a free inertia, std of the drive torque over the last 1.5 s / push)."""
    rng = np.random.default_rng(seed)
    k_star, ups = K * kp * gain_model, ki / kp
    loop = OuterLoop(np.array([1.0 / k_star]), np.array([ups]), np.array([0.05]),
                     np.array([2.0]))  # fmt: skip
    pred = DelayPredictor(delay if predicted else 0)
    m_inv = np.array([[1.0 / j_model]])
    q = dq = 0.0
    ref_q, ref_dq, t_ref = 0.0, 0.0, 0.0
    queue: list[tuple[float, float]] = []
    echo = (0.0, 0.0)
    t, taus = 0.0, []
    sub = round(period / SERVO_S)
    for _ in range(round(seconds / period)):
        if len(queue) > delay:  # the controller applies the set d cycles late
            ref_q, ref_dq = queue.pop(0)
            t_ref = t
        hand = force_nm if t > 0.2 else 0.0
        tau_sum = 0.0
        for _ in range(sub):
            r = ref_q + ref_dq * (t - t_ref)
            tau = K * (-kp * (dq - ref_dq) - ki * (q - r))
            tau_sum += tau
            dq += (tau + hand) / j * SERVO_S
            q += dq * SERVO_S
            t += SERVO_S
        taus.append(tau_sum / sub)
        dq_m = dq + rng.normal(0.0, 2e-4)
        qa, dqa = np.array([q]), np.array([dq_m])
        qp, dqp = pred.predict(qa, dqa, np.array([echo[0]]), np.array([echo[1]]), period,
                               True, m_inv, np.array([k_star]), np.array([ups]))  # fmt: skip
        cmd = loop.step(qp, dqp, np.zeros(1), period)
        echo = (float(cmd.q_cmd_rad[0]), float(cmd.dq_cmd_rad_s[0]))
        queue.append(echo)
    n = round(1.5 / period)
    return dq * j / (force_nm * (seconds - 0.2)), float(np.std(taus[-n:])) / force_nm


def test_without_delay_the_predictor_changes_nothing():
    q, dq = np.array([0.1]), np.array([0.2])
    out = DelayPredictor(0).predict(q, dq, q, dq, 0.008, True, np.eye(1), np.ones(1),
                                    np.ones(1))  # fmt: skip
    assert out[0] is q and out[1] is dq


def test_a_stale_command_makes_the_arm_a_damper_and_prediction_makes_it_light_again():
    light, _ = push(0, False)
    damped, _ = push(1, False)
    predicted, ripple = push(1, True)
    assert damped < 0.05 * light  # K K_I h ≈ 6,600 N·m·s/rad holds the arm
    assert predicted > 0.9 * light and ripple < 1.0


@pytest.mark.parametrize("delay,period", [(1, 0.008), (2, 0.008), (1, 0.004)])
@pytest.mark.parametrize("j_model,gain_model", [(1.3 * J, 1.0), (0.7 * J, 1.0), (J, 1.2),
                                                (J, 0.8), (1.3 * J, 0.8)])  # fmt: skip
def test_the_prediction_stays_stable_with_a_wrong_inertia_and_gain(delay, period, j_model,
                                                                   gain_model):  # fmt: skip
    for kp_f, ki_f, j in ((0.5, 0.5, J), (1.5, 1.5, J), (1.0, 1.0, 0.5 * J)):
        speed, ripple = push(delay, True, period, j_model * j / J, gain_model, KP * kp_f,
                             KI * ki_f, j)  # fmt: skip
        assert 0.1 < speed < 1.1 and ripple < 2.0, (kp_f, ki_f, j, speed, ripple)


def test_a_drive_model_stiffer_than_the_step_is_integrated_in_shorter_steps():
    """A drive model whose velocity loop is 5,000/s (K̂* 4 times a J2 drive on a 20 kg·m² arm):
    1 ms steps would diverge; the predictor takes shorter ones and stays near the arm, and
    beyond MAX_SUBSTEPS (K̂* 10⁴ times) it carries the velocity on instead."""
    pred = DelayPredictor(1)
    q, dq = np.array([0.1]), np.array([0.05])
    m_inv = np.array([[1.0 / 20.0]])
    k_star, ups = np.array([4.0 * K * KP]), np.array([1.2])
    for _ in range(3):  # a consecutive history: the PI model runs
        qp, dqp = pred.predict(q, dq, q + 0.001, dq, 0.008, True, m_inv, k_star, ups)
    assert abs(qp[0] - q[0]) < 0.01 and abs(dqp[0]) < 1.0
    huge = np.array([1e4 * K * KP])
    qp, dqp = pred.predict(q, dq, q + 0.001, dq, 0.008, True, m_inv, huge, ups)
    np.testing.assert_allclose((qp, dqp), (q + 0.008 * dq, dq))
