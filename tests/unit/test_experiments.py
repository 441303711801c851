"""Excitation motions: shapes the paper prescribes, start/end at rest, limits enforced."""

import numpy as np
import pytest
from example_program import write_program

from control.experiments import (
    build_plan,
    friction_runs,
    multisine,
    reciprocating,
    teaching_strokes,
)
from control.plan_player import MAX_REPLAY_JOINT_SPEED_RAD_S, RESUME_ACCEL_RAD_S2, PlanPlayer
from gateway.message_factories import make_joint_state
from gateway.messages import FLAG_PREV_HOLD, FLAG_SERVO_POWER, ControllerState, JointState
from gateway.robot.description import load_description

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


# --- the plan player of the control process -------------------------------------------------
PLAYER_PLAN = {
    "plan_id": "p",
    "multisine": [
        {"seed": 1, "duration_s": 0.4, "amplitude_rad": 0.01, "base_hz": 2.5, "harmonics": 2},
        {"seed": 2, "duration_s": 0.4, "amplitude_rad": 0.01, "base_hz": 2.5, "harmonics": 2,
         "role": "test"},
    ],
    "pause_s": 0.04,
}  # fmt: skip
PERIOD_S = 0.008


def _state(cycle: int, flags: int = 0) -> JointState:
    q = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
    z = np.zeros(6)
    return make_joint_state(cycle, 0.0, ControllerState.EXTERNAL, FLAG_SERVO_POWER | flags,
                            q, z, z, q, z, PERIOD_S)  # fmt: skip


def _player() -> PlanPlayer:
    desc = load_description()
    player = PlanPlayer(desc.lower_rad, desc.upper_rad)
    player.start(PLAYER_PLAN, _state(100), PERIOD_S)
    assert player.state == "running"
    return player


def play(player: PlanPlayer, held_cycles: set[int], last: int) -> list[np.ndarray]:
    """Feed cycles 100..last; a cycle in ``held_cycles`` was answered by the driver's hold."""
    sent = []
    for cycle in range(100, last + 1):
        out = player.command(_state(cycle, FLAG_PREV_HOLD if cycle - 1 in held_cycles else 0))
        if out is not None and player.state == "running":
            sent.append(out[0])
    return sent


def test_plan_plays_one_sample_per_cycle_and_records_segment_cycles():
    player = _player()
    n = len(player.q)
    play(player, set(), 100 + n)
    assert player.state == "done" and player.repeats == 0
    first, second = player.segments
    assert first["start_cycle"] == 100 and second["end_cycle"] == 100 + n - 1
    assert second["start_cycle"] == first["end_cycle"] + 1


def test_a_report_is_one_reading_and_a_dropped_plan_plays_nothing_more():
    player = _player()
    play(player, set(), 110)
    report = player.report()
    assert (report["state"], report["plan_id"]) == ("running", PLAYER_PLAN["plan_id"])
    assert report["progress"] == player.k / len(player.q) > 0  # nothing played between
    assert report["segments"][0]["start_cycle"] == 100
    player.drop()  # another plan is coming
    assert player.play.status() is None
    assert (player.state, player.reason) == ("idle", "")
    assert player.command(_state(111)) is None


def test_a_held_sample_is_sent_again_and_the_plan_waits():
    player = _player()
    n = len(player.q)
    sent = play(player, {110, 111}, 100 + n + 2)
    assert player.state == "done" and player.repeats == 2
    np.testing.assert_array_equal(sent[10], sent[11])  # cycle 110's sample again in 111, 112
    np.testing.assert_array_equal(sent[11], sent[12])
    assert not np.array_equal(sent[12], sent[13])
    # two cycles later than unheld (this plan is slow enough to resume at full speed at once)
    assert player.segments[1]["end_cycle"] == 100 + n + 1


