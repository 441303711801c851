"""Excitation motions: shapes the paper prescribes, start/end at rest, limits enforced."""

import numpy as np
import pytest

from control.experiments import build_plan, friction_runs, multisine, reciprocating

DT = 0.004
Q0 = np.array([0.0, 0.1, 0.2, 0.0, -0.4, 0.0])
LOWER, UPPER = np.full(6, -1.0), np.full(6, 1.0)


def test_reciprocating_stroke_is_constant_speed_with_parabolic_blends_and_dwell():
    seg = reciprocating(Q0, 1, 0.2, np.radians(4.0), DT, strokes=1)
    dq = seg.dq_rad_s[:, 1]
    plateau = dq[np.abs(dq) > 0.99 * np.radians(4.0)]
    assert plateau.size > 0.8 * 0.2 / np.radians(4.0) / DT  # 90 % of the path at speed
    np.testing.assert_allclose(np.abs(plateau), np.radians(4.0), rtol=0.02)
    assert seg.q_rad[:, 1].max() == pytest.approx(Q0[1] + 0.2, abs=1e-9)
    np.testing.assert_allclose(seg.q_rad[[0, -1]], [Q0, Q0], atol=1e-9)
    others = np.delete(seg.q_rad, 1, axis=1)
    np.testing.assert_array_equal(others, np.tile(np.delete(Q0, 1), (len(seg.q_rad), 1)))
    assert abs(dq[0]) < 0.05 * np.radians(4.0) and abs(dq[-1]) < 0.05 * np.radians(4.0)


def test_friction_runs_cover_every_joint_and_speed():
    segs = friction_runs(Q0, [0, 2], 0.1, (0.5, 4.0), DT)
    assert [s.label for s in segs] == [
        "friction/j1/0.5dps",
        "friction/j1/4.0dps",
        "friction/j3/0.5dps",
        "friction/j3/4.0dps",
    ]


def test_multisine_starts_and_ends_at_rest_at_q0_within_amplitude():
    amp = np.array([0.1, 0.2, 0.1, 0.3, 0.3, 0.3])
    seg = multisine(Q0, amp, 0.2, 5, 20.0, DT, seed=3)
    np.testing.assert_allclose(seg.q_rad[0], Q0, atol=1e-9)
    np.testing.assert_allclose(seg.q_rad[-1], Q0, atol=2e-3)
    np.testing.assert_allclose(seg.dq_rad_s[[0, -1]], 0.0, atol=5e-3)
    assert np.all(np.abs(seg.q_rad - Q0).max(0) <= amp + 1e-9)
    assert not np.allclose(seg.q_rad, multisine(Q0, amp, 0.2, 5, 20.0, DT, seed=4).q_rad)


def test_build_plan_concatenates_segments_with_roles():
    plan = {
        "plan_id": "p1",
        "friction": {"joints": [2], "amplitude_rad": 0.1, "speeds_deg_s": [4.0]},
        "multisine": [
            {"seed": 1, "duration_s": 4, "amplitude_rad": 0.05, "base_hz": 0.5, "harmonics": 3},
            {
                "seed": 2,
                "duration_s": 4,
                "amplitude_rad": 0.05,
                "base_hz": 0.5,
                "harmonics": 3,
                "role": "test",
            },
        ],
    }
    parts = build_plan(plan, Q0, LOWER, UPPER, DT, 0.05)
    assert [(label, role) for label, role, _, _ in parts] == [
        ("friction/j2/4.0dps", "train"),
        ("multisine/seed1", "train"),
        ("multisine/seed2", "test"),
    ]


@pytest.mark.parametrize(
    "plan, match",
    [
        ({"plan_id": "x"}, "no experiment"),
        ({"plan_id": "x", "fly": {}}, "unknown plan key"),
        (
            {
                "plan_id": "x",
                "friction": {"joints": [7], "amplitude_rad": 0.1, "speeds_deg_s": [1]},
            },
            "1..6",
        ),
        ({"plan_id": "x", "gravity": {"joints": [2]}}, "missing"),
        (
            {
                "plan_id": "x",
                "friction": {"joints": [2], "amplitude_rad": 0.95, "speeds_deg_s": [8]},
            },
            "outside its range",
        ),
    ],
)
def test_bad_plans_are_refused_with_a_reason(plan, match):
    with pytest.raises(ValueError, match=match):
        build_plan(plan, Q0, LOWER, UPPER, DT, 0.05)
