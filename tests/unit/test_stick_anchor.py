"""The admittance's stick anchor (control/rt/src/law/admittance/stick_anchor.rs): a resting
joint's share of its load reads as no hand, and a push that changes the estimate passes in full."""

from __future__ import annotations

import numpy as np
import pytest

from control._rt import STICK_ANCHOR_FOLLOW_S as FOLLOW_S
from control._rt import STICK_ANCHOR_SETTLE_S as SETTLE_S
from control._rt import StickAnchor

DT = 0.008
BAND = np.array([1.5])
REST, SLIDING = np.array([True]), np.array([False])


def settle(anchor: StickAnchor, tau: float, resting: np.ndarray, s: float):
    out = None
    for _ in range(int(s / DT)):
        out = anchor.hand(np.array([tau]), resting, BAND, DT)
    return out


def test_the_share_a_joint_stopped_with_reads_as_no_hand_however_large():
    a = StickAnchor(1, 5.0)
    # sliding with a 30 N·m estimate (the friction the model compensated), then it sticks
    # with that share in its friction: the estimate stays, and no hand is read
    settle(a, 30.0, SLIDING, 1.0)
    pushed, settled = settle(a, 30.0, REST, 2.0)
    assert settled[0] and abs(pushed[0]) < 1e-9


def test_a_push_that_breaks_the_joint_away_passes_in_full_at_once():
    a = StickAnchor(1, 5.0)
    settle(a, 30.0, SLIDING, 1.0)
    settle(a, 30.0, REST, 2.0)
    # the push slipped the joint: the vendor loop's reaction moves the estimate by 10 N·m
    out = a.hand(np.array([20.0]), REST, BAND, DT)
    assert np.asarray(out[0]) == pytest.approx(-10.0)
    # and it is not followed away while it is beyond the dead zone
    pushed, _ = settle(a, 20.0, REST, 3.0 * FOLLOW_S)
    assert pushed[0] == pytest.approx(-10.0, abs=1e-6)


def test_a_slow_drift_within_the_dead_zone_is_followed():
    a = StickAnchor(1, 5.0)
    settle(a, 5.0, REST, 1.0)
    pushed, _ = settle(a, 6.0, REST, 5.0 * FOLLOW_S)
    assert abs(pushed[0]) < 0.01


def test_a_joint_is_settled_only_after_it_has_rested_a_while_and_not_while_it_slides():
    a = StickAnchor(1, 5.0)
    _, settled = settle(a, 30.0, SLIDING, 1.0)
    assert not settled[0]
    _, settled = settle(a, 30.0, REST, 0.5 * SETTLE_S)
    assert not settled[0]
    _, settled = settle(a, 30.0, REST, SETTLE_S)
    assert settled[0]
    _, settled = a.hand(np.array([30.0]), SLIDING, BAND, DT)
    assert not settled[0]


def test_a_bad_size_or_filter_is_refused_by_name():
    with pytest.raises(ValueError, match="joints"):
        StickAnchor(0, 5.0)
    with pytest.raises(ValueError, match="filter"):
        StickAnchor(6, float("nan"))
