"""Rows of a stuck joint neither fit nor score the model (preprocess.sliding_mask, lsq.BlockLS).

A geared joint below its breakaway torque does not move, and the torque it then carries is
whatever the servo wound up: no function of the motion. A fit that takes those rows in is
pulled towards them; one that leaves them out finds the sliding friction. A joint that only
passes through zero velocity (a reversal) has not stopped: those rows stay.
"""

from __future__ import annotations

import numpy as np
import pytest

from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.preprocess import Prepared, sliding_mask

RATE_HZ = 100.0


def prepared(dq: np.ndarray, segment: np.ndarray | None = None) -> Prepared:
    t = np.arange(dq.shape[0]) / RATE_HZ
    zeros = np.zeros_like(dq)
    return Prepared(
        t=t,
        q=zeros,
        dq=dq,
        ddq=zeros,
        tau=zeros,
        p=None,
        p_joints=(),
        segment=np.zeros(dq.shape[0], int) if segment is None else segment,
        sources=("x",),
        rate_hz=RATE_HZ,
    )


def test_stuck_rows_and_a_window_around_them_are_left_out_per_joint():
    dq = np.full((100, 2), 0.1)
    dq[50, 0] = 0.0  # joint 1 stuck for one sample; joint 2 never
    on = sliding_mask(prepared(dq), 2e-3, 0.05)  # ±5 samples
    assert on[:, 1].all()
    assert not on[45:56, 0].any()
    assert on[:45, 0].all() and on[56:, 0].all()


def test_the_window_does_not_reach_across_a_segment_boundary():
    dq = np.full((40, 1), 0.1)
    dq[19, 0] = 0.0
    segment = np.repeat([0, 1], 20)
    on = sliding_mask(prepared(dq, segment), 2e-3, 0.05)
    assert not on[14:20, 0].any()
    assert on[20:, 0].all(), "the next segment is another recording: untouched"


def test_a_segment_shorter_than_the_window_is_handled():
    dq = np.full((13, 1), 0.1)
    dq[11, 0] = 0.0  # the last segment: 3 rows, one stuck, a window of ±5 rows
    segment = np.repeat([0, 1], [10, 3])
    on = sliding_mask(prepared(dq, segment), 2e-3, 0.05)
    assert on[:10, 0].all() and not on[10:, 0].any()


def test_zero_stick_velocity_keeps_every_row():
    dq = np.zeros((10, 3))
    assert sliding_mask(prepared(dq), 0.0, 0.05).all()


def test_a_masked_fit_equals_the_fit_on_the_kept_rows():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(200, 2))
    y = x @ np.array([2.0, -1.0]) + rng.normal(0, 0.1, 200)
    keep = rng.uniform(size=200) > 0.3
    folds = contiguous_folds(200, 4)
    masked = BlockLS(y[:, None], folds, keep[:, None].astype(float))
    masked.add("a", {0: x})
    sub = BlockLS(y[keep][:, None], contiguous_folds(int(keep.sum()), 4))
    sub.add("a", {0: x[keep]})
    ev_m, ev_s = masked.evaluate(["a"], np.ones(1)), sub.evaluate(["a"], np.ones(1))
    np.testing.assert_allclose(ev_m.solution.coef["a"], ev_s.solution.coef["a"], rtol=1e-10)
    np.testing.assert_allclose(ev_m.fit_rms, ev_s.fit_rms, rtol=1e-10)
    assert ev_m.n_rows[0] == keep.sum()
    # predictions and targets stay whole: callers shift and subtract them
    assert masked.y.shape == (200, 1) and masked.predict(ev_m.solution).shape == (200, 1)
    np.testing.assert_array_equal(masked.y[:, 0], y)


def test_leaving_stuck_rows_out_recovers_the_sliding_friction():
    """Coulomb + viscous joint, fitted with a position column as a gravity or spring term
    would bring; where it is stuck the torque is the servo's wound-up value, the direction it
    last pushed, at the end of the stroke (as in a friction run's dwell). With those rows the
    position column takes them up; without, the fit finds the friction and no position term."""
    rng = np.random.default_rng(2)
    t = np.arange(3000) / RATE_HZ
    dq = 0.2 * np.sin(2 * np.pi * 0.2 * t)
    dq[np.abs(dq) < 0.03] = 0.0  # it sticks around every reversal
    coulomb, viscous = 40.0, 60.0
    tau = coulomb * np.sign(dq) + viscous * dq + rng.normal(0, 0.5, dq.size)
    stuck = dq == 0.0
    last = np.sign(np.maximum.accumulate(np.where(dq != 0, np.arange(dq.size), 0)))
    pushed = np.sign(dq[np.maximum.accumulate(np.where(dq != 0, np.arange(dq.size), 0))])
    tau[stuck] = 35.0 * (pushed * last)[stuck]  # wound-up, below breakaway
    q = np.cumsum(dq) / RATE_HZ
    cols = {0: np.column_stack([np.tanh(dq / 0.005), dq, q - q.mean()])}
    folds = contiguous_folds(dq.size, 5)
    whole = BlockLS(tau[:, None], folds)
    whole.add("f", cols)
    on = sliding_mask(prepared(dq[:, None]), 2e-3, 0.05)
    masked = BlockLS(tau[:, None], folds, on)
    masked.add("f", cols)
    fit_whole = whole.evaluate(["f"], np.ones(1)).solution.coef["f"]
    fit_masked = masked.evaluate(["f"], np.ones(1)).solution.coef["f"]
    assert fit_masked[:2] == pytest.approx([coulomb, viscous], rel=0.03)
    assert abs(fit_masked[2]) < 2.0  # N·m/rad: none
    assert abs(fit_whole[2]) > 20.0, fit_whole
