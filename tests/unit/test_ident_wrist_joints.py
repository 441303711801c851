"""Wrist couplings are looked for among the wrist's joints
(:func:`control.identification.effect_candidates.wrist_start`): those after the three that place
the wrist (base, shoulder, elbow, each on its own motor and gear train), at most the last three;
the last two of a shorter arm. A five-axis arm's wrist is joints 4 and 5, not its elbow (hard
world draw 221, no effect in the data: a coupling of joint 3 from joint 4 of 0.098 was named)."""

from __future__ import annotations

from control.identification.effect_candidates import wrist_start


def test_the_wrist_follows_the_three_joints_that_place_it():
    wrists = {n: list(range(wrist_start(n), n)) for n in range(2, 8)}
    assert wrists == {
        2: [0, 1],
        3: [1, 2],
        4: [2, 3],
        5: [3, 4],  # an industrial five-axis arm: pitch and roll behind the elbow
        6: [3, 4, 5],
        7: [4, 5, 6],  # a redundant arm (Panda): the last three
    }
