"""The time shift of the delay effect (:func:`control.identification.signal_shift.shift_signal`) is
band-limited: exact on a smooth signal, and it keeps white noise's power at any fraction of a
sample (linear interpolation halves it at half a sample, which a delay search mistook for a
better fit: a -3.8 ms "delay" accepted on a 100 Hz run that had none)."""

from __future__ import annotations

import numpy as np
import pytest

from control.identification.signal_shift import shift_signal


@pytest.mark.parametrize("fraction", [0.25, 0.5, 0.9])
def test_shift_keeps_the_noise_power_at_any_fraction_of_a_sample(fraction):
    rate_hz = 100.0
    t = np.arange(50_000) / rate_hz
    noise = np.random.default_rng(3).standard_normal((t.size, 2))
    shifted = shift_signal(t, None, noise, fraction / rate_hz)
    assert np.std(shifted) == pytest.approx(np.std(noise), rel=0.01)
    linear = np.interp(t + fraction / rate_hz, t, noise[:, 0])
    # what linear interpolation would have done: average neighbours, take noise out
    expected = np.sqrt((1 - fraction) ** 2 + fraction**2) * np.std(noise[:, 0])
    assert np.std(linear) == pytest.approx(expected, rel=0.02)


def test_shift_is_exact_on_a_smooth_signal_and_per_segment():
    t = np.r_[np.arange(2000) / 200.0, 30.0 + np.arange(1500) / 200.0]
    segment = np.r_[np.zeros(2000, int), np.ones(1500, int)]

    def x(tt):
        return np.column_stack([np.sin(2 * np.pi * 0.7 * tt + 0.4) + 0.3 * tt, np.cos(1.3 * tt)])

    for delta in (0.0123, -0.051, 0.005):
        got = shift_signal(t, segment, x(t), delta)
        inner = np.r_[np.arange(20, 1980), 2000 + np.arange(20, 1480)]
        np.testing.assert_allclose(got[inner], x(t + delta)[inner], atol=2e-4)
    one = shift_signal(t, segment, np.sin(t), 0.01)
    assert one.shape == t.shape


def test_delay_refinement_finds_a_v_shaped_minimum_between_scan_points():
    """Near its optimum the error of a torque with friction steps grows like |δ - δ₀|: a
    parabola through the three best scan points misses δ₀, the bounded search does not."""
    from control.identification.effect_candidates import DELAY_TOLERANCE_S, _refine

    true = 0.0121

    def error_of(d: float) -> float:
        return abs(d - true) + 0.2 * (d - true) ** 2

    deltas = 0.005 * np.arange(-20, 21)
    errors = np.array([error_of(d) for d in deltas])
    assert abs(_refine(deltas, errors, error_of) - true) <= 2 * DELAY_TOLERANCE_S
    assert _refine(deltas, errors) == pytest.approx(0.01)  # the scan alone: its best point
