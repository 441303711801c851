"""Taught programs made replayable (control/taught_path*.py): tremor out, constant tool speed,
rest-to-rest strokes, joint limits kept, approaches between segments."""

from __future__ import annotations

import re
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

from control.taught_path import approach, constant_speed, replay_trajectory
from control.taught_path_kinematics import fastest_point_m_s, path_error_m, slow_down, tool_path
from control.taught_path_tremor import TREMOR_CUTOFF_HZ, remove_tremor
from gateway.program import Program
from gateway.robot.description import load_description

DESC = load_description()
DT = 0.004  #: controller period [s]
OMEGA = np.array([0.8, 0.8, 0.8, 1.5, 1.5, 1.5])  #: cell.toml [control] max_velocity_rad_s
Q0 = np.array([0.0, 0.25, 0.1, 0.0, 0.6, 0.0])
AMPLITUDE_RAD = np.array([0.3, 0.12, 0.15, 0.25, 0.2, 0.3])
PHASE_RAD = np.array([0.0, 1.0, 2.0, 0.5, 1.5, 2.5])
DRIFT_RAD_S = np.array([0.08, 0.02, -0.03, 0.05, 0.04, 0.06])
MOTION_HZ, TREMOR_HZ = 0.3, 8.0
#: joint amplitude giving ~1 mm at the tool: lever of each joint to the tool at Q0 [m]
TREMOR_RAD = 1e-3 / np.array([1.6, 1.4, 1.0, 0.25, 0.25, 0.25])
ENCODER_RAD = 2 * np.pi / 2**18


def _times(rng: np.random.Generator, n: int = 600) -> np.ndarray:
    """~100 Hz with jitter and three dropped samples."""
    t = np.cumsum(rng.uniform(0.008, 0.012, n))
    return np.delete(t - t[0], [100, 101, 350])


def _clean(t: np.ndarray) -> np.ndarray:
    """A smooth sweep that keeps moving: 0.3 Hz sinusoids on a slow drift, every joint."""
    return (
        Q0
        + DRIFT_RAD_S * t[:, None]
        + AMPLITUDE_RAD * np.sin(2 * np.pi * MOTION_HZ * t[:, None] + PHASE_RAD)
    )


