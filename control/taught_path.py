"""Taught programs made replayable: hand tremor out, one tool speed, approaches in between.

A taught program (:mod:`gateway.program`) holds the joint positions recorded at ~100 Hz while an
operator dragged the spray gun by hand. Played back as recorded it would repeat the operator's
tremor and uneven pace, and a coat needs the gun at one speed. :func:`replay_trajectory` turns
each teaching segment into a joint trajectory sampled at the controller period:

1. :func:`~control.taught_path_tremor.remove_tremor`: a zero-phase low-pass of every joint;
2. :func:`constant_speed`: the same tool path at one tool speed, from and to rest, slowed
   down only where (and as much as) a joint would exceed its speed or acceleration limit;
3. :func:`approach`: a synchronised rest-to-rest joint move from where the robot is (or where
   the previous segment ended) to where the next segment starts.

:func:`~control.taught_path_kinematics.path_error_m` judges a replay against the taught path.
Pure functions, no I/O; the notes of :func:`replay_trajectory` (the slow-downs, the stops it
makes) go to the log. A stroke's speed profile is :mod:`control.taught_path_profile`, the
argument checks :mod:`control.taught_path_checks`.

Stops. The tool is replayed at one speed only where the operator moved it. Where the recorded
tool was (nearly) still, or pivoting about its tip while the joints turned, or reversed (a
zig-zag stroke), the replay comes to rest: constant tool speed through a reversal would need
an infinite joint acceleration. A teaching segment is therefore cut into *strokes* (tool moving,
parametrised by the tool's arc length [m], replayed at the tool speed) and *turns* (tool still,
parametrised by joint travel, replayed at the joint speed limit), each rest to rest. A segment
whose tool never moves (a pure reorientation) is one turn.
"""

from __future__ import annotations

import logging
import math
from itertools import pairwise
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from scipy.interpolate import PchipInterpolator

from control.taught_path_checks import (
    _check_within_limits,
    _finite_array,
    _joint_array,
    _per_joint,
    _require_positive,
)
from control.taught_path_kinematics import slow_down, tool_path
from control.taught_path_profile import (
    _SLOWER,
    _cruise_speed,
    _Limits,
    _percent,
    _Profile,
    _slow_down_notes,
    _stroke,
)
from control.taught_path_tremor import TREMOR_CUTOFF_HZ, remove_tremor
from gateway.robot.description import RobotDescription

if TYPE_CHECKING:
    from collections.abc import Sequence

    from gateway.program import Program

log = logging.getLogger("leadthrough.control.taught_path")

#: tool acceleration along a stroke: its ramps from and to rest, its slow-downs [m/s²]
DEFAULT_ACCEL_M_S2 = 1.0
#: joint acceleration of approaches and turns, and its limit along strokes [rad/s²]
DEFAULT_JOINT_ACCEL_RAD_S2 = 1.0
#: a recorded tool slower than this is standing still (a pause, a reversal, a pivot) [m/s]
STILL_TOOL_SPEED_M_S = 0.005
#: joints turning more than this per metre of tool travel pivot the tool about its tip [rad/m]
PIVOT_RAD_PER_M = 20.0
#: the recorded tool path turning more than this between two samples is a reversal [rad]
REVERSAL_TURN_RAD = math.radians(60.0)

_KNOT_EPS = 1e-12  #: path parameter steps below this are the same knot
_SAME_POSE_RAD = 1e-9  #: an approach shorter than this is not needed [rad]
_TURN_RAD = 0.01  #: a stop whose joints turn more than this is a reorientation [rad]
_TURN_KNOT_RAD = 1e-4  #: a turn follows the recorded joints to this [rad], not their noise
_QUINTIC_PEAK_SPEED = 1.875  #: max of d/du (10u³ - 15u⁴ + 6u⁵)
_QUINTIC_PEAK_ACCEL = 10.0 / math.sqrt(3.0)  #: max of d²/du² (10u³ - 15u⁴ + 6u⁵)


