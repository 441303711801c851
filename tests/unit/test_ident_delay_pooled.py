"""A time delay is one shift of the whole measurement chain: its effect size is the held-out
error of all joints together (rule (i) of :mod:`control.identification.effect_rules`)."""

from __future__ import annotations

import numpy as np

from control.identification.effect_rules import NoiseFloor, Options, judge, pooled_gain
from control.identification.lsq import Evaluation, Solution
from control.identification.terms import EffectTerm


def _evaluation(cv_sse, rank: int) -> Evaluation:
    sse = np.asarray(cv_sse, dtype=float)
    return Evaluation(sse, sse, rank, np.full(sse.size, 10_000), Solution({}, rank))


NOISE = NoiseFloor(std_nm=np.full(4, 0.1), dof_nm2=np.full(4, 0.01))
WEIGHTS = np.full(4, 10.0)  # 1 / noise
DELAY = EffectTerm("time_delay", (0, 1, 2, 3), {"delay_s": 0.004})
PAYLOAD = EffectTerm("payload", (0, 1, 2, 3), {})


def test_a_shift_that_helps_one_joint_of_four_is_not_a_delay():
    current = _evaluation([100.0, 100.0, 100.0, 100.0], 40)
    # 20 % of one joint's sum of squares (10.6 % of its RMS), the others as they were
    new = _evaluation([80.0, 100.0, 100.0, 100.0], 40)
    assert pooled_gain(current, new, WEIGHTS) < 0.10
    v = judge(DELAY, current, new, WEIGHTS, NOISE, 1, Options(), 1)
    assert not v.accepted and v.improved == ()
    # the same gains on a payload, whose share differs per joint by the arm's geometry: taken
    assert judge(PAYLOAD, current, new, WEIGHTS, NOISE, 1, Options(), 0).improved == (0,)


def test_a_shift_that_helps_every_joint_is_a_delay():
    current = _evaluation([100.0, 100.0, 100.0, 100.0], 40)
    new = _evaluation([75.0, 78.0, 80.0, 79.0], 40)
    assert pooled_gain(current, new, WEIGHTS) > 0.10
    v = judge(DELAY, current, new, WEIGHTS, NOISE, 1, Options(), 1)
    assert v.accepted and v.improved == (0, 1, 2, 3)


def test_the_pooled_gain_weighs_each_joint_by_its_inverse_noise():
    current = _evaluation([1.0, 100.0], 4)
    new = _evaluation([0.0, 100.0], 4)
    # unweighted, the quiet joint's whole error is 1 % of the sum; weighted 100x, half of it
    assert pooled_gain(current, new, np.array([1.0, 1.0])) < 0.01
    assert 0.2 < pooled_gain(current, new, np.array([100.0, 10.0])) < 0.3
