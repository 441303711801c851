"""Friction columns of a jittered recording are mixed as its resampled torque was
(:func:`control.identification.resample.resample_mix`,
:meth:`control.identification.terms.Context.sample_mean`).

A recording whose time steps jitter is resampled onto a uniform grid by linear interpolation:
at a grid point between two recorded samples the torque is their weighted mean, so a friction
reversal between them is a blend of the two friction levels there, while a sign column
computed at the grid point alone jumps whole. The fit then widened the smooth sign to stand in
for the blend (hard world draw 178: 100 Hz with 13 % jitter, joint 5's sign 13.6 mrad/s wide
where the same files without their jitter chose 2 mrad/s, and 0.29 N·m held-out error between
2 and 20 mrad/s where the noise is 0.03).
"""

from __future__ import annotations

import numpy as np

from control.identification.datafile import Measurements
from control.identification.model import plain_friction_columns
from control.identification.preprocess import prepare
from control.identification.resample import resample_mix
from control.identification.terms import Context, FrictionTerm

RATE_HZ = 100.0
#: the time steps' relative jitter (uniform, ± this): draw 178's std of 13 %
JITTER = 0.23
COULOMB_NM, VISCOUS_NM_S = 1.0, 0.3


def _run(freq_hz: float, amplitude_rad: float, seconds: float = 60.0) -> Measurements:
    """One joint swinging at ``freq_hz`` (plus a slower harmonic), recorded at 100 Hz with
    jittered time steps; torque sharp Coulomb plus viscous friction at the recorded instants,
    no noise."""
    rng = np.random.default_rng(178)
    steps = (1.0 + rng.uniform(-JITTER, JITTER, round(seconds * RATE_HZ))) / RATE_HZ
    t = np.concatenate([[0.0], np.cumsum(steps)])
    w = 2 * np.pi * freq_hz
    q = amplitude_rad * (np.sin(w * t) + 0.3 * np.sin(0.37 * w * t + 1.0))
    dq = amplitude_rad * w * (np.cos(w * t) + 0.111 * np.cos(0.37 * w * t + 1.0))
    tau = COULOMB_NM * np.sign(dq) + VISCOUS_NM_S * dq
    return Measurements(t, q[:, None], dq[:, None], tau[:, None], None, source=f"{freq_hz}.csv")


def _context(m: Measurements, mixed: bool) -> tuple[Context, np.ndarray]:
    data = prepare(m, RATE_HZ, 20.0, 40.0)
    assert data.resample_mix is not None and np.any(data.resample_mix[:, 2] > 0.0)
    ctx = Context(
        data.q, data.dq, data.ddq, data.t, lowpass=data.lowpass,
        sample_hz=data.sample_hz, raw_hz=data.raw_hz,
        resample_mix=data.resample_mix if mixed else None,
    )  # fmt: skip
    return ctx, data.tau[:, 0]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_the_mix_is_linear_interpolations_own_weights():
    t = np.array([0.0, 0.012, 0.019, 0.031])
    grid = np.array([0.0, 0.01, 0.02, 0.03])
    mix = resample_mix(t, grid)
    values = np.array([1.0, -2.0, 5.0, 0.5])
    lo = np.array([0, 0, 2, 2])
    blended = (1.0 - mix[:, 2]) * values[lo] + mix[:, 2] * values[lo + 1]
    np.testing.assert_allclose(blended, np.interp(grid, t, values))
    np.testing.assert_allclose(mix[:, 0], t[lo] - grid)
    np.testing.assert_allclose(mix[:, 1], t[lo + 1] - grid)


def test_the_reversal_is_blended_as_in_the_resampled_torque():
    m = _run(0.3, 0.8)
    errors = {}
    for mixed in (True, False):
        ctx, tau = _context(m, mixed)
        cols = plain_friction_columns(ctx, 0)
        errors[mixed] = _rms(cols @ [COULOMB_NM, VISCOUS_NM_S, 0.0] - tau)
    # the true friction through the same chain: what is left is the acceleration's change
    # over the few milliseconds to each recorded sample, far below the unmixed column's blend
    assert errors[True] < 0.01 * COULOMB_NM
    assert errors[True] < 0.25 * errors[False]


def test_a_sharp_friction_fitted_on_a_fast_jittered_run_predicts_a_slow_one():
    """The smooth sign's width of the simple law (``tanh(dq / 2 q_e)``) chosen on the fast
    training run and its coefficients fitted there: on a run reversing at a third of the
    acceleration the error stays small, and the width chosen is the sharpest tried."""
    fast, slow = _run(0.45, 0.9), _run(0.15, 0.9)
    widths = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05)
    errors, chosen = {}, {}
    for mixed in (True, False):
        (c_fast, tau_fast), (c_slow, tau_slow) = (_context(r, mixed) for r in (fast, slow))
        best = (np.inf, 0.0, np.zeros(0))
        for width in widths:
            term = FrictionTerm(0, "simple", width, 1.0)
            a = term.columns(c_fast)[0]
            coef = np.linalg.lstsq(a, tau_fast, rcond=None)[0]
            sse = _rms(a @ coef - tau_fast)
            if sse < best[0]:
                best = (sse, width, coef)
        _, chosen[mixed], coef = best
        term = FrictionTerm(0, "simple", chosen[mixed], 1.0)
        errors[mixed] = _rms(term.columns(c_slow)[0] @ coef - tau_slow)
    # mixed, the fast run chooses the sharpest sign, as the recorded friction is; unmixed, a
    # wider one stands in for the blend (the test above: the mixed columns are the torque's to
    # 1e-5 of the Coulomb level; what is left here is the sharpest sign tried, tanh(dq / 1
    # mrad/s), against the true sign on the slow run's reversals)
    assert chosen[True] == widths[0] and chosen[False] > widths[0], chosen
    assert errors[True] < 0.5 * errors[False]