def test_after_a_hold_the_plan_resumes_from_rest_within_the_resume_acceleration():
    """A hold stopped the arm: the re-sent sample asks for no velocity, and each joint's
    commanded velocity then rises by at most RESUME_ACCEL_RAD_S2 per second until the plan
    runs at its own timing again, along the same path (positions between its samples)."""
    desc = load_description()
    player = PlanPlayer(desc.lower_rad, desc.upper_rad)
    swing = {"seed": 3, "duration_s": 1.6, "amplitude_rad": 0.15, "base_hz": 1.0, "harmonics": 2}
    player.start({"plan_id": "fast", "multisine": [swing]}, _state(100), PERIOD_S)
    fast = int(np.argmax(np.max(np.abs(player.dq), axis=1)))  # hold where the plan is fastest
    held = 100 + fast
    out = []
    for cycle in range(100, 100 + 3 * len(player.q)):
        cmd = player.command(_state(cycle, FLAG_PREV_HOLD if cycle - 1 == held else 0))
        if player.state != "running":
            break
        out.append(cmd)
    q = np.array([c[0] for c in out])
    dq = np.array([c[1] for c in out])
    k = fast + 1  # the command answering the state that reported the hold
    np.testing.assert_array_equal(q[k], q[fast])
    assert np.max(np.abs(dq[k])) == 0.0
    rise = np.max(np.abs(np.diff(dq[k:], axis=0)), axis=1) / PERIOD_S
    plan_own = np.max(np.abs(np.diff(player.dq, axis=0))) / PERIOD_S
    assert rise.max() <= max(RESUME_ACCEL_RAD_S2, plan_own) * (1 + 1e-9)
    assert np.max(np.abs(player.dq[fast])) > 4 * RESUME_ACCEL_RAD_S2 * PERIOD_S, "no ramp tested"
    # the same path: every resumed position lies on the segment between two plan samples
    a, b = player.q[:-1], player.q[1:]
    for qk in q[k:]:
        d = b - a
        t = np.clip(np.sum((qk - a) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-30), 0, 1)
        assert np.min(np.linalg.norm(a + t[:, None] * d - qk, axis=1)) < 1e-12
    assert player.state == "done"


def test_a_plan_held_at_its_first_sample_fails_like_at_any_other():
    # the plan is built before its first sample is sent (control/plan_builder.py), so the
    # start has no longer allowance than any other sample
    player = _player()
    held = set(range(100, 100 + round(0.6 / PERIOD_S)))
    play(player, held, 100 + round(0.6 / PERIOD_S))
    assert player.state == "failed" and "at sample 0" in player.reason


def test_a_plan_held_too_long_fails_with_the_reason():
    player = _player()
    held = set(range(105, 105 + round(0.6 / PERIOD_S)))
    play(player, held, 105 + round(0.6 / PERIOD_S))
    assert player.state == "failed" and "did not follow" in player.reason
    report = player.report()
    assert report["state"] == "failed" and report["repeated_samples"] > 0


def test_a_replay_plan_approaches_the_taught_path_and_ends_at_its_end(tmp_path):
    desc = load_description()
    program = tmp_path / "p.jsonl"
    q_start = np.array([0.1, 0.2, 0.3, 0.0, -0.3, 0.0])
    write_program(program, q_start)
    player = PlanPlayer(desc.lower_rad, desc.upper_rad, desc)
    plan = {"plan_id": "r", "replay": {"program": str(program), "speed_m_s": 0.1}}
    player.start(plan, _state(100), PERIOD_S)
    assert player.state == "running", player.reason
    assert [s["label"] for s in player.segments] == ["approach/1", "taught/1"]
    assert {s["role"] for s in player.segments} == {"replay"}
    np.testing.assert_allclose(player.q[0], _state(100).q_cmd_rad, atol=1e-9)
    np.testing.assert_allclose(
        player.q[-1], q_start + np.array([0.15, 0, 0.05, 0, 0, 0]), atol=2e-3
    )
    assert np.abs(player.dq).max() <= MAX_REPLAY_JOINT_SPEED_RAD_S + 1e-6


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ({"program": "/nonexistent.jsonl"}, "cannot read program"),
        ({"speed_m_s": 0.1}, "replay needs"),
        ("p.jsonl", "replay needs"),
        ({"program": "PROGRAM", "speed_m_s": 2.0}, "replay speed"),
        ({"program": "PROGRAM", "speed_m_s": float("nan")}, "replay speed"),
    ],
)
def test_a_bad_replay_plan_fails_with_the_reason(tmp_path, spec, match):
    desc = load_description()
    write_program(tmp_path / "p.jsonl", np.array([0.1, 0.2, 0.3, 0.0, -0.3, 0.0]))
    if isinstance(spec, dict) and spec.get("program") == "PROGRAM":
        spec = {**spec, "program": str(tmp_path / "p.jsonl")}
    player = PlanPlayer(desc.lower_rad, desc.upper_rad, desc)
    player.start({"plan_id": "r", "replay": spec}, _state(100), PERIOD_S)
    assert player.state == "failed" and match in player.reason
    assert player.command(_state(101)) is None  # nothing moves