def _taught(seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, clean q, tremor, recorded q): 8 Hz tremor, noise, encoder quantisation."""
    rng = np.random.default_rng(seed)
    t = _times(rng)
    clean = _clean(t)
    tremor = TREMOR_RAD * np.sin(2 * np.pi * TREMOR_HZ * t[:, None] + rng.uniform(0, 6.3, 6))
    noisy = clean + tremor + rng.normal(0.0, 2e-5, clean.shape)
    return t, clean, tremor, np.round(noisy / ENCODER_RAD) * ENCODER_RAD


def _amplitude(t: np.ndarray, y: np.ndarray, hz: float) -> np.ndarray:
    """Least-squares amplitude of the ``hz`` sinusoid in each column of y (offset and drift
    fitted alongside)."""
    w = 2 * np.pi * hz * t
    basis = np.column_stack([np.sin(w), np.cos(w), np.ones_like(t), t])
    coef = np.linalg.lstsq(basis, y, rcond=None)[0]
    return np.hypot(coef[0], coef[1])


def _along(joint: int, rad: float) -> np.ndarray:
    """A displacement of one joint (0-based)."""
    out = np.zeros(6)
    out[joint] = rad
    return out


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10 - 15 * u + 6 * u**2)


def _tool_speed(q: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(tool_path(DESC, q), axis=0), axis=1) / DT


def _program(segments: list[tuple[np.ndarray, np.ndarray]]) -> Program:
    t = np.concatenate([s[0] for s in segments])
    return Program(
        path=Path("test.jsonl"),
        header={"type": "header", "joints": list(DESC.joint_names)},
        t_s=t,
        cycle=np.arange(t.size, dtype=np.int64),
        q_rad=np.vstack([s[1] for s in segments]),
        segment=np.concatenate([np.full(len(s[0]), k) for k, s in enumerate(segments)]),
    )


# --- remove_tremor ------------------------------------------------------------------------


def test_tremor_at_8hz_is_cut_tenfold_and_the_0_3hz_motion_passes_within_2_percent():
    t, clean, tremor, q = _taught()
    smooth = remove_tremor(t, q)
    inner = (t > 1.0) & (t < t[-1] - 1.0)
    before = _amplitude(t[inner], tremor[inner], TREMOR_HZ)
    after = _amplitude(t[inner], (smooth - clean)[inner], TREMOR_HZ)
    assert np.all(after < before / 10), after / before
    passed = _amplitude(t[inner], smooth[inner] - Q0, MOTION_HZ) / AMPLITUDE_RAD
    np.testing.assert_allclose(passed, 1.0, atol=0.02)
    # in the tool: the tremor's ~1.5 mm gone but at the very ends (no later sample to average)
    error_m = np.linalg.norm(tool_path(DESC, smooth) - tool_path(DESC, clean), axis=1)
    assert np.abs(tool_path(DESC, q) - tool_path(DESC, clean)).max() > 1e-3
    assert error_m[inner].max() < 0.2e-3
    assert error_m.max() < 2e-3


def test_a_cutoff_above_the_tremor_would_let_it_through():
    t, clean, tremor, q = _taught()
    inner = (t > 1.0) & (t < t[-1] - 1.0)
    smooth = remove_tremor(t, q, cutoff_hz=20.0)
    after = _amplitude(t[inner], (smooth - clean)[inner], TREMOR_HZ)
    before = _amplitude(t[inner], tremor[inner], TREMOR_HZ)
    assert np.all(after > 0.5 * before)


def test_remove_tremor_keeps_times_and_shape_and_takes_one_joint():
    t, _, _, q = _taught()
    assert remove_tremor(t, q).shape == q.shape
    np.testing.assert_allclose(remove_tremor(t, q[:, 2]), remove_tremor(t, q)[:, 2])


@pytest.mark.parametrize("n", [1, 2, 3, 10, 79])
def test_short_segments_come_back_unfiltered(n):
    t = np.arange(n) * 0.01
    q = Q0 + np.outer(np.arange(n), np.full(6, 1e-3))
    np.testing.assert_array_equal(remove_tremor(t, q), q)


def test_non_finite_or_unordered_input_is_refused_by_name():
    t, _, _, q = _taught()
    bad_t = t.copy()
    bad_t[5] = np.nan
    with pytest.raises(ValueError, match=r"t_s has a non-finite value nan at \[5\]"):
        remove_tremor(bad_t, q)
    bad_q = q.copy()
    bad_q[7, 3] = np.inf
    with pytest.raises(ValueError, match=r"q_rad has a non-finite value inf at \[7, 3\]"):
        remove_tremor(t, bad_q)
    with pytest.raises(ValueError, match="t_s must increase: sample 4"):
        remove_tremor(np.r_[t[:4], t[3], t[5:]], q)
    with pytest.raises(ValueError, match="cut-off needs samples faster"):
        remove_tremor(t[::25], q[::25], cutoff_hz=TREMOR_CUTOFF_HZ)  # 4 Hz sampling


# --- constant_speed -----------------------------------------------------------------------


def test_resampled_tool_runs_at_the_requested_speed_along_the_taught_path():
    t, clean, _, q = _taught()
    speed, accel = 0.3, 1.0
    # joint accelerations out of the way (j1 would need 1.4 rad/s² on the ramps, 1 is the
    # default): the ramps at the tool's acceleration
    out = constant_speed(DESC, t, q, speed, DT, accel, max_joint_speed_rad_s=OMEGA,
                         max_joint_accel_rad_s2=2.0)  # fmt: skip
    assert out.notes == () and out.speed_m_s == pytest.approx(speed, rel=1e-3)
    v = _tool_speed(out.q_rad)
    ramp = int(np.ceil(speed / accel / DT)) + 1
    np.testing.assert_allclose(v[ramp:-ramp], speed, rtol=0.05)
    assert v.max() < 1.05 * speed
    # starts and ends at rest, gentle ramps
    np.testing.assert_array_equal(out.dq_rad_s[[0, -1]], 0.0)
    assert v[0] < 0.01 * speed and v[-1] < 0.01 * speed
    assert np.abs(np.diff(v)).max() / DT < 1.2 * accel
    # dq is the derivative of q
    np.testing.assert_allclose(
        np.gradient(out.q_rad, DT, axis=0), out.dq_rad_s, atol=0.01 * np.abs(out.dq_rad_s).max()
    )
    # the path: the smoothed taught one, within 1 mm of the tremor-free one
    smooth = remove_tremor(t, q)
    np.testing.assert_array_equal(out.q_rad[[0, -1]], smooth[[0, -1]])
    assert path_error_m(DESC, smooth, out.q_rad) < 0.1e-3
    assert path_error_m(DESC, clean, out.q_rad) < 1e-3
    # ... and the whole of it: the replay takes as long as the path at that speed
    length_m = np.linalg.norm(np.diff(tool_path(DESC, smooth), axis=0), axis=1).sum()
    assert len(out.q_rad) * DT == pytest.approx(length_m / speed + speed / accel, abs=0.05)


@pytest.mark.parametrize("j1_limit", [0.2, 0.1])
def test_a_joint_over_its_speed_limit_slows_the_tool_where_it_would_be_too_fast(j1_limit):
    t, _, _, q = _taught()
    omega = OMEGA.copy()
    omega[0] = j1_limit  # j1 needs ~0.43 rad/s at 0.3 m/s where it sweeps fastest
    out = constant_speed(DESC, t, q, 0.3, DT, max_joint_speed_rad_s=omega)
    note = next(n for n in out.notes if n.startswith("joint j1 would turn at 0.4"))
    low, share = (float(x) for x in re.search(r"to (\S+) m/s over (\S+) %", note).groups())
    assert low == pytest.approx(0.3 * j1_limit / 0.426, rel=0.02)
    assert np.all(np.abs(out.dq_rad_s) <= omega)
    assert np.all(np.abs(np.diff(out.q_rad, axis=0)) / DT <= omega)
    assert np.abs(out.dq_rad_s[:, 0]).max() > 0.95 * omega[0]
    v = _tool_speed(out.q_rad)
    assert v.max() == pytest.approx(0.3, rel=0.01)  # the request where j1 is slow enough
    assert v[v < 0.95 * 0.3].min() < 1.05 * low
    # the uniform slow-down that was (the whole path at `low`) took far longer
    smooth = remove_tremor(t, q)
    length_m = np.linalg.norm(np.diff(tool_path(DESC, smooth), axis=0), axis=1).sum()
    assert len(out.q_rad) * DT < 0.7 * length_m / low
    # the cruise speed: the request while j1 slows the tool over less than half of the path
    if share < 50:
        assert out.speed_m_s == 0.3
    else:
        assert low < out.speed_m_s < 0.3


def _wrist_swing(seconds: float = 8.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, q, omega): j1 sweeps the gun ~0.63 m at a steady pace while j4 swings 0.2 rad in the
    middle tenth of the time (~12 % of the tool path, up to 3.6 rad of j4 per metre); j4 is
    limited to 0.3 rad/s, i.e. the tool to ~0.08 m/s during the swing."""
    t = np.arange(0.0, seconds, 0.01)
    u = t / t[-1]
    q = np.tile(Q0, (len(t), 1))
    q[:, 0] += 0.6 * u
    q[:, 3] += 0.2 * _smoothstep((u - 0.45) / 0.1)
    omega = OMEGA.copy()
    omega[3] = 0.3
    return t, q, omega


