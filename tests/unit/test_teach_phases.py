"""The phases of a teaching run (sim_bridge/teach_phases.py) on synthetic traces: start-up,
cruise, reversal and dwell rows, and the force in each."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_bridge.teach_phases import (
    PHASES,
    REVERSAL_S,
    STARTUP_S,
    classify,
    phase_forces,
    reversal_rows,
)

STEP_S = 0.004


def _legs():
    """Target speed 0.1 m/s on [1, 5) and [5.5, 9), still otherwise; the path ends at 10 s."""
    tau = np.arange(0.0, 11.0, STEP_S)
    speed = np.where(((tau >= 1.0) & (tau < 5.0)) | ((tau >= 5.5) & (tau < 9.0)), 0.1, 0.0)
    return tau, speed


def test_each_leg_starts_with_a_start_up_then_cruises_and_stands_at_its_corners():
    tau, speed = _legs()
    phase = classify(tau, speed, 10.0, None)
    name = np.array([PHASES[i] if i >= 0 else "after" for i in phase])
    assert set(name[tau < 1.0]) == {"dwell"}
    assert set(name[(tau >= 1.0) & (tau < 1.0 + STARTUP_S - STEP_S)]) == {"startup"}
    assert set(name[(tau >= 1.0 + STARTUP_S + STEP_S) & (tau < 5.0)]) == {"cruise"}
    assert set(name[(tau >= 5.0) & (tau < 5.5)]) == {"dwell"}
    assert set(name[(tau >= 5.5) & (tau < 5.5 + STARTUP_S - STEP_S)]) == {"startup"}
    assert set(name[tau > 10.0]) == {"after"}


def test_a_run_stopped_before_the_target_moved_is_all_dwell():
    # the product faulted 9 cycles into teaching (plant seed 105 on one CPU): the target never
    # left its start, and the range's bench went on to its other seeds
    tau = np.arange(9) * 0.008
    q = np.zeros((tau.size, 6))
    phase = classify(tau, np.zeros(tau.size), 57.0, q)
    assert (phase == PHASES.index("dwell")).all()


def test_a_joint_that_reverses_mid_leg_marks_the_rows_around_it_and_tremor_does_not():
    tau, speed = _legs()
    # joint 1 swings through zero speed at 3 s (0.1 rad/s before, -0.1 after); joint 2 stands
    # and trembles: 0.5 mm at a metre at 9 Hz (0.028 rad/s peaks, no reversal of intent)
    q1 = -0.05 * (tau - 3.0) ** 2
    q2 = 5e-4 * np.sin(2 * math.pi * 9.0 * tau)
    phase = classify(tau, speed, 10.0, np.stack([q1, q2], axis=1))
    reversal = phase == PHASES.index("reversal")
    assert reversal[np.abs(tau - 3.0) < 0.1].all()
    assert not reversal[np.abs(tau - 3.0) > REVERSAL_S + 0.15].any()
    only_tremor = reversal_rows(tau, q2[:, None])
    assert not only_tremor.any()


def test_a_reversal_within_a_start_up_counts_as_start_up():
    tau, speed = _legs()
    q = -0.05 * (tau - 1.2) ** 2  # reverses 0.2 s into the first leg
    phase = classify(tau, speed, 10.0, q[:, None])
    assert (phase[(tau >= 1.0) & (tau < 1.0 + STARTUP_S - STEP_S)] == PHASES.index("startup")).all()


def test_the_force_per_phase_and_its_time():
    tau, speed = _legs()
    phase = classify(tau, speed, 10.0, None)
    force = np.choose(np.maximum(phase, 0), [30.0, 10.0, 0.0, 2.0])  # by PHASES' order
    force[phase < 0] = 99.0  # after the path: counted nowhere
    out = phase_forces(tau, force, phase)
    assert out["startup"]["mean_force_n"] == pytest.approx(30.0)
    assert out["cruise"]["peak_force_n"] == pytest.approx(10.0)
    assert out["dwell"]["p95_force_n"] == pytest.approx(2.0)
    assert math.isnan(out["reversal"]["mean_force_n"]) and out["reversal"]["seconds"] == 0.0
    assert out["startup"]["seconds"] == pytest.approx(2 * STARTUP_S, abs=2 * STEP_S)
    assert out["dwell"]["seconds"] == pytest.approx(1.0 + 0.5 + 1.0, abs=3 * STEP_S)