def test_an_offset_multisine_moves_slowly_to_its_centre_and_back_to_q0():
    amp = np.array([0.1, 0.2, 0.1, 0.3, 0.3, 0.3])
    offset = np.array([0.0, -0.3, 0.35, 0.0, 0.0, 0.0])
    seg = multisine(Q0, amp, 0.2, 5, 20.0, DT, seed=3, offset_rad=offset,
                    transfer_speed_rad_s=0.1)  # fmt: skip
    np.testing.assert_allclose(seg.q_rad[[0, -1]], [Q0, Q0], atol=1e-9)
    np.testing.assert_allclose(seg.dq_rad_s[[0, -1]], 0.0, atol=5e-3)
    centre = Q0 + offset
    # the transfers: 1.5 × 0.35 / 0.1 = 5.25 s each way, no joint above 0.1 rad/s
    legs = round(5.25 / DT)
    there = seg.q_rad[:legs]
    # between them the sines swing within the amplitude, as far each way about the centre
    core = seg.q_rad[legs:-legs]
    up, down = core.max(0) - centre, centre - core.min(0)
    np.testing.assert_allclose(up, down, atol=1e-4)
    assert np.all(up <= amp + 1e-9) and np.all(up >= 0.3 * amp)
    assert np.abs(np.gradient(there, DT, axis=0)).max() <= 0.1 + 1e-3
    assert seg.q_rad.shape[0] * DT == pytest.approx(20.0 + 2 * 5.25, abs=3 * DT)


def test_teaching_strokes_move_every_joint_slowly_reverse_each_stroke_and_start_from_rest():
    """Commissioning's validation motion (on_cell.TEACHING_VALIDATION): 0.5-2 °/s, a reversal
    at every stroke, a rest before each, within the amplitude about its centre."""
    amp, offset = np.full(6, 0.03), np.array([0.0, -0.15, 0.1, 0.0, 0.0, 0.0])
    seg = teaching_strokes(Q0, amp, (0.5, 2.0), 4, 1.0, DT, seed=11, offset_rad=offset)
    np.testing.assert_allclose(seg.q_rad[[0, -1]], [Q0, Q0], atol=1e-9)
    centre = Q0 + offset
    # the strokes lie between the transfer there (1.5 x 0.15 / 0.1 rad/s = 2.25 s) and the
    # last rest, after which the transfer back begins
    there = int(np.ceil(2.25 / DT)) + 1
    still = np.all(np.abs(seg.dq_rad_s) < 1e-9, axis=1)
    core = slice(there, int(np.flatnonzero(still)[-1]) + 1)
    assert np.all(np.abs(seg.q_rad[core] - centre) <= amp + 1e-9)
    v = seg.dq_rad_s[core]
    # strokes: 0.5-2 °/s (the blends below), never faster
    assert np.abs(v).max() <= np.radians(2.0) * 1.01
    for j in range(6):
        moving = v[np.abs(v[:, j]) > 1e-5, j]
        assert np.count_nonzero(np.diff(np.sign(moving)) != 0) == 3  # 4 strokes, 3 reversals
        cruise = np.abs(moving)
        assert np.percentile(cruise, 90) >= np.radians(0.5) * 0.99
    # at rest for the rest time before every stroke: whole rows with every joint still
    still = np.all(np.abs(v) < 1e-9, axis=1)
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, still.astype(int), 0])))[::2]
    assert np.sum(runs >= round(1.0 / DT) - 2) >= 4


def test_a_plan_with_teaching_strokes_marks_them_for_validation_by_default():
    spec = {"seed": 1, "strokes": 2, "amplitude_rad": 0.02, "speeds_deg_s": [0.5, 2.0],
            "rest_s": 0.5}  # fmt: skip
    segs = build_plan({"plan_id": "x", "teaching": [spec]}, Q0, LOWER, UPPER, DT, 0.05)
    assert [(label, role) for label, role, _, _ in segs] == [("teaching/seed1", "validate")]
    with pytest.raises(ValueError, match="teaching role"):
        build_plan({"plan_id": "x", "teaching": [{**spec, "role": "x"}]}, Q0, LOWER, UPPER,
                   DT, 0.05)  # fmt: skip
    with pytest.raises(ValueError, match="teaching speeds"):
        build_plan({"plan_id": "x", "teaching": [{**spec, "speeds_deg_s": [2, 0.5]}]}, Q0,
                   LOWER, UPPER, DT, 0.05)  # fmt: skip