class Resampled(NamedTuple):
    """One teaching segment as :func:`constant_speed` replays it, sampled every ``dt_s``."""

    q_rad: np.ndarray  #: (K, n) joint positions
    dq_rad_s: np.ndarray  #: (K, n) their time derivative
    #: the strokes' cruise tool speed: the highest the joint limits allow over at least half of
    #: the strokes' length, so the request unless they slow the tool over most of it (the
    #: request when there is no stroke); the tool runs slower only where the notes say
    speed_m_s: float
    notes: tuple[str, ...]  #: where the replay differs from the request or the recording


class ReplaySegment(NamedTuple):
    """One piece of a replay: ``approach/k`` (to the start of teaching segment k) or
    ``taught/k``; each starts and ends at rest, and starts where the previous one ended."""

    label: str
    q_rad: np.ndarray  #: (K, n)
    dq_rad_s: np.ndarray  #: (K, n)


# --- trajectories -------------------------------------------------------------------------


def constant_speed(
    desc: RobotDescription,
    t_s: np.ndarray,
    q_rad: np.ndarray,
    speed_m_s: float,
    dt_s: float,
    accel_m_s2: float = DEFAULT_ACCEL_M_S2,
    *,
    max_joint_speed_rad_s: float | Sequence[float] | np.ndarray,
    max_joint_accel_rad_s2: float | Sequence[float] | np.ndarray = DEFAULT_JOINT_ACCEL_RAD_S2,
    cutoff_hz: float | None = TREMOR_CUTOFF_HZ,
) -> Resampled:
    """One teaching segment (times (T,) [s], joint positions (T, n) [rad]) replayed along the
    same tool path at ``speed_m_s`` [m/s], sampled every ``dt_s`` [s], from rest to rest.

    The recording is first low-passed (:func:`remove_tremor`, ``cutoff_hz``; None: as given)
    and cut into strokes and turns (module docstring). A stroke is parametrised by the tool's
    cumulative arc length s [m] (joints by PCHIP in s, monotone between knots, so no overshoot
    of the taught joint range) and played with a time-optimal speed profile v(s) = ṡ
    (:func:`_stroke`): at ``speed_m_s`` wherever the joints allow it, from and to rest, v
    changing at most at ``accel_m_s2``. A turn (the tool still while joints move) is
    parametrised by joint travel Σ max_j |Δq_j| / ω_j and played with its fastest joint at
    its limit ω_j, ramping at ``max_joint_accel_rad_s2``.

    Joint limits: speed ω (``max_joint_speed_rad_s``, one value or one per joint [rad/s]; the
    robot description carries none, the cell's ``[control] max_velocity_rad_s`` is the
    ceiling) and acceleration α (``max_joint_accel_rad_s2``, likewise [rad/s²]). Where a
    stroke at ``speed_m_s`` would turn a joint faster than ω, the tool slows down there only,
    to the speed that joint allows, braking before and speeding up after within the tool
    and joint accelerations; the rest of the stroke keeps ``speed_m_s``. The notes say which
    joint slowed the tool, to what speed and over which share of the strokes' length, and
    how much longer the joint accelerations made the strokes (when over 1 %). Each returned
    sample is within ω; along strokes the joint accelerations keep to α approximately (the
    bounds hold on the profile's grid, not between its points).
    Raises ValueError naming the joint and sample when the recording leaves the
    description's joint limits (then the program is not for this robot).
    """
    n = desc.n_dof
    for name, value in (("speed_m_s", speed_m_s), ("dt_s", dt_s), ("accel_m_s2", accel_m_s2)):
        _require_positive(value, name)
    omega = _per_joint(max_joint_speed_rad_s, n, "max_joint_speed_rad_s")
    alpha = _per_joint(max_joint_accel_rad_s2, n, "max_joint_accel_rad_s2")
    t = _finite_array(t_s, "t_s")
    q = _joint_array(q_rad, n, "q_rad")
    if t.shape != (q.shape[0],):
        raise ValueError(f"t_s {t.shape} must have one time per row of q_rad {q.shape}")
    if t.size == 0:
        raise ValueError("the segment has no samples")
    _check_within_limits(desc, q, t)
    notes: list[str] = []
    q_f = q if cutoff_hz is None else remove_tremor(t, q, cutoff_hz)
    clipped = np.clip(q_f, desc.lower_rad, desc.upper_rad)
    if np.any(clipped != q_f):
        over = float(np.abs(clipped - q_f).max())
        notes.append(f"the low-pass overshot a joint limit by {over:.2g} rad; clipped to it")
        q_f = clipped
    if len(q_f) == 1:
        return Resampled(q_f.copy(), np.zeros_like(q_f), 0.0, ())

    p = tool_path(desc, q_f)
    step_p = np.diff(p, axis=0)
    dp = np.linalg.norm(step_p, axis=1)
    dq = np.abs(np.diff(q_f, axis=0))
    pieces = _strokes_and_turns(dp, dq, np.diff(t), step_p)
    ramp_s = float(np.max(omega / alpha))  # turns: the fastest joint reaches ω in this time
    limits = _Limits(speed_m_s, accel_m_s2, omega, alpha, 1.0 / ramp_s, dt_s)
    q_out, dq_out, profiles, margin = _play_pieces(pieces, q_f, dp, limits)
    speed = _cruise_speed(profiles, speed_m_s)
    notes.extend(_slow_down_notes(desc, profiles, speed_m_s, omega))
    if margin < _SLOWER:
        notes.append(
            f"the interpolated joints would exceed their speed limits: replayed with the "
            f"limits lowered by {_percent(1.0 - margin)} where they bind"
        )
    if not any(stroke for stroke, _, _ in pieces):
        notes.append(
            f"the tool point barely moves ({dp.sum() * 1e3:.1f} mm of path): replayed by joint "
            "travel, the fastest joint at its speed limit"
        )
    else:
        # a still start or end (the operator taking or letting go of the gun) is no stop
        stops = len(pieces) - 1 - (not pieces[0][0]) - (not pieces[-1][0])
        turns = sum(
            1
            for stroke, i0, i1 in pieces[1:-1]
            if not stroke and dq[i0:i1].sum(axis=0).max() > _TURN_RAD
        )
        if stops > 0:
            notes.append(
                f"the recorded tool stops {stops} time(s) on its way (a pause, reversal or "
                f"pivot; {turns} with the joints turning): the replay comes to rest there"
            )
    short = sum(not profile.reached for profile in profiles)
    if short:
        notes.append(
            f"{short} stroke(s) too short to reach {speed:.3g} m/s at {accel_m_s2} m/s² "
            "within the joint limits"
        )
    return Resampled(q_out, dq_out, speed, tuple(notes))


