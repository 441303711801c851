"""Friction taken in expectation over whether a joint moves, given its velocity's measurement
noise (:meth:`control.identification.terms.Context.sample_mean`,
:func:`control.identification.friction_law.rest_probability`,
:func:`control.identification.preprocess.velocity_noise_std`).

A joint at rest reads its velocity noise; a friction sign taken of it flipped between ± the
Coulomb level from one sample to the next. On the hard world of issue 46 (teaching stretches
with rests in the held-out run) that alone left a resting joint 44 N·m RMS off (seed 28, J2,
noise floor 2.3 N·m), and plain least squares no better. Given a measured velocity v̂ with
noise σ the joint rests with probability expit(L - v̂²/2σ²) (no friction sign there), and
moves at v̂ otherwise: 0 at rest, the sign itself once |v̂| is a few σ. The prior log odds L
come from the motion's own velocities (:func:`rest_log_odds`): a motion that only crosses 0
gets L < 0 and keeps the friction's sign there, as the joint does (a fixed L = 8 counted
± 4 σ around each crossing of the declared world's multi-sines as rest and lost to plain
least squares by up to 6 % on a joint, seeds 23, 28, 36); a motion that dwells gets its share.
"""

from __future__ import annotations

import numpy as np
import pytest

from control.identification.friction_law import (
    REST_LOG_ODDS,
    rest_log_odds,
    rest_probability,
)
from control.identification.model import plain_friction_columns
from control.identification.preprocess import (
    _lowpass,
    filter_noise_gain,
    velocity_noise_std,
)
from control.identification.terms import Context

SIGMA = 2e-4  # rad/s


def _columns(dq: np.ndarray, noise: float | None, odds: float | None = None) -> np.ndarray:
    q = np.zeros((dq.size, 1))
    ctx = Context(
        q, dq[:, None], np.zeros_like(q), dq_noise=None if noise is None else [noise],
        rest_odds=None if odds is None else np.array([odds]),
    )  # fmt: skip
    return plain_friction_columns(ctx, 0)  # sgn dq, dq, 1


def test_the_coulomb_column_is_the_sign_weighed_by_the_chance_the_joint_moves():
    dq = np.array([-1.0, -6 * SIGMA, -SIGMA, 0.0, 0.5 * SIGMA, 4 * SIGMA, 1.0])
    cols = _columns(dq, SIGMA, REST_LOG_ODDS)  # L = 8: rest and motion equally likely
    moving = 1.0 - rest_probability(dq, SIGMA, REST_LOG_ODDS)
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


def _sweep(rest_share: float, rng: np.random.Generator, n: int = 40_000) -> np.ndarray:
    """A joint's true velocity: sine sweeps of 0.05 rad/s (250 σ) between rests taking
    ``rest_share`` of the time, 200 samples per piece."""
    pieces, rest = [], 0
    while sum(p.size for p in pieces) < n:
        if rng.random() < rest_share:
            pieces.append(np.zeros(200))
            rest += 200
        else:
            pieces.append(0.05 * np.sin(np.pi * np.arange(200) / 200) * rng.choice([-1, 1]))
    return np.concatenate(pieces)[:n]


@pytest.mark.parametrize("seed", range(5))
def test_a_motion_that_only_crosses_zero_keeps_its_friction_sign_there(seed):
    rng = np.random.default_rng(seed)
    t = np.arange(40_000) / 500.0
    true = 0.05 * np.sin(2 * np.pi * 0.3 * t) + 0.03 * np.sin(2 * np.pi * 0.7 * t + 1.0)
    dq = true + SIGMA * rng.standard_normal(t.size)
    odds = rest_log_odds(dq, SIGMA)
    # π is 0 up to the count's noise (a few per mille); the density of motion near 0 is about
    # 1 / (π · 0.08 rad/s) per rad/s, 2.5e-3 per σ: L = ln(π / (2.5 m)) is below 0
    assert odds < 0.0
    cols = _columns(dq, SIGMA)
    away = np.abs(true) > 2 * SIGMA  # the sign is known there to the noise's 2.3 %
    agree = np.mean(np.sign(cols[away, 0]) == np.sign(true[away]))
    assert agree > 0.97
    assert np.mean(np.abs(cols[away, 0])) > 0.9  # the sign's full level, not a rest's 0


@pytest.mark.parametrize("share", [0.2, 0.5, 0.8])
def test_a_motion_that_dwells_counts_its_rests_as_rests(share):
    rng = np.random.default_rng(11)
    true = _sweep(share, rng)
    dq = true + SIGMA * rng.standard_normal(true.size)
    odds = rest_log_odds(dq, SIGMA)
    assert odds > 0.0
    cols = _columns(dq, SIGMA)
    resting = true == 0.0
    # at rest: the noise alone; 95 % of it within ± 2 σ, where a positive L gives rest > 1/2
    assert np.sqrt(np.mean(cols[resting, 0] ** 2)) < 0.3
    fast = np.abs(true) > 10 * SIGMA
    np.testing.assert_allclose(cols[fast, 0], np.sign(true[fast]), atol=1e-6)


def test_without_noise_or_samples_the_prior_is_the_fixed_one():
    assert rest_log_odds(np.zeros(0), SIGMA) == REST_LOG_ODDS
    assert rest_log_odds(np.ones(10), 0.0) == REST_LOG_ODDS
    assert rest_log_odds(np.full(10, np.nan), SIGMA) == REST_LOG_ODDS


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
