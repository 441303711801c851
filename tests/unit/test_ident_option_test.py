"""The sign test that takes a friction option (memory, a Gaussian Stribeck rise) where it holds
(control/identification/option_test.py), and the held-out prediction it reads (lsq.cv_joint)."""

from __future__ import annotations

import numpy as np
import pytest

from control.identification import option_test
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.option_test import (
    ALPHA,
    changed_rows,
    option_holds,
    sign_flip_p,
    stretches,
)


def test_stretches_are_the_maximal_runs_of_true_rows() -> None:
    rows = np.array([0, 1, 1, 0, 0, 1, 0, 1, 1, 1], dtype=bool)
    assert stretches(rows) == [slice(1, 3), slice(5, 6), slice(7, 10)]
    assert stretches(np.zeros(4, dtype=bool)) == []
    assert stretches(np.ones(3, dtype=bool)) == [slice(0, 3)]


def test_the_randomization_test_weighs_magnitudes_and_is_repeatable() -> None:
    # a few large gains among many noise-level losses: the sum leans negative far beyond
    # what random signs give, though most stretches are losses (a sign test would refuse)
    rng = np.random.default_rng(4)
    mixed = np.concatenate([np.full(8, -10.0), rng.uniform(0.01, 0.1, size=60)])
    assert sign_flip_p(mixed) < 0.01
    # one large loss beside the gains: not significant
    assert sign_flip_p(np.array([-1.0, -1.0, -1.0, 5.0])) > 0.5
    assert sign_flip_p(np.zeros(4)) == 1.0
    # every difference negative, m = 5: the exact tail is 1/32; 2,000 draws estimate it
    # within about four binomial standard errors (sqrt(p(1-p)/2000) = 0.0039)
    assert sign_flip_p(-np.arange(1.0, 6.0)) == pytest.approx(1 / 32, abs=0.016)
    d = rng.normal(size=40)
    assert sign_flip_p(d) == sign_flip_p(d)


def test_the_randomization_test_is_as_exact_as_its_draws_on_a_known_null() -> None:
    # ten stretches of equal size: all ten lost by the plain law has probability 1/1024 under
    # random signs, eight of ten (a sum of -6 or less) 56/1024
    p = option_test.sign_flip_p(-np.ones(10), draws=20_000)
    assert p == pytest.approx(1 / 1024, abs=0.001)
    p = option_test.sign_flip_p(np.array([-1.0] * 8 + [1.0] * 2), draws=20_000)
    assert p == pytest.approx(56 / 1024, abs=0.006)


def test_changed_rows_are_where_a_shared_column_moves_or_a_new_one_is_not_zero() -> None:
    t = np.linspace(0.0, 1.0, 200)
    plain = np.column_stack([np.sign(np.sin(8 * t)), t])
    same = plain.copy()
    assert not changed_rows(plain, same).any()
    memory = plain.copy()
    memory[50:60, 0] = 0.3
    assert np.flatnonzero(changed_rows(plain, memory)).tolist() == list(range(50, 60))
    rise = np.column_stack([plain, np.where((t > 0.2) & (t < 0.25), 1.0, 0.0)])
    assert changed_rows(plain, rise).sum() == int(((t > 0.2) & (t < 0.25)).sum())
    with pytest.raises(ValueError, match="rows"):
        changed_rows(plain, plain[:-1])


def _trial(rng: np.random.Generator, better: float, events: int = 30) -> tuple:
    """Targets and two predictions over ``events`` stretches of 20 rows apart from each other;
    on each stretch the option's prediction is the target plus noise, the plain one is off by
    ``better`` more (0: the two are as good)."""
    n = events * 40
    y = rng.normal(size=n)
    changed = np.zeros(n, dtype=bool)
    for e in range(events):
        changed[e * 40 : e * 40 + 20] = True
    without = y + rng.normal(size=n) + better * changed
    with_option = y + rng.normal(size=n)
    return y, without, with_option, changed


def test_an_option_that_lowers_the_error_at_most_reversals_holds() -> None:
    rng = np.random.default_rng(0)
    y, without, with_option, changed = _trial(rng, better=1.0)
    holds, wins, trials = option_holds(y, without, with_option, changed, values_tried=6)
    assert holds and trials == 30 and wins >= 25


def test_an_option_as_good_as_the_plain_law_is_taken_at_most_at_the_test_level() -> None:
    # 400 draws of two laws as good as each other: the share accepted is the test's false
    # acceptance rate, ALPHA over the values tried (here 1: 5 %); 400 draws put the 95 % upper
    # binomial bound of a 5 % rate at about 7.5 %
    rng = np.random.default_rng(1)
    accepted = sum(option_holds(*_trial(rng, better=0.0), values_tried=1)[0] for _ in range(400))
    assert accepted / 400 <= ALPHA * 1.5


def test_rows_outside_the_mask_are_not_trials() -> None:
    rng = np.random.default_rng(2)
    y, without, with_option, changed = _trial(rng, better=1.0)
    mask = np.zeros_like(y)
    mask[: 10 * 40] = 1.0
    _, _, trials = option_holds(y, without, with_option, changed, 6, mask)
    assert trials == 10


def test_cv_joint_is_the_fold_errors_and_the_held_out_prediction() -> None:
    rng = np.random.default_rng(3)
    t_rows, n = 300, 2
    x = {j: rng.normal(size=(t_rows, 3)) for j in range(n)}
    y = np.column_stack([x[j] @ np.array([1.0, -2.0, 0.5]) for j in range(n)])
    y += 0.1 * rng.normal(size=y.shape)
    ls = BlockLS(y, contiguous_folds(t_rows, 5))
    ls.add("g", x)
    w = np.ones(n)
    folds, pred = ls.cv_joint(["g"], w, 1)
    np.testing.assert_allclose(folds, ls.cv_fold_sse(["g"], w))
    np.testing.assert_allclose(pred, ls.cv_predict(["g"], w)[:, 1])