def _strokes_and_turns(
    dp: np.ndarray, dq: np.ndarray, dt: np.ndarray, step_p: np.ndarray
) -> list[tuple[bool, int, int]]:
    """Cut the samples into pieces (is_stroke, first sample, last sample), consecutive pieces
    sharing their boundary sample. An interval belongs to a stroke when the recorded tool moves
    at >= STILL_TOOL_SPEED_M_S and no joint turns more than PIVOT_RAD_PER_M per metre of it;
    a stroke is also cut where the tool path turns by more than REVERSAL_TURN_RAD."""
    moving = (dp >= STILL_TOOL_SPEED_M_S * dt) & (dq.max(axis=1) <= PIVOT_RAD_PER_M * dp)
    cuts = set(np.flatnonzero(np.diff(moving.astype(np.int8))) + 1)
    both = moving[:-1] & moving[1:]
    cos_turn = np.sum(step_p[:-1] * step_p[1:], axis=1) / np.maximum(dp[:-1] * dp[1:], 1e-300)
    cuts |= set(np.flatnonzero(both & (cos_turn < math.cos(REVERSAL_TURN_RAD))) + 1)
    bounds = [0, *sorted(int(c) for c in cuts), len(dp)]
    return [(bool(moving[a]), a, b) for a, b in pairwise(bounds)]


