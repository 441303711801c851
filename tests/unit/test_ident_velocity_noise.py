"""Friction taken in expectation over whether a joint moves, given its velocity's measurement
noise (:meth:`control.identification.terms.Context.sample_mean`,
:func:`control.identification.friction_law.rest_probability`,
:func:`control.identification.preprocess.velocity_noise_std`).

A joint at rest reads its velocity noise; a friction sign taken of it flipped between ± the
Coulomb level from one sample to the next. On the hard world of issue 46 (teaching stretches
with rests in the held-out run) that alone left a resting joint 44 N·m RMS off (seed 28, J2,
noise floor 2.3 N·m), and plain least squares no better. Given a measured velocity v̂ with
noise σ the joint rests with probability expit(L - v̂²/2σ²) (no friction sign there), and
moves at v̂ otherwise: 0 at rest, the sign itself once |v̂| is a few σ.
"""

from __future__ import annotations

import numpy as np
import pytest

from control.identification.friction_law import rest_probability
from control.identification.model import plain_friction_columns
from control.identification.preprocess import (
    _lowpass,
    filter_noise_gain,
    velocity_noise_std,
)
from control.identification.terms import Context

SIGMA = 2e-4  # rad/s


def _columns(dq: np.ndarray, noise: float | None) -> np.ndarray:
    q = np.zeros((dq.size, 1))
    ctx = Context(q, dq[:, None], np.zeros_like(q), dq_noise=None if noise is None else [noise])
    return plain_friction_columns(ctx, 0)  # sgn dq, dq, 1


def test_the_coulomb_column_is_the_sign_weighed_by_the_chance_the_joint_moves():
    dq = np.array([-1.0, -6 * SIGMA, -SIGMA, 0.0, 0.5 * SIGMA, 4 * SIGMA, 1.0])
    cols = _columns(dq, SIGMA)
    moving = 1.0 - rest_probability(dq, SIGMA)
    np.testing.assert_allclose(cols[:, 0], np.sign(dq) * moving, atol=1e-12)
    assert cols[3, 0] == 0.0  # at rest: no friction sign either way
    assert abs(cols[2, 0]) < 1e-3 and abs(cols[4, 0]) < 1e-3  # within the noise: at rest
    assert cols[5, 0] == pytest.approx(0.5)  # the band's edge, ± 4 σ
    assert cols[1, 0] < -0.98 and cols[-1, 0] == pytest.approx(1.0)  # moving: the sign
    np.testing.assert_allclose(cols[:, 2], 1.0)  # a constant stays itself
    np.testing.assert_allclose(cols[[0, -1], 1], dq[[0, -1]], rtol=1e-12)


def test_without_noise_the_columns_are_the_velocitys_own():
    dq = np.array([-1.0, -1e-6, 0.0, 1e-6, 1.0])
    for noise in (None, 0.0):
        np.testing.assert_array_equal(_columns(dq, noise)[:, 0], np.sign(dq))


def test_a_resting_joints_predicted_coulomb_torque_averages_out_instead_of_flipping():
    rng = np.random.default_rng(3)
    dq = rng.normal(0.0, SIGMA, 2000)  # a joint at rest: its velocity is the noise alone
    sign = _columns(dq, SIGMA)[:, 0]
    hard = np.sign(dq)
    assert np.sqrt(np.mean(hard**2)) == 1.0  # ± the Coulomb level on every sample
    assert np.sqrt(np.mean(sign**2)) < 0.01  # a joint at rest: no Coulomb torque predicted


def test_the_velocity_noise_after_the_filter_is_measured_from_the_raw_samples():
    fs, cutoff = 500.0, 5.0
    t = np.arange(20000) / fs
    rng = np.random.default_rng(7)
    true_dq = 0.3 * np.cos(2 * np.pi * 0.2 * t)  # a slow motion under the noise
    q = np.column_stack([0.3 / (2 * np.pi * 0.2) * np.sin(2 * np.pi * 0.2 * t)])
    noise = 1e-3 * rng.standard_normal(t.size)
    dq = np.column_stack([true_dq + noise])
    measured = velocity_noise_std(q, dq, 1.0 / fs, cutoff)
    filtered = np.std(_lowpass(noise[:, None], cutoff, fs)[500:-500])
    assert measured[0] == np.float64(measured[0])
    np.testing.assert_allclose(measured[0], filtered, rtol=0.1)
    np.testing.assert_allclose(
        measured[0], 1e-3 * np.sqrt(filter_noise_gain(cutoff, fs)), rtol=0.05
    )
