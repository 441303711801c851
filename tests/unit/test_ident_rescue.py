"""Rule (vi) of the effect search (control/identification/effect_rules.py): below the margin, a
candidate is still taken where it lifts a joint that plain least squares beats, and plain least
squares beats a joint only by more than the measured noise could give."""

from __future__ import annotations

import numpy as np

from control.identification.effect_rules import NoiseFloor, Verdict, chi2_threshold, rescuing
from control.identification.lsq import Evaluation, Solution
from control.identification.terms import EffectTerm


def _evaluation(cv_sse: list[float], own_dof: float = 1.0) -> Evaluation:
    """Held-out SSE ``cv_sse`` of a model with ``own_dof`` effective parameters on each joint:
    its in-sample SSE lower by twice that many noise columns (noise dof 1 N²·m² below)."""
    cv = np.asarray(cv_sse, dtype=float)
    return Evaluation(cv - 2.0 * own_dof, cv, 3, np.full(2, 100), Solution({}, 3))


def _verdict(joint: int, cv_sse: list[float], current: Evaluation) -> Verdict:
    ev = _evaluation(cv_sse)
    rel = 1.0 - np.sqrt(ev.cv_sse / current.cv_sse)
    term = EffectTerm("spring", (joint,))
    return Verdict(term, ev, False, float(rel.max()), rel, (), 50.0, 20.0)


def test_a_lead_of_plain_least_squares_within_the_noise_rescues_nothing():
    noise = NoiseFloor(np.ones(2), np.ones(2))  # one column takes 1 N²·m² out of pure noise
    current = _evaluation([100.0, 100.0])
    # plain least squares ahead by 0.5 noise dof on joint 1 (noise) and by 50 on joint 2
    rival = np.array([99.5, 50.0])
    assert 0.5 < chi2_threshold(1, 2, 0.01) < 50.0
    lifts_1 = _verdict(0, [99.0, 100.0], current)
    lifts_2 = _verdict(1, [100.0, 49.0], current)
    taken = rescuing([lifts_1, lifts_2], current, rival, noise, 0.01)
    assert [v.term.joints for v in taken] == [(1,)]
    assert taken[0].improved == (1,) and taken[0].accepted


def test_a_lead_within_the_models_own_parameter_error_rescues_nothing():
    """The same lead of 20 noise dof: beyond what one parameter's error gives, within what 30
    give (a joint at its noise floor on which a shared rigid body and a friction law act)."""
    noise = NoiseFloor(np.ones(2), np.ones(2))
    rival = np.array([80.0, 100.0])
    assert chi2_threshold(1, 2, 0.01) < 20.0 < chi2_threshold(30, 2, 0.01)
    for own_dof, taken_joints in ((1.0, [(0,)]), (30.0, [])):
        current = _evaluation([100.0, 100.0], own_dof)
        lifts = _verdict(0, [79.0, 100.0], current)
        taken = rescuing([lifts], current, rival, noise, 0.01)
        assert [v.term.joints for v in taken] == taken_joints, own_dof
