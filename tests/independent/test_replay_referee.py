"""The replay referee's own arithmetic (tests/independent/replay.py): which rows it scores."""

from __future__ import annotations

import numpy as np

from .replay import (
    MIN_SPEED_RAD_S,
    SLIDE_WINDOW_S,
    replay_rows,
    sliding_rows,
    verdict,
)


def test_a_joint_is_scored_only_where_it_slides_one_way_through_the_window():
    dt = 0.008
    t = np.arange(0.0, 2.0, dt)
    # joint 1: +0.05 rad/s, a reversal at 1 s; joint 2: at rest; joint 3: creeping below the bar
    dq = np.column_stack([
        np.where(t < 1.0, 0.05, -0.05),
        np.zeros_like(t),
        np.full_like(t, 0.5 * MIN_SPEED_RAD_S),
    ])  # fmt: skip
    rows = sliding_rows(t, dq)
    assert not rows[:, 1].any() and not rows[:, 2].any()
    near = np.abs(t - 1.0) < SLIDE_WINDOW_S / 2 - dt
    assert not rows[near, 0].any()  # the reversal's window holds both signs
    far = (np.abs(t - 1.0) > SLIDE_WINDOW_S / 2 + dt) & (t > SLIDE_WINDOW_S) & (t < 1.9)
    assert rows[far, 0].all()


def test_the_replay_is_the_last_stretch_in_external_control():
    state = np.array([0, 2, 2, 2, 0, 0, 2, 2, 0, 2, 2, 2, 2, 0])
    np.testing.assert_array_equal(replay_rows({"ctrl_state": state}), [9, 10, 11, 12])


def test_the_bound_is_twice_the_heldout_error_and_half_a_newton_metre_on_j1_to_j3():
    v = verdict([2.4, 1.0, 0.9, 99.0], [1.0, 0.2, 0.3, 0.1])
    assert v["pass_per_joint"] == [True, False, True] and not v["pass"]
    assert v["bound_nm"][:3] == [2.5, 0.9, 1.1]


def test_a_joint_the_replay_left_at_rest_is_neither_passed_nor_failed():
    v = verdict([9.0, 1.0, 1.0], [1.0, 1.0, 1.0], rows=[20, 500, 500])
    assert v["pass_per_joint"] == [None, True, True] and v["pass"]
    assert not verdict([9.0, 1.0, 1.0], [1.0, 1.0, 1.0], rows=[0, 0, 0])["pass"]


def test_a_joint_at_the_plants_own_floor_passes_where_the_heldout_bound_is_too_tight():
    # replay 6.0 against held-out 1.0 (bound 2.5): the plant's own torque misses by 5.5 on
    # the same states, the model by 6.0 (≤ 1.25 × 5.5): at the floor; 7.0 is not
    v = verdict([6.0, 6.0, 1.0], [1.0, 1.0, 1.0], [500] * 3, [6.0, 7.0, 1.0], [5.5, 5.5, 1.0])
    assert v["pass_per_joint"] == [True, False, True]