def _progress(q: np.ndarray, length_m: float) -> np.ndarray:
    """Share of the tool path covered at the end of each step of q (K-1,)."""
    return np.cumsum(np.linalg.norm(np.diff(tool_path(DESC, q), axis=0), axis=1)) / length_m


def test_a_local_wrist_swing_slows_the_tool_only_there():
    t, q, omega = _wrist_swing()
    speed, accel = 0.3, 1.0
    out = constant_speed(DESC, t, q, speed, DT, accel, max_joint_speed_rad_s=omega,
                         max_joint_accel_rad_s2=20.0)  # fmt: skip
    smooth = remove_tremor(t, q)
    length_m = np.linalg.norm(np.diff(tool_path(DESC, smooth), axis=0), axis=1).sum()
    where, v = _progress(out.q_rad, length_m), _tool_speed(out.q_rad)
    # the requested speed away from the swing (it runs from 44 % to 56 % of the path; braking
    # from 0.3 to 0.08 m/s at 1 m/s² takes 4.2 cm, 7 % of it), slower at the swing
    away = ((where > 0.1) & (where < 0.36)) | ((where > 0.64) & (where < 0.9))
    np.testing.assert_allclose(v[away], speed, rtol=0.05)
    swing = (where > 0.47) & (where < 0.53)
    assert v[swing].max() < 0.6 * speed
    assert v.max() < 1.05 * speed
    assert out.speed_m_s == speed
    # no joint over its limit, j4 at it through the swing
    assert np.all(np.abs(out.dq_rad_s) <= omega)
    assert np.all(np.abs(np.diff(out.q_rad, axis=0)) / DT <= omega)
    assert np.abs(out.dq_rad_s[:, 3]).max() > 0.98 * omega[3]
    # from and to rest, along the taught path, within the tool acceleration
    np.testing.assert_array_equal(out.dq_rad_s[[0, -1]], 0.0)
    np.testing.assert_array_equal(out.q_rad[[0, -1]], smooth[[0, -1]])
    assert v[0] < 0.01 * speed and v[-1] < 0.01 * speed
    assert np.abs(np.diff(v)).max() / DT < 1.2 * accel
    assert path_error_m(DESC, smooth, out.q_rad) < 0.1e-3
    np.testing.assert_allclose(
        np.gradient(out.q_rad, DT, axis=0), out.dq_rad_s, atol=0.01 * np.abs(out.dq_rad_s).max()
    )
    # far quicker than the whole path at the swing's speed (the uniform slow-down that was)
    (note,) = out.notes
    low, share = (float(x) for x in re.search(r"to (\S+) m/s over (\S+) %", note).groups())
    assert note.startswith("joint j4 would turn at 1.09 rad/s at 0.3 m/s (limit 0.3 rad/s)")
    assert low == pytest.approx(v[swing].min(), rel=0.05)
    assert 5 < share < 15
    duration_s = len(out.q_rad) * DT
    assert duration_s < 1.5 * (length_m / speed + speed / accel)
    assert duration_s < 0.5 * length_m / low


