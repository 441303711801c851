"""Friction models eq. (14) and eq. (15) (our physically sound reading) and their linear bases."""

from __future__ import annotations

import numpy as np
import pytest

from control.model.friction import (
    EQ14_PARAM_NAMES,
    EQ15_PARAM_NAMES,
    FourierFrictionParams,
    FrictionParams,
    eq14_basis,
    eq15_basis,
    friction_eq14,
    friction_eq15,
    smooth_sign,
)

GEAR_RATIOS = (147.0, 153.0, 153.0, 76.0, 80.0, 50.0)


def _eq15_params(rng: np.random.Generator, gear_ratio: float) -> FrictionParams:
    return FrictionParams(
        tau_s_nm=rng.uniform(5, 20),
        tau_c_nm=rng.uniform(10, 40),
        f1_nm=rng.normal(0, 2),
        f2_nm=rng.normal(0, 2),
        f3_nm=rng.normal(0, 2),
        f4_nm=rng.normal(0, 2),
        f5_nm=rng.normal(0, 2),
        f6_nm=rng.normal(0, 2),
        tau_v1_nm_s_per_rad=rng.uniform(10, 50),
        tau_v2_nm_s2_per_rad2=rng.uniform(0, 10),
        q_e_rad_s=rng.uniform(0.005, 0.05),
        gear_ratio=gear_ratio,
    )


def _eq14_params(rng: np.random.Generator) -> FourierFrictionParams:
    return FourierFrictionParams(
        f1_nm=rng.normal(0, 2),
        f2_nm=rng.normal(0, 2),
        f3_nm=rng.normal(0, 2),
        f4_nm=rng.normal(0, 2),
        f_c_nm=rng.uniform(10, 40),
        f_s_nm=rng.uniform(5, 20),
        f_v_nm_s_per_rad=rng.uniform(10, 50),
        q_e_rad_s=rng.uniform(0.005, 0.05),
    )


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(15)


@pytest.fixture
def params15(rng) -> list[FrictionParams]:
    return [_eq15_params(rng, r) for r in GEAR_RATIOS]


@pytest.fixture
def samples(rng) -> tuple[np.ndarray, np.ndarray]:
    q = rng.uniform(-2.0, 2.0, size=(500, 6))
    dq = rng.uniform(-2.0, 2.0, size=(500, 6))
    return q, dq


def test_smooth_sign_is_two_sigmoids_minus_one():
    dq = np.linspace(-1, 1, 101)
    q_e = 0.02
    sigmoid = 1.0 / (1.0 + np.exp(-dq / q_e))  # eq. (16)
    np.testing.assert_allclose(smooth_sign(dq, q_e), 2.0 * sigmoid - 1.0, atol=1e-12)


def test_eq15_is_odd_in_velocity(params15, samples):
    q, dq = samples
    np.testing.assert_allclose(
        friction_eq15(q, -dq, params15), -friction_eq15(q, dq, params15), atol=1e-12
    )


def test_eq15_is_zero_and_continuous_at_rest(params15, samples):
    q, _ = samples
    zero = np.zeros_like(q)
    np.testing.assert_array_equal(friction_eq15(q, zero, params15), 0.0)
    tiny = np.full_like(q, 1e-9)
    assert np.abs(friction_eq15(q, tiny, params15)).max() < 1e-4
    assert np.abs(friction_eq15(q, -tiny, params15)).max() < 1e-4


def test_eq15_stays_bounded_for_fast_negative_motion(params15):
    # The printed S⁻¹ = exp(-dq/q_e) would give ~exp(100) here; our reading decays instead.
    q = np.zeros(6)
    dq = np.full(6, -2.0)
    tau = friction_eq15(q, dq, params15)
    assert np.all(np.isfinite(tau))
    assert np.all(tau < 0)  # friction opposes the motion
    assert np.abs(tau).max() < 200.0


