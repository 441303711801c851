"""The guard's fold schemes (:mod:`control.identification.folds`): mixed in the shares of test
rows that lie as far from the training rows as each scheme's held-out rows from their fit,
judged on the test run's inputs, never its torques."""

from __future__ import annotations

import numpy as np

from control.identification.folds import (
    CONTIGUOUS,
    IN_SAMPLE,
    INTERLEAVED,
    gcv_factor,
    interleaved_folds,
    plan_folds,
)

RATE_HZ = 200.0


def _trajectory(t: np.ndarray, scale: float = 1.0, phase: float = 0.0) -> tuple:
    w = 2 * np.pi * np.array([0.011, 0.023, 0.037])  # no period within the runs
    q = scale * np.column_stack([np.sin(wj * t + phase + j) for j, wj in enumerate(w)])
    dq = scale * np.column_stack([wj * np.cos(wj * t + phase + j) for j, wj in enumerate(w)])
    return q, dq


def test_interleaved_folds_partition_the_rows_in_blocks():
    folds = interleaved_folds(23, 3, 4)
    rows = np.sort(np.concatenate(folds))
    np.testing.assert_array_equal(rows, np.arange(23))
    np.testing.assert_array_equal(folds[0], [0, 1, 2, 3, 12, 13, 14, 15])
    np.testing.assert_array_equal(folds[2], [8, 9, 10, 11, 20, 21, 22])


def test_gcv_factor():
    np.testing.assert_allclose(gcv_factor(0.0, np.array([10.0])), [1.0])
    np.testing.assert_allclose(gcv_factor(50.0, np.array([100.0, 1000.0])), [4.0, 1 / 0.95**2])
    assert np.isinf(gcv_factor(20.0, np.array([10.0]))[0])


def test_a_test_retracing_the_training_run_is_judged_in_sample():
    rng = np.random.default_rng(1)
    t = np.arange(0, 40, 1 / RATE_HZ)
    q, dq = _trajectory(t)
    # the same trajectory again (every row of the test near a training row), new noise
    m = t.size // 3
    qt = q[:m] + 1e-5 * rng.standard_normal((m, 3))
    dqt = dq[:m] + 1e-5 * rng.standard_normal((m, 3))
    plan = plan_folds(q, dq, RATE_HZ, qt, dqt, 5)
    assert [s.name for s in plan.schemes] == [IN_SAMPLE]
    (scheme,) = plan.schemes
    assert scheme.in_sample and scheme.share == 1.0 and scheme.folds == [slice(0, t.size)]
    assert not plan.extrapolates and plan.beyond_share == 0.0
    assert plan.candidates[0].name == CONTIGUOUS


def test_a_test_outside_the_training_envelope_is_judged_on_contiguous_folds():
    t = np.arange(0, 40, 1 / RATE_HZ)
    q, dq = _trajectory(t)
    qt, dqt = _trajectory(t[:2000], scale=1.6, phase=1.0)
    plan = plan_folds(q, dq, RATE_HZ, qt, dqt, 5)
    assert [s.name for s in plan.schemes] == [CONTIGUOUS]
    assert plan.extrapolates and plan.beyond_share > 0.5
    assert plan.to_json()["schemes"][0]["share"] == 1.0


def test_a_test_half_on_the_training_path_and_half_off_it_mixes_schemes():
    t = np.arange(0, 40, 1 / RATE_HZ)
    q, dq = _trajectory(t)
    q_off, dq_off = _trajectory(t[:1000], scale=1.6, phase=1.0)
    plan = plan_folds(
        q, dq, RATE_HZ, np.vstack([q[:1000], q_off]), np.vstack([dq[:1000], dq_off]), 5
    )
    shares = {s.name: s.share for s in plan.schemes}
    assert shares.keys() == {CONTIGUOUS, IN_SAMPLE}
    assert abs(shares[CONTIGUOUS] - 0.5) < 0.05 and abs(sum(shares.values()) - 1.0) < 1e-12


def test_candidate_distances_shrink_with_the_blocks():
    """Shorter interleaved blocks hold out rows nearer the rows their fit sees; the in-sample
    neighbour is nearest."""
    t = np.arange(0, 60, 1 / RATE_HZ)
    q, dq = _trajectory(t)
    plan = plan_folds(q, dq, RATE_HZ, q[::7] + 0.05, dq[::7], 5)
    d = [c.median_distance for c in plan.candidates]
    kinds = [c.name for c in plan.candidates]
    assert kinds[0] == CONTIGUOUS and kinds[-1] == IN_SAMPLE and INTERLEAVED in kinds
    assert d == sorted(d, reverse=True)
    blocks = [c.block_s for c in plan.candidates if c.name == INTERLEAVED]
    assert min(blocks) >= 0.5 and blocks == sorted(blocks, reverse=True)
    assert abs(sum(c.share for c in plan.candidates) - 1.0) < 1e-12
    assert all(c.share == 0.0 or c.share >= 0.1 for c in plan.candidates)


def test_a_still_joint_is_left_out_of_the_distance():
    t = np.arange(0, 20, 1 / RATE_HZ)
    q, dq = _trajectory(t)
    q[:, 2] = 0.5  # never moved: zero spread
    dq[:, 2] = 0.0
    plan = plan_folds(q, dq, RATE_HZ, q[:500].copy(), dq[:500].copy(), 5)
    assert np.isfinite(plan.test_median) and [s.name for s in plan.schemes] == [IN_SAMPLE]