def test_joint_accelerations_stretch_the_slow_down_but_stay_within_their_limit():
    t, q, omega = _wrist_swing()
    quick = constant_speed(DESC, t, q, 0.3, DT, max_joint_speed_rad_s=omega,
                           max_joint_accel_rad_s2=20.0)  # fmt: skip
    out = constant_speed(DESC, t, q, 0.3, DT, max_joint_speed_rad_s=omega,
                         max_joint_accel_rad_s2=1.0)  # fmt: skip
    ddq = np.abs(np.diff(out.dq_rad_s, axis=0)) / DT
    assert ddq.max() < 1.05  # rad/s²: the limit holds on the profile's grid, ~between
    assert np.abs(np.diff(quick.dq_rad_s, axis=0)).max() / DT > 4.0
    assert np.all(np.abs(out.dq_rad_s) <= omega)
    assert len(quick.q_rad) < len(out.q_rad) < 1.5 * len(quick.q_rad)
    assert any(n.startswith("the joint acceleration limits slow the tool") for n in out.notes)
    assert not any("acceleration" in n for n in quick.notes)


def test_a_zigzag_comes_to_rest_at_each_reversal():
    t = np.arange(0.0, 7.0, 0.01)
    q = np.tile(Q0, (len(t), 1))
    q[:, 0] += 0.3 * np.sin(2 * np.pi * 0.3 * t)  # j1 sweeps the gun left, right, left
    out = constant_speed(DESC, t, q, 0.3, DT, max_joint_speed_rad_s=OMEGA)
    assert any("stops" in n for n in out.notes)
    dq1 = out.dq_rad_s[:, 0]
    turns = np.flatnonzero(np.sign(dq1[1:]) * np.sign(dq1[:-1]) < 0)
    assert turns.size == 0  # j1 never reverses while moving: it stops first
    rests = np.flatnonzero(np.all(out.dq_rad_s == 0.0, axis=1))
    assert len(rests) >= 4  # start, two reversals, end
    assert np.abs(np.diff(out.dq_rad_s, axis=0)).max() / DT < 2.0  # rad/s², no jolt


