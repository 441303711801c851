"""The velocity friction is taken of (:mod:`control.identification.friction_velocity`): the
positions' slope where they are finer than the measured velocity.

Issue 46, hard world draw 137 (J2, a Coulomb law at its full 38.9 N·m from 1e-4 rad/s; the
velocity reading's noise 3e-4 rad/s, the encoder's step 1e-6 rad): leaving a rest the joint
crept at 1e-4-3e-4 rad/s for 0.35 s, and the model's friction, taken of the measured velocity,
came 0.15 s late: 14.4 N·m RMS over that second of the holdout, where the noise is 1.3.
"""

from __future__ import annotations

import numpy as np
import pytest

from control.identification.friction_velocity import (
    MIN_POSITION_NOISE_RAD,
    friction_velocity,
    resolution,
    slope,
)
from control.identification.preprocess import _lowpass, filter_noise_gain

FS = 200.0
CUTOFF = 4.0
STEP_RAD = 1e-6  # encoder step through the gear
DQ_NOISE = 1e-3  # rad/s


def _quantised(q: np.ndarray) -> np.ndarray:
    return np.round(q / STEP_RAD) * STEP_RAD


def _blend(q_true: np.ndarray, seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(friction velocity, its noise, the low-passed measured velocity) of one joint."""
    rng = np.random.default_rng(seed)
    q = _quantised(q_true)[:, None]
    dq_true = np.gradient(q_true, 1.0 / FS)
    dq = (dq_true + DQ_NOISE * rng.standard_normal(q_true.size))[:, None]
    v_measured = _lowpass(dq, CUTOFF, FS)
    v_noise = np.array([DQ_NOISE * np.sqrt(filter_noise_gain(CUTOFF, FS))])
    v, sigma = friction_velocity(q, q, np.zeros(1), v_measured, v_noise, CUTOFF, FS)
    return v[:, 0], sigma, v_measured[:, 0]


def test_a_creep_out_of_rest_reads_in_the_positions_and_not_in_the_velocity():
    t = np.arange(0.0, 4.0, 1.0 / FS)
    creep = 2e-4  # rad/s, from t = 2 s: below the measured velocity's noise after its filter
    q_true = 0.3 + creep * np.clip(t - 2.0, 0.0, None)
    v, sigma, v_measured = _blend(q_true)
    moving = t > 2.25  # a quarter second in: the positions have moved 50 steps
    assert np.mean(v[moving] > 3 * sigma[0]) > 0.95
    # the measured velocity, against its own noise after the filter: mostly within it
    measured_noise = DQ_NOISE * np.sqrt(filter_noise_gain(CUTOFF, FS))
    assert np.mean(v_measured[moving] > 3 * measured_noise) < 0.2
    resting = t < 1.75
    np.testing.assert_allclose(v[resting], 0.0, atol=3 * sigma[0])


def test_a_stop_is_not_read_as_a_reversal():
    t = np.arange(0.0, 3.0, 1.0 / FS)
    q_true = 0.3 + 0.0213 * np.clip(t, None, 1.5)  # 0.0213 rad/s (106.5 steps a sample), holds
    v, sigma, v_measured = _blend(q_true)
    after = t > 1.5
    # the positions' slope never turns negative after a stop; the low-passed velocity rings
    assert v[after].min() > -3 * sigma[0]
    assert np.all(v[t > 1.75] == pytest.approx(0.0, abs=3 * sigma[0]))
    assert v_measured[after].min() < -1e-3


def test_a_joint_that_holds_still_throughout_reads_zero_with_a_positive_noise():
    q = np.full((400, 1), 0.25)
    rng = np.random.default_rng(11)
    v_measured = _lowpass(DQ_NOISE * rng.standard_normal(q.shape), CUTOFF, FS)
    v_noise = np.array([DQ_NOISE * np.sqrt(filter_noise_gain(CUTOFF, FS))])
    v, sigma = friction_velocity(q, q, np.zeros(1), v_measured, v_noise, CUTOFF, FS)
    np.testing.assert_allclose(v, 0.0, atol=1e-15)
    assert sigma[0] > 0.0 and sigma[0] < 1e-9
    assert resolution(q)[0] == 0.0 and MIN_POSITION_NOISE_RAD > 0.0


def test_coarse_positions_leave_the_measured_velocity_in_charge():
    t = np.arange(0.0, 4.0, 1.0 / FS)
    q_true = 0.5 * np.sin(0.5 * t)
    rng = np.random.default_rng(5)
    q = (q_true + 1e-3 * rng.standard_normal(t.size))[:, None]  # a noisy position reading
    v_measured = np.gradient(q_true, 1.0 / FS)[:, None]
    v_noise = np.array([1e-4])
    v, sigma = friction_velocity(q, q, np.array([1e-3]), v_measured, v_noise, CUTOFF, FS)
    assert sigma[0] < v_noise[0]
    np.testing.assert_allclose(v[:, 0], v_measured[:, 0], atol=5 * v_noise[0])


def test_the_slope_of_a_line_is_its_rate_to_the_ends():
    x = 0.7 - 0.003 * np.arange(50) / FS
    np.testing.assert_allclose(slope(x, 6, FS), -0.003, rtol=1e-9)
    # a stretch shorter than the window (predict answers stretches from 28 rows)
    np.testing.assert_allclose(slope(x[:9], 30, FS), -0.003, rtol=1e-9)


def test_the_encoder_step_is_read_from_the_positions_and_not_from_their_rounding():
    t = np.arange(0.0, 2.0, 1.0 / FS)
    step = STEP_RAD * np.pi / 3  # not a round decimal: its multiples round when written
    q = np.round((0.3 + 0.0213 * t + 0.05 * np.sin(t)) / step) * step
    q_written = np.array([float(f"{v:.12g}") for v in q])  # a CSV's 12 significant digits
    assert resolution(q_written[:, None])[0] == pytest.approx(step, rel=1e-4)


def test_a_coarse_encoder_read_from_a_file_gives_an_honest_noise():
    """Regular stamps at 1 kHz, 4.2e-6 rad steps written to 12 significant digits, a crawl of
    at most 1e-3 rad/s (a step every 4 ms), a velocity reading of 1.5e-4 rad/s noise: the
    noise the blend reports covers the error it has, and it is no worse than the reading."""
    fs, cutoff, step = 1000.0, 40.0, 4e-6 * np.pi / 3  # not a round decimal
    t = np.arange(0.0, 3.0, 1.0 / fs)
    q_true = 0.2 + 5e-4 * np.sin(2 * np.pi * 0.3 * t)  # 1e-3 rad/s at most: a step per 4 ms
    q = np.array([float(f"{v:.12g}") for v in np.round(q_true / step) * step])[:, None]
    rng = np.random.default_rng(2)
    dq_true = np.gradient(q_true, 1.0 / fs)
    v_measured = _lowpass((dq_true + 1.5e-4 * rng.standard_normal(t.size))[:, None], cutoff, fs)
    v_noise = np.array([1.5e-4 * np.sqrt(filter_noise_gain(cutoff, fs))])
    v, sigma = friction_velocity(q, q, np.zeros(1), v_measured, v_noise, cutoff, fs)
    inner = slice(100, -100)
    err = (v[:, 0] - dq_true)[inner]
    assert np.std(err) <= 1.5 * sigma[0]  # the noise it reports is the noise it has
    assert np.std(err) <= 1.1 * np.std((v_measured[:, 0] - dq_true)[inner])