def _play_pieces(
    pieces: list[tuple[bool, int, int]], q: np.ndarray, dp: np.ndarray, limits: _Limits
) -> tuple[np.ndarray, np.ndarray, list[_Profile], float]:
    """Each piece rest to rest, joined (the shared boundary sample once); also the strokes'
    speed profiles and the least factor the joint speed limits were lowered by (below).
    Strokes: :func:`_stroke`. Turns run along knots _TURN_KNOT_RAD apart (the filtered noise
    of a pause is no path to follow), parametrised by Σ max_j |Δq_j| / ω_j, which advances at
    1 s/s (the fastest joint at its limit) after ramping up at ``limits.turn_accel`` [1/s].
    A piece whose interpolated joints still exceed a speed limit (PCHIP can be steeper than
    its knots' secants, and sampling moves) is played again with the limits lowered by the
    excess."""
    qs, dqs, profiles, margin = [q[:1]], [np.zeros_like(q[:1])], [], 1.0
    for stroke, i0, i1 in pieces:
        if stroke:
            q_piece, ds = q[i0 : i1 + 1], dp[i0:i1]
        else:
            q_piece = q[i0 + _thinned(q[i0 : i1 + 1], _TURN_KNOT_RAD)]
            ds = (np.abs(np.diff(q_piece, axis=0)) / limits.omega).max(axis=1)
        knots = _knots(q_piece, np.r_[0.0, np.cumsum(ds)])
        if knots is None:
            continue
        scale = 1.0  # of the joint speed limits
        for _ in range(5):
            if stroke:
                q_out, dq_out, profile = _stroke(*knots, limits, scale)
            else:
                q_out, dq_out = _rest_to_rest(*knots, scale, limits.turn_accel, limits.dt_s)
            over = float(np.max(np.abs(dq_out) / limits.omega))
            if over <= 1.0:
                break
            scale /= over * (1.0 + 1e-4)
        else:  # pragma: no cover - each pass lowers the limits by the excess of the last
            raise AssertionError(f"joint speed still {over:.6f} x its limit after slowing down")
        if stroke:
            profiles.append(profile)
        margin = min(margin, scale)
        qs.append(q_out[1:])
        dqs.append(dq_out[1:])
    return np.vstack(qs), np.vstack(dqs), profiles, margin


def _thinned(q: np.ndarray, tol_rad: float) -> np.ndarray:
    """Indices of the rows of q (m, n) to keep: the first, each one more than ``tol_rad`` (any
    joint) from the last kept, and the last."""
    keep, last = [0], q[0]
    for i in range(1, len(q) - 1):
        if np.max(np.abs(q[i] - last)) > tol_rad:
            keep.append(i)
            last = q[i]
    if len(q) > 1:
        keep.append(len(q) - 1)
    return np.array(keep)


