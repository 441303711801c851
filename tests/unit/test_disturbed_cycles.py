"""gateway/disturbed_cycles.py: a hold always disturbs the cycle it answered; a coast only when it
is not a single one the law's command followed (a run, a hold after it, an unrecorded side)."""

from __future__ import annotations

import numpy as np

from gateway.disturbed_cycles import disturbed_cycles
from gateway.message_factories import make_joint_state
from gateway.messages import FLAG_PREV_COAST, FLAG_PREV_HOLD, FLAG_SERVO_POWER, ControllerState

PERIOD_S = 0.008
N_JOINTS = 3


def _law_commands(cycles: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A teaching-like law: velocity commands that follow a slow hand motion with the law's
    own cycle-to-cycle jitter, positions integrated from them."""
    rng = np.random.default_rng(seed)
    t = PERIOD_S * np.arange(cycles)[:, None]
    dq = 0.3 * np.sin(2 * np.pi * 0.4 * t + np.arange(N_JOINTS)) + rng.normal(
        0, 2e-3, (cycles, N_JOINTS)
    )
    q = np.cumsum(PERIOD_S * dq, axis=0)
    return q, dq


def _states(sent_q: np.ndarray, sent_dq: np.ndarray, answers: dict[int, int]) -> list:
    """The JointStates of cycles 1..len: state c + 1 echoes the command sent for cycle c and
    flags how it was answered (``answers``: cycle → FLAG_PREV_*)."""
    flags = [FLAG_SERVO_POWER | answers.get(c, 0) for c in range(len(sent_q))]
    return [
        make_joint_state(c + 1, c * PERIOD_S, ControllerState.EXTERNAL, flags[c], sent_q[c],
                         sent_dq[c], np.ones(N_JOINTS), sent_q[c], sent_dq[c], PERIOD_S)
        for c in range(len(sent_q))
    ]  # fmt: skip


def _coast(q: np.ndarray, dq: np.ndarray, cycles: range) -> tuple[np.ndarray, np.ndarray]:
    """What the CAN driver sends for ``cycles`` when it coasts: the last command moved on by
    its own velocity."""
    q, dq = q.copy(), dq.copy()
    for c in cycles:
        dq[c] = dq[c - 1]
        q[c] = q[c - 1] + PERIOD_S * dq[c - 1]
    return q, dq


def test_a_single_coast_the_law_resumes_smoothly_is_not_disturbed():
    q, dq = _law_commands(1000)
    q, dq = _coast(q, dq, range(500, 501))
    states = _states(q, dq, {500: FLAG_PREV_COAST})
    assert disturbed_cycles(states, None) == []


def test_a_hold_always_disturbs_the_cycle_it_answered():
    q, dq = _law_commands(1000)
    dq[500] = 0.0
    q[500] = q[499]
    states = _states(q, dq, {500: FLAG_PREV_HOLD})
    assert disturbed_cycles(states, None) == [(500, PERIOD_S)]


def test_every_coast_of_a_run_is_disturbed():
    """Two or forty coasted cycles: the law has moved on by what that many cycles change."""
    q, dq = _law_commands(1000)
    for lost in (range(500, 502), range(500, 540)):
        sent_q, sent_dq = _coast(q, dq, lost)
        states = _states(sent_q, sent_dq, dict.fromkeys(lost, FLAG_PREV_COAST))
        assert [c for c, _ in disturbed_cycles(states, None)] == list(lost)


def test_coasts_that_end_in_a_hold_are_disturbed():
    q, dq = _law_commands(1000)
    q, dq = _coast(q, dq, range(500, 502))
    dq[502], q[502] = 0.0, q[501]
    answers = {500: FLAG_PREV_COAST, 501: FLAG_PREV_COAST, 502: FLAG_PREV_HOLD}
    states = _states(q, dq, answers)
    assert [c for c, _ in disturbed_cycles(states, None)] == [500, 501, 502]


def test_a_coast_whose_resumption_was_not_recorded_is_disturbed():
    q, dq = _law_commands(1000)
    q, dq = _coast(q, dq, range(500, 501))
    states = [st for st in _states(q, dq, {500: FLAG_PREV_COAST}) if st.cycle != 502]
    assert [c for c, _ in disturbed_cycles(states, None)] == [500]


def test_a_coast_whose_run_before_it_was_not_recorded_is_disturbed():
    q, dq = _law_commands(1000)
    q, dq = _coast(q, dq, range(500, 501))
    states = [st for st in _states(q, dq, {500: FLAG_PREV_COAST}) if st.cycle != 500]
    assert [c for c, _ in disturbed_cycles(states, None)] == [500]


def test_only_cycles_in_range_are_reported():
    q, dq = _law_commands(1000)
    for c in (300, 700):
        dq[c], q[c] = 0.0, q[c - 1]
    states = _states(q, dq, {300: FLAG_PREV_HOLD, 700: FLAG_PREV_HOLD})
    assert disturbed_cycles(states, (400, 999)) == [(700, PERIOD_S)]
