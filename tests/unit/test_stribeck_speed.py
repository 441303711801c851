"""control/stribeck_speed.py: the speed where a model's friction stops falling, on friction
curves written out here (a smooth sign, a Stribeck fall, a viscous rise)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from control.stribeck_speed import SEARCH_RAD_S, stribeck_speeds

#: the search grid's ratio from one speed to the next: a found speed is exact to it
STEP = SEARCH_RAD_S[1] / SEARCH_RAD_S[0]


class Curves:
    """A model whose friction per joint is ``laws[j](dq)``, the same at every position."""

    def __init__(self, *laws):
        self.n = len(laws)
        self.laws = laws
        self.desc = SimpleNamespace(cylinders=(None, None))

    def cycle_torques_nm(self, q, dq, p_bar):
        assert len(p_bar) == 2 and len(q) == self.n
        return [0.0] * self.n, [law(v) for law, v in zip(self.laws, dq, strict=True)]


def eq15(tau_s, tau_c, q_e, viscous=0.0, width=1e-4):
    """Friction of eq. (15)'s form: the Stribeck fall and the smooth sign's rise."""
    return lambda v: (
        (tau_s * math.exp(-abs(v) / q_e) + tau_c) * math.tanh(v / (2 * width)) + (viscous * v)
    )


def test_a_stribeck_fall_holds_up_to_where_it_is_within_the_model_error():
    # 20 N·m falling over q_e = 10 mrad/s: within 0.5 N·m of its least (20 e^-5 at the
    # search's end) at 10 ln(20 / (0.5 + 20 e^-5)) mrad/s
    model = Curves(eq15(20.0, 30.0, 0.01), eq15(20.0, 30.0, 0.005))
    speeds = stribeck_speeds(model, np.zeros(2), np.array([0.5, 0.5]))
    want = [q_e * math.log(20.0 / (0.5 + 20.0 * math.exp(-0.05 / q_e))) for q_e in (0.01, 0.005)]
    assert want[0] / STEP <= speeds[0] <= want[0] * STEP
    assert want[1] / STEP <= speeds[1] <= want[1] * STEP
    assert speeds[1] < speeds[0]


def test_friction_that_only_grows_or_falls_within_the_error_holds_no_joint():
    model = Curves(eq15(0.0, 30.0, 0.01, viscous=50.0), eq15(0.4, 30.0, 0.01, viscous=5.0),
                   eq15(0.0, 0.0, 0.01))  # fmt: skip
    assert stribeck_speeds(model, np.zeros(3), np.array([0.5, 0.5, 0.5])).tolist() == [0, 0, 0]


def test_a_larger_error_takes_a_slower_speed_and_one_above_the_fall_none():
    model = Curves(eq15(20.0, 30.0, 0.01))
    tight, loose, above = (stribeck_speeds(model, np.zeros(1), np.array([e]))[0]
                           for e in (0.1, 2.0, 25.0))  # fmt: skip
    assert tight > loose > 0.0 and above == 0.0


def test_a_viscous_rise_ends_the_fall_before_the_search_does():
    # with 300 N·m·s/rad the least friction is where 20/q_e e^(-v/q_e) = 300: 10 ln(6.7) mrad/s
    model = Curves(eq15(20.0, 30.0, 0.01, viscous=300.0))
    least = 0.01 * math.log(20.0 / (0.01 * 300.0))
    speed = stribeck_speeds(model, np.zeros(1), np.array([0.5]))[0]
    assert 0.0 < speed < least * STEP


def test_the_slower_direction_does_not_hide_the_faster_one():
    # a joint whose friction falls only when it turns one way (a one-sided Stribeck fall)
    one_way = eq15(20.0, 30.0, 0.01)
    model = Curves(lambda v: one_way(v) if v < 0 else eq15(0.0, 30.0, 0.01)(v))
    assert stribeck_speeds(model, np.zeros(1), np.array([0.5]))[0] > 0.02


def test_the_search_never_goes_past_the_fastest_hold_allowed():
    # a fall far slower than any hold: still 0.12 N·m between the last two speeds searched
    model = Curves(eq15(20.0, 30.0, 0.5))
    assert stribeck_speeds(model, np.zeros(1), np.array([1e-3]))[0] == SEARCH_RAD_S[-1]