def _knots(q: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Knots (s from 0, q) of positions q (m, n) at path parameter s (m,), non-decreasing:
    knots closer than _KNOT_EPS in s merge (the path parameter stood still), the last sample
    is the last knot. None when the path has no length."""
    keep = np.r_[True, np.diff(s) > _KNOT_EPS]
    keep[np.flatnonzero(keep)[-1]] = False  # the last knot is the last sample itself
    keep[-1] = True
    knots_s, knots_q = s[keep], q[keep]
    if len(knots_s) < 2 or knots_s[-1] - knots_s[0] <= _KNOT_EPS:
        return None
    return knots_s - knots_s[0], knots_q


def _rest_to_rest(
    knots_s: np.ndarray, knots_q: np.ndarray, rate: float, accel: float, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Positions knots_q (m, n) at path parameter knots_s (m,), from 0, increasing, played
    from rest to rest: ṡ ramps at ``accel`` to ``rate`` (or as far as the length allows),
    cruises, ramps down; sampled every ``dt_s``, the total time stretched (slower by < one
    sample) to a whole number of samples. Returns (q, dq)."""
    length = float(knots_s[-1])
    ramp_s = rate / accel
    if length < rate * ramp_s:  # triangular: ramp up and straight down again
        rate = math.sqrt(length * accel)
        ramp_s = rate / accel
    total_s = length / rate + ramp_s
    samples = max(1, math.ceil(total_s / dt_s - 1e-9))
    stretch = samples * dt_s / total_s  # >= 1: slower by less than one sample
    rate, ramp_s, total_s = rate / stretch, ramp_s * stretch, samples * dt_s
    accel = rate / ramp_s
    t = np.arange(samples + 1) * dt_s
    to_end = np.clip(total_s - t, 0.0, None)
    along = np.where(
        t < ramp_s,
        0.5 * accel * t**2,
        np.where(to_end > ramp_s, rate * (t - 0.5 * ramp_s), length - 0.5 * accel * to_end**2),
    )
    along_rate = np.where(t < ramp_s, accel * t, np.where(to_end > ramp_s, rate, accel * to_end))
    along = np.clip(along, 0.0, length)
    along[-1], along_rate[[0, -1]] = length, 0.0
    path = PchipInterpolator(knots_s, knots_q, axis=0)
    q_out = path(along)
    dq_out = path.derivative()(along) * along_rate[:, None]
    q_out[0], q_out[-1] = knots_q[0], knots_q[-1]
    return q_out, dq_out


def approach(
    q_from: np.ndarray,
    q_to: np.ndarray,
    dt_s: float,
    max_joint_speed_rad_s: float | Sequence[float] | np.ndarray,
    max_joint_accel_rad_s2: float | Sequence[float] | np.ndarray = DEFAULT_JOINT_ACCEL_RAD_S2,
) -> tuple[np.ndarray, np.ndarray]:
    """A rest-to-rest joint move (q (K, n) [rad], dq (K, n) [rad/s]) from ``q_from`` to
    ``q_to`` along the straight line in joint space, all joints on one quintic time law
    q = q_from + (10u³ - 15u⁴ + 6u⁵)(q_to - q_from), u = t/T (zero speed and acceleration at
    both ends), T the shortest whole number of samples keeping every joint within its speed
    (peak 1.875 Δ/T) and acceleration (peak 5.77 Δ/T²) limits. The first sample is
    ``q_from``, the last exactly ``q_to``. Already there (within 1e-9 rad): (0, n) arrays."""
    _require_positive(dt_s, "dt_s")
    a = _finite_array(q_from, "q_from")
    b = _finite_array(q_to, "q_to")
    if a.ndim != 1 or a.shape != b.shape:
        raise ValueError(f"q_from {a.shape} and q_to {b.shape} must be two (n,) poses")
    omega = _per_joint(max_joint_speed_rad_s, a.size, "max_joint_speed_rad_s")
    alpha = _per_joint(max_joint_accel_rad_s2, a.size, "max_joint_accel_rad_s2")
    delta = b - a
    if np.max(np.abs(delta), initial=0.0) <= _SAME_POSE_RAD:
        return np.zeros((0, a.size)), np.zeros((0, a.size))
    duration_s = float(
        np.max(
            np.maximum(
                _QUINTIC_PEAK_SPEED * np.abs(delta) / omega,
                np.sqrt(_QUINTIC_PEAK_ACCEL * np.abs(delta) / alpha),
            )
        )
    )
    samples = max(1, math.ceil(duration_s / dt_s - 1e-9))
    u = np.arange(samples + 1) / samples
    progress = u**3 * (10 - 15 * u + 6 * u**2)
    rate = 30 * u**2 * (1 - u) ** 2 / (samples * dt_s)
    q = a + progress[:, None] * delta
    q[0], q[-1] = a, b
    return q, rate[:, None] * delta


def replay_trajectory(
    program: Program,
    desc: RobotDescription,
    q_now: np.ndarray,
    dt_s: float,
    speed_m_s: float,
    cutoff_hz: float | None = TREMOR_CUTOFF_HZ,
    *,
    max_joint_speed_rad_s: float | Sequence[float] | np.ndarray,
    accel_m_s2: float = DEFAULT_ACCEL_M_S2,
    max_joint_accel_rad_s2: float | Sequence[float] | np.ndarray = DEFAULT_JOINT_ACCEL_RAD_S2,
    max_point_speed_m_s: float | None = None,
) -> list[ReplaySegment]:
    """A taught program as replay segments sampled every ``dt_s`` [s]: ``approach/1`` from
    ``q_now`` [rad] to the start of teaching segment 1, ``taught/1`` (:func:`constant_speed`
    at ``speed_m_s`` [m/s], tremor removed at ``cutoff_hz``), ``approach/2`` from its end to
    the start of segment 2 (left out where there is nothing to approach), ``taught/2``, ...

    Every segment starts and ends at rest; consecutive segments share their boundary pose.
    Positions stay within the description's joint limits and speeds within
    ``max_joint_speed_rad_s``. Raises ValueError (naming the segment, sample and joint) for a
    program that does not fit this robot, a non-finite value, or ``q_now`` outside the limits.
    The notes of :func:`constant_speed` (slow-downs, stops) are logged as warnings.

    With ``max_point_speed_m_s``, a segment on which the tool point or the flange would pass
    it (an approach's joint move far from the base; a taught stroke whose tool turns, which
    swings the flange about the tool point) is played that much slower (:func:`slow_down`),
    with a warning: the CAN driver's speed monitor stops a replay that passes 250 mm/s.
    """
    n = desc.n_dof
    if len(program.joints) != n or program.q_rad.shape[1:] != (n,):
        raise ValueError(
            f"{program.path}: the program has {len(program.joints)} joints "
            f"{program.joints}; {desc.name} has {n}"
        )
    here = _finite_array(q_now, "q_now")
    if here.shape != (n,):
        raise ValueError(f"q_now must be {n} joint positions, got shape {here.shape}")
    try:
        _check_within_limits(desc, here[None, :])
    except ValueError as exc:
        raise ValueError(f"the robot is outside its joint limits: {exc}") from None
    segments = program.segments()
    if not segments:
        raise ValueError(f"{program.path}: the program has no trace samples to replay")
    out: list[ReplaySegment] = []
    for k, (t, q) in enumerate(segments, 1):
        try:
            played = constant_speed(
                desc, t, q, speed_m_s, dt_s, accel_m_s2, cutoff_hz=cutoff_hz,
                max_joint_speed_rad_s=max_joint_speed_rad_s,
                max_joint_accel_rad_s2=max_joint_accel_rad_s2,
            )  # fmt: skip
        except ValueError as exc:
            raise ValueError(f"{program.path}: teaching segment {k}, {exc}") from None
        for note in played.notes:
            log.warning("%s: teaching segment %d: %s", program.path, k, note)
        q_a, dq_a = approach(
            here, played.q_rad[0], dt_s, max_joint_speed_rad_s, max_joint_accel_rad_s2
        )
        pieces = [(f"approach/{k}", q_a, dq_a), (f"taught/{k}", played.q_rad, played.dq_rad_s)]
        for label, q, dq in pieces:
            if not len(q):
                continue
            if max_point_speed_m_s is not None:
                q, dq, factor = slow_down(desc, q, dq, dt_s, max_point_speed_m_s)
                if factor > 1.0:
                    log.warning("%s: %s played %.2f times slower: the tool or the flange would "
                                "pass %.3g m/s", program.path, label, factor,
                                max_point_speed_m_s)  # fmt: skip
            out.append(ReplaySegment(label, q, dq))
        here = played.q_rad[-1]
    return out