def test_a_pivot_with_the_tool_still_is_replayed_in_joint_space_without_slowing_the_strokes():
    t = np.arange(0.0, 6.0, 0.01)
    q = np.tile(Q0, (len(t), 1))
    q[:, 0] += 0.2 * _smoothstep(t / 2) + 0.2 * _smoothstep((t - 4) / 2)
    q[:, 5] += 1.0 * _smoothstep((t - 2) / 2)  # j6 turns the gun about its own tip
    out = constant_speed(
        DESC, t, q, 0.3, DT, max_joint_speed_rad_s=OMEGA, max_joint_accel_rad_s2=10.0
    )
    assert out.speed_m_s == pytest.approx(0.3, rel=1e-3)
    assert any("1 with the joints turning" in n for n in out.notes)
    assert np.abs(out.dq_rad_s[:, 5]).max() == pytest.approx(OMEGA[5], rel=0.05)
    assert np.all(np.abs(out.dq_rad_s) <= OMEGA)
    np.testing.assert_allclose(out.q_rad[-1], q[-1], atol=1e-4)


def test_a_pure_reorientation_is_replayed_by_joint_travel():
    t = np.arange(0.0, 6.0, 0.01)
    q = np.tile(Q0, (len(t), 1))
    q[:, 5] += _smoothstep(t / 6)  # the tool point on the j6 axis does not move
    out = constant_speed(DESC, t, q, 0.3, DT, max_joint_speed_rad_s=OMEGA)
    assert any("barely moves" in n for n in out.notes)
    np.testing.assert_allclose(out.q_rad[-1], q[-1], atol=1e-4)
    np.testing.assert_array_equal(out.dq_rad_s[[0, -1]], 0.0)
    # 1 rad is too short for j6 to reach 1.5 rad/s at 1 rad/s²: it accelerates at the limit
    assert np.all(np.abs(out.dq_rad_s) <= OMEGA)
    ddq = np.abs(np.diff(out.dq_rad_s[:, 5])) / DT
    assert ddq.max() == pytest.approx(1.0, rel=0.05)


@pytest.mark.parametrize("n", [1, 2, 3, 20])
def test_segments_of_a_few_samples_are_replayed_from_and_to_rest(n):
    t = np.arange(n) * 0.01
    q = Q0 + np.outer(np.arange(n), [1e-3, 0, 0, 0, 0, 0])
    out = constant_speed(DESC, t, q, 0.3, DT, max_joint_speed_rad_s=OMEGA)
    np.testing.assert_array_equal(out.q_rad[[0, -1]], q[[0, -1]])
    np.testing.assert_array_equal(out.dq_rad_s[[0, -1]], 0.0)
    assert np.all(np.abs(out.dq_rad_s) <= OMEGA)


def test_a_taught_path_outside_the_joint_limits_is_refused_naming_joint_and_sample():
    t, _, _, q = _taught()
    q = q.copy()
    q[42, 2] = DESC.joints[2].upper_rad + 0.01
    with pytest.raises(ValueError, match=r"sample 42 \(t = .* s\): joint j3 at 1\.0572 rad"):
        constant_speed(DESC, t, q, 0.3, DT, max_joint_speed_rad_s=OMEGA)


def test_bad_arguments_are_refused():
    t, _, _, q = _taught()
    with pytest.raises(ValueError, match="speed_m_s must be a finite number > 0"):
        constant_speed(DESC, t, q, 0.0, DT, max_joint_speed_rad_s=OMEGA)
    with pytest.raises(ValueError, match="max_joint_speed_rad_s must be one value or 6"):
        constant_speed(DESC, t, q, 0.3, DT, max_joint_speed_rad_s=[1.0, 2.0])
    with pytest.raises(ValueError, match=r"q_rad must be \(T, 6\)"):
        constant_speed(DESC, t, q[:, :5], 0.3, DT, max_joint_speed_rad_s=OMEGA)


# --- approach -----------------------------------------------------------------------------


def test_approach_is_synchronised_rest_to_rest_and_ends_exactly_at_the_target():
    start = Q0 + np.array([0.3, -0.1, 0.05, 1.0, 0.0, -0.5])
    q, dq = approach(start, Q0, DT, OMEGA, max_joint_accel_rad_s2=10.0)
    np.testing.assert_array_equal(q[0], start)
    np.testing.assert_array_equal(q[-1], Q0)
    np.testing.assert_array_equal(dq[[0, -1]], 0.0)
    assert np.all(np.abs(dq) <= OMEGA + 1e-12)
    assert np.abs(dq[:, 3]).max() == pytest.approx(OMEGA[3], rel=0.02)  # j4 sets the pace
    moving = np.flatnonzero(start != Q0)
    progress = (q - start)[:, moving] / (Q0 - start)[moving]
    np.testing.assert_allclose(progress, np.repeat(progress[:, :1], moving.size, 1), atol=1e-12)
    np.testing.assert_allclose(np.gradient(q, DT, axis=0), dq, atol=0.01)


