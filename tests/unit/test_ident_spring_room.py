"""Rule (vii) bounds a spring by its joint's torque room
(:func:`control.identification.effect_rules.implausible`,
:attr:`control.identification.envelope.Envelope.torque_room_nm`): the largest torque the joint's
channel read plus the largest its URDF rigid body asks of it.

A held-out hard draw (seed 157) had a gear ripple of 52 N·m at 10 cycles per revolution on a
joint moving over 0.9 rad, whose torque stays under 1,640 N·m; the search named it a spring of
4e5 N·m/rad, whose torque over that range reaches 2e5 N·m, against the gravity columns.
"""

from __future__ import annotations

import numpy as np
import pytest

from control.identification.effect_rules import SPRING_TORQUE_FACTOR, implausible
from control.identification.envelope import Envelope
from control.identification.terms import EffectTerm

SPRING = EffectTerm("spring", (0,))
#: the joint's training range [rad] and torque room [N·m] (measured 1,640 + URDF 1,300)
Q_MIN, Q_MAX, ROOM = -0.886, 0.033, 2940.0


def _envelope(room: float | None) -> Envelope:
    q = np.array([[Q_MIN], [Q_MAX]])
    return Envelope.of(q, np.zeros_like(q), None if room is None else np.array([room]))


def _coef(k: float, q0: float) -> np.ndarray:
    """The spring's coefficients on its columns ``q`` and ``1``: torque ``k (q - q0)``."""
    return np.array([k, -k * q0])


def test_a_spring_far_stronger_than_the_joint_and_its_gravity_is_refused():
    why = implausible(SPRING, _coef(4.05e5, -0.487), _envelope(ROOM))
    assert "more than" in why and "N·m over the joint's range" in why


def test_a_balancer_carrying_the_whole_gravity_the_urdf_gives_is_kept():
    # its torque reaches the room's URDF part (1,300 N·m) at the far end of the range
    k = 1300.0 / (Q_MAX - Q_MIN)
    assert implausible(SPRING, _coef(k, Q_MIN), _envelope(ROOM)) == ""


@pytest.mark.parametrize("share", [0.9, 1.1])
def test_the_bound_sits_at_the_factor_times_the_room(share):
    k = share * SPRING_TORQUE_FACTOR * ROOM / (Q_MAX - Q_MIN)
    why = implausible(SPRING, _coef(k, Q_MIN), _envelope(ROOM))
    assert (why == "") == (share < 1.0), why


def test_without_a_known_room_only_the_other_parts_of_the_rule_apply():
    assert implausible(SPRING, _coef(4.05e5, -0.487), _envelope(None)) == ""
    # the room does not stand in for the rest angle's or the sign's test
    assert "far outside" in implausible(SPRING, _coef(1.0, 5.0), _envelope(ROOM))
    assert "pushing away" in implausible(SPRING, _coef(-1.0, -0.4), _envelope(ROOM))


def test_the_room_is_not_written_with_the_model():
    # a model read back from its file judges no effect: the room stays the analysis's own
    doc = _envelope(ROOM).to_json()
    assert "torque_room_nm" not in str(doc)
    assert Envelope.from_json(doc).torque_room_nm is None