def test_eq15_opposes_motion_and_grows_with_speed(rng):
    p = FrictionParams(10, 20, 0, 0, 0, 0, 0, 0, 30, 5, 0.01, 100)
    dq = np.array([0.05, 0.2, 1.0, 3.0])
    tau = friction_eq15(np.zeros((4, 1)), dq[:, None], [p])[:, 0]
    assert np.all(tau > 0)
    assert np.all(np.diff(tau) > 0)
    # Far above q_e: Coulomb + viscous, the static part has decayed.
    assert tau[-1] == pytest.approx(20 + 30 * 3.0 + 5 * 9.0, rel=1e-9)


def test_eq15_basis_times_parameters_matches_the_model(params15, samples):
    q, dq = samples
    tau = friction_eq15(q, dq, params15)
    for j, p in enumerate(params15):
        basis = eq15_basis(q[:, j], dq[:, j], p.q_e_rad_s, p.gear_ratio)
        assert basis.shape == (q.shape[0], len(EQ15_PARAM_NAMES))
        np.testing.assert_allclose(basis @ p.linear_parameters(), tau[:, j], atol=1e-10)


def test_eq15_single_sample_matches_batched_rows(params15, samples):
    q, dq = samples
    batched = friction_eq15(q, dq, params15)
    for k in (0, 17, 499):
        np.testing.assert_allclose(friction_eq15(q[k], dq[k], params15), batched[k])


def test_eq15_parameters_round_trip_and_least_squares_recovery(rng):
    # R = 3 keeps the sin/cos(q/R), (2q/R) and q columns apart; with a real gear ratio
    # (R ≈ 150) cos(q/R) ≈ 1 and the f2, f4 columns nearly repeat the Coulomb column.
    truth = _eq15_params(rng, 3.0)
    assert FrictionParams.from_linear(truth.linear_parameters(), truth.q_e_rad_s, 3.0) == truth
    q = rng.uniform(-6.0, 6.0, 4000)
    dq = rng.uniform(-1.5, 1.5, 4000)
    basis = eq15_basis(q, dq, truth.q_e_rad_s, 3.0)
    tau = friction_eq15(q[:, None], dq[:, None], [truth])[:, 0]
    theta, *_ = np.linalg.lstsq(basis, tau, rcond=None)
    np.testing.assert_allclose(theta, truth.linear_parameters(), rtol=1e-6, atol=1e-6)


def test_eq15_refuses_mismatched_shapes(params15):
    with pytest.raises(ValueError):
        friction_eq15(np.zeros(5), np.zeros(5), params15)
    with pytest.raises(ValueError):
        friction_eq15(np.zeros(6), np.zeros((2, 6)), params15)
    with pytest.raises(ValueError):
        FrictionParams(1, 1, 0, 0, 0, 0, 0, 0, 1, 0, q_e_rad_s=0.0, gear_ratio=100)


def test_eq14_basis_times_parameters_matches_the_model(rng, samples):
    q, dq = samples
    params = [_eq14_params(rng) for _ in range(6)]
    tau = friction_eq14(q, dq, params)
    for j, p in enumerate(params):
        basis = eq14_basis(q[:, j], dq[:, j], p.q_e_rad_s)
        assert basis.shape == (q.shape[0], len(EQ14_PARAM_NAMES))
        np.testing.assert_allclose(basis @ p.linear_parameters(), tau[:, j], atol=1e-10)


def test_eq14_direction_dependent_part_is_odd_and_bounded(rng, samples):
    q, dq = samples
    params = [_eq14_params(rng) for _ in range(6)]
    even = 0.5 * (friction_eq14(q, dq, params) + friction_eq14(q, -dq, params))
    odd = 0.5 * (friction_eq14(q, dq, params) - friction_eq14(q, -dq, params))
    fourier = friction_eq14(q, np.zeros_like(dq), params)  # sgn(0) = 0: only the Fourier terms
    np.testing.assert_allclose(even, fourier, atol=1e-10)
    assert np.all(odd * dq >= 0)  # Coulomb, static and viscous terms oppose motion
    assert np.all(np.isfinite(friction_eq14(q, np.full_like(dq, -5.0), params)))