def test_approach_to_where_the_robot_already_is_has_no_samples():
    q, dq = approach(Q0, Q0.copy(), DT, OMEGA)
    assert q.shape == dq.shape == (0, 6)


def test_a_tiny_approach_respects_the_acceleration_limit():
    _, dq = approach(Q0, Q0 + 1e-3, DT, OMEGA, max_joint_accel_rad_s2=0.5)
    assert np.abs(np.diff(dq, axis=0)).max() / DT < 0.5 * 1.05


# --- replay_trajectory --------------------------------------------------------------------


def _two_segments() -> list[tuple[np.ndarray, np.ndarray]]:
    t1, _, _, q1 = _taught(seed=1)
    t2, _, _, q2 = _taught(seed=2)
    return [(t1, q1), (t2 + t1[-1] + 5.0, q2[::-1] + _along(0, 0.1))]


def test_replay_approaches_then_plays_each_segment_continuously_within_limits():
    program = _program(_two_segments())
    here = Q0 + 0.2
    parts = replay_trajectory(program, DESC, here, DT, 0.3, max_joint_speed_rad_s=OMEGA)
    assert [p.label for p in parts] == ["approach/1", "taught/1", "approach/2", "taught/2"]
    np.testing.assert_array_equal(parts[0].q_rad[0], here)
    for before, after in pairwise(parts):
        np.testing.assert_array_equal(before.q_rad[-1], after.q_rad[0])
    for label, q, dq in parts:
        np.testing.assert_array_equal(dq[[0, -1]], 0.0, err_msg=label)
        assert np.all(np.abs(dq) <= OMEGA), label
        assert np.all((q >= DESC.lower_rad) & (q <= DESC.upper_rad)), label
    _, (t2, q2) = program.segments()
    assert path_error_m(DESC, remove_tremor(t2, q2), parts[3].q_rad) < 0.1e-3


def test_no_approach_where_the_robot_already_is():
    (t1, q1), (t2, q2) = _two_segments()
    first = constant_speed(DESC, t1, q1, 0.3, DT, max_joint_speed_rad_s=OMEGA).q_rad[0]
    program = _program([(t1, q1), (t2, q2)])
    parts = replay_trajectory(program, DESC, first, DT, 0.3, max_joint_speed_rad_s=OMEGA)
    assert [p.label for p in parts] == ["taught/1", "approach/2", "taught/2"]


def test_replay_of_one_and_two_sample_segments():
    one = (np.array([0.0]), Q0[None, :])
    two = (np.array([1.0, 1.01]), np.vstack([Q0, Q0 + 1e-3]))
    parts = replay_trajectory(_program([one, two]), DESC, Q0 + 0.01, DT, 0.3,
                              max_joint_speed_rad_s=OMEGA)  # fmt: skip
    # segment 2 starts where segment 1 (a single sample) is: nothing to approach
    assert [p.label for p in parts] == ["approach/1", "taught/1", "taught/2"]
    assert len(parts[1].q_rad) == 1
    np.testing.assert_array_equal(parts[-1].q_rad[-1], Q0 + 1e-3)


def test_replay_refuses_a_program_outside_the_limits_naming_segment_joint_and_sample():
    (t1, q1), (t2, q2) = _two_segments()
    q2 = q2.copy()
    q2[17, 1] = DESC.joints[1].lower_rad - 0.05
    program = _program([(t1, q1), (t2, q2)])
    with pytest.raises(ValueError, match=r"teaching segment 2, sample 17 .* joint j2"):
        replay_trajectory(program, DESC, Q0, DT, 0.3, max_joint_speed_rad_s=OMEGA)


def test_replay_refuses_non_finite_values_a_robot_off_limits_and_a_wrong_robot():
    (t1, q1), _ = _two_segments()
    program = _program([(t1, q1)])
    with pytest.raises(ValueError, match="q_now has a non-finite value nan"):
        replay_trajectory(program, DESC, Q0 * np.nan, DT, 0.3, max_joint_speed_rad_s=OMEGA)
    with pytest.raises(ValueError, match=r"robot is outside its joint limits: .* joint j3"):
        replay_trajectory(program, DESC, Q0 + _along(2, 2.0), DT, 0.3,
                          max_joint_speed_rad_s=OMEGA)  # fmt: skip
    bad = _program([(t1, q1)])
    bad.q_rad[3, 4] = np.nan
    with pytest.raises(
        ValueError, match=r"segment 1, q_rad has a non-finite value nan at \[3, 4\]"
    ):
        replay_trajectory(bad, DESC, Q0, DT, 0.3, max_joint_speed_rad_s=OMEGA)
    five = _program([(t1, q1)])
    five.header["joints"] = ["a", "b", "c", "d", "e"]
    with pytest.raises(ValueError, match="the program has 5 joints"):
        replay_trajectory(five, DESC, Q0, DT, 0.3, max_joint_speed_rad_s=OMEGA)


# --- path_error_m -------------------------------------------------------------------------


def test_path_error_is_the_distance_to_the_taught_polyline_not_to_its_samples():
    t = np.linspace(0.0, 1.0, 11)
    taught = Q0 + np.outer(t, [0.2, 0, 0, 0, 0, 0])  # coarse samples on an arc of j1
    fine = Q0 + np.outer(np.linspace(0.0, 1.0, 1001), [0.2, 0, 0, 0, 0, 0])
    chord_sag_m = 1.3 * (1 - np.cos(0.01))  # arc of radius ~1.3 m between samples 0.02 rad apart
    assert path_error_m(DESC, taught, fine) < 2 * chord_sag_m
    lifted = fine + _along(1, 0.01)  # j2 tilts the arm: ~1.6 cm off the path
    assert 0.01 < path_error_m(DESC, taught, lifted) < 0.03


def test_path_error_search_is_exact_against_brute_force():
    from control.taught_path_kinematics import _polyline_distance, _segment_distance

    rng = np.random.default_rng(5)
    vertices = np.cumsum(rng.normal(0, 0.01, (400, 3)), axis=0)
    vertices[200:] += [0.5, 0, 0]  # one long segment among short ones
    points = vertices[rng.integers(0, 400, 300)] + rng.normal(0, 0.05, (300, 3))
    brute = _segment_distance(points[:, None], vertices[None, :-1], np.diff(vertices, axis=0))
    np.testing.assert_allclose(_polyline_distance(vertices, points), brute.min(axis=1))


def test_a_replay_never_moves_the_tool_or_the_flange_past_the_point_limit():
    """An approach of 0.2 rad on every joint at 0.8 rad/s, and strokes at 0.3 m/s: with a
    0.24 m/s point limit every segment is played slower where it must be, along the same
    joint path, still from rest to rest; without it the same plan is faster than that."""
    program = _program(_two_segments())
    here = Q0 + 0.2
    free = replay_trajectory(program, DESC, here, DT, 0.3, max_joint_speed_rad_s=OMEGA)
    assert max(fastest_point_m_s(DESC, p.q_rad, DT) for p in free) > 0.26
    parts = replay_trajectory(program, DESC, here, DT, 0.3, max_joint_speed_rad_s=OMEGA,
                              max_point_speed_m_s=0.24)  # fmt: skip
    assert [p.label for p in parts] == [p.label for p in free]
    for slow, fast in zip(parts, free, strict=True):
        assert fastest_point_m_s(DESC, slow.q_rad, DT) <= 0.24, slow.label
        assert len(slow.q_rad) >= len(fast.q_rad)
        np.testing.assert_array_equal(slow.q_rad[[0, -1]], fast.q_rad[[0, -1]])
        np.testing.assert_allclose(slow.dq_rad_s[[0, -1]], 0.0, atol=1e-12)
        # the same path: every slow sample lies on the fast one's joint polyline
        assert path_error_m(DESC, fast.q_rad, slow.q_rad) < 1e-4, slow.label


def test_slow_down_leaves_a_slow_path_alone():
    q = np.linspace(Q0, Q0 + 0.001, 50)
    dq = np.gradient(q, DT, axis=0)
    out_q, out_dq, factor = slow_down(DESC, q, dq, DT, 0.24)
    assert factor == 1.0 and out_q is q and out_dq is dq
