"""Taught programs made replayable: hand tremor out, one tool speed, approaches in between.

A taught program (:mod:`gateway.program`) holds the joint positions recorded at ~100 Hz while an
operator dragged the spray gun by hand. Played back as recorded it would repeat the operator's
tremor and uneven pace, and a coat needs the gun at one speed. :func:`replay_trajectory` turns
each teaching segment into a joint trajectory sampled at the controller period:

1. :func:`remove_tremor`: a zero-phase low-pass of every joint;
2. :func:`constant_speed`: the same tool path at one tool speed, from and to rest, slowed
   down only where (and as much as) a joint would exceed its speed or acceleration limit;
3. :func:`approach`: a synchronised rest-to-rest joint move from where the robot is (or where
   the previous segment ended) to where the next segment starts.

:func:`path_error_m` judges a replay against the taught path. Pure functions, no I/O; the
notes of :func:`replay_trajectory` (the slow-downs, the stops it makes) go to the log.

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
from scipy.interpolate import CubicHermiteSpline, PchipInterpolator
from scipy.signal import butter, sosfiltfilt
from scipy.spatial import cKDTree

from control.robot.description import RobotDescription
from control.robot.kinematics import dh_tool_and_flange

if TYPE_CHECKING:
    from collections.abc import Sequence

    from gateway.program import Program

log = logging.getLogger("leadthrough.control.taught_path")

#: tremor low-pass cut-off [Hz], -6 dB point of the zero-phase filter (see remove_tremor)
TREMOR_CUTOFF_HZ = 2.5
#: order of the Butterworth design; sosfiltfilt runs it forward and backward (|H|² overall)
TREMOR_FILTER_ORDER = 4
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

_MIN_FILTER_SAMPLES = 3  #: fewer samples are returned unfiltered
#: shorter segments (in cut-off periods) are returned unfiltered: on a synthetic 0.6 s move
#: the low-pass erred more than the tremor it removed
_MIN_FILTER_PERIODS = 2.0
_MAX_RESAMPLE_FACTOR = 100  #: uniform grid at most this many times the samples (a time gap)
_MAX_CUTOFF_OF_NYQUIST = 0.8  #: the cut-off must lie well below the Nyquist frequency
_KNOT_EPS = 1e-12  #: path parameter steps below this are the same knot
_SAME_POSE_RAD = 1e-9  #: an approach shorter than this is not needed [rad]
_TURN_RAD = 0.01  #: a stop whose joints turn more than this is a reorientation [rad]
_TURN_KNOT_RAD = 1e-4  #: a turn follows the recorded joints to this [rad], not their noise
_QUINTIC_PEAK_SPEED = 1.875  #: max of d/du (10u³ - 15u⁴ + 6u⁵)
_QUINTIC_PEAK_ACCEL = 10.0 / math.sqrt(3.0)  #: max of d²/du² (10u³ - 15u⁴ + 6u⁵)
_NEAREST_SEGMENTS = 8  #: polyline segments tried first per point in path_error_m
_PROFILE_STEP_M = 0.5e-3  #: arc-length grid of a stroke's speed profile [m]
_MIN_PROFILE_STEPS = 50  #: a short stroke's grid has this many steps all the same
_MAX_PROFILE_STEPS = 20_000  #: a long stroke's grid is coarser (the passes loop in Python)
_FLAT_RAD_PER_M = 1e-9  #: |dq/ds| below this is a joint standing still along the path
_SLOWER = 0.99  #: a tool below this fraction of a speed counts as slowed (notes)
_NOTE_LONGER = 0.01  #: joint accelerations lengthening the strokes more than this are noted


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


# --- tremor -------------------------------------------------------------------------------


def remove_tremor(
    t_s: np.ndarray, q_rad: np.ndarray, cutoff_hz: float = TREMOR_CUTOFF_HZ
) -> np.ndarray:
    """Joint positions (T, n) or (T,) [rad] at times ``t_s`` (T,) [s] with the hand tremor
    low-passed away, at the same times.

    Filter: Butterworth of order :data:`TREMOR_FILTER_ORDER` (4) run forward and backward
    (``sosfiltfilt``): no phase lag, so the path is not shifted, and |H(f)|² = 1 / (1 +
    (f/f_c)^8) overall, -6 dB at f_c. Physiological hand tremor lies at 4-12 Hz, a painter's
    deliberate motion below ~1.5 Hz. f_c = 2.5 Hz sits midway between 1.5 and 4 Hz on a log
    scale: 1.5 Hz keeps 98 % (at 2 Hz it would keep 91 %), 4 Hz is cut 44x, 8 Hz 11,000x.

    Non-uniform time: the samples are interpolated (linearly) onto a uniform grid at their
    median rate, filtered, and interpolated back. Ends: each end is extended by a least-squares
    quadratic through its first 1/(2 f_c) s (value, slope and curvature carry on) plus the
    samples' deviation from it reflected through the end (:func:`_odd_extension`).
    sosfiltfilt's own odd reflection about the raw end sample flips the path's curvature
    there: on the tests' 0.3 Hz sweep a bias of up to 1.3 mm at the tool, 0.2 mm this way.
    The first and last ~50 ms keep part of the tremor all the same: there is no later sample
    to average it with. A segment shorter than two periods of the cut-off (0.8 s), or of
    fewer than 3 samples, is returned unfiltered: too short to tell tremor from motion.
    Raises ValueError on non-finite values, times that do not increase, or a cut-off the
    sample rate cannot carry.
    """
    t = _finite_array(t_s, "t_s")
    q = _finite_array(q_rad, "q_rad")
    if t.ndim != 1 or q.ndim not in (1, 2) or q.shape[0] != t.size:
        raise ValueError(f"t_s must be (T,) and q_rad (T,) or (T, n); got {t.shape}, {q.shape}")
    if not (math.isfinite(cutoff_hz) and cutoff_hz > 0):
        raise ValueError(f"cutoff_hz must be a finite frequency > 0, got {cutoff_hz!r}")
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise ValueError(f"t_s must increase: sample {k} at {t[k]!r} s follows {t[k - 1]!r} s")
    if t.size < _MIN_FILTER_SAMPLES or t[-1] - t[0] < _MIN_FILTER_PERIODS / cutoff_hz:
        return q.copy()  # too short to tell tremor from motion
    y = q.reshape(t.size, -1)
    duration = float(t[-1] - t[0])
    n_uniform = max(_MIN_FILTER_SAMPLES, round(duration / float(np.median(steps))) + 1)
    if n_uniform > _MAX_RESAMPLE_FACTOR * t.size:
        gap = int(np.argmax(steps))
        raise ValueError(
            f"t_s has a gap of {steps[gap]:.3f} s after sample {gap} in samples "
            f"{np.median(steps):.4f} s apart: a uniform grid would be too large"
        )
    fs_hz = (n_uniform - 1) / duration
    if cutoff_hz >= _MAX_CUTOFF_OF_NYQUIST * fs_hz / 2:
        raise ValueError(
            f"a {cutoff_hz} Hz tremor cut-off needs samples faster than "
            f"{2 * cutoff_hz / _MAX_CUTOFF_OF_NYQUIST:.1f} Hz; these come at {fs_hz:.1f} Hz"
        )
    t_u = np.linspace(t[0], t[-1], n_uniform)
    y_u = np.column_stack([np.interp(t_u, t, y[:, j]) for j in range(y.shape[1])])
    y_f = _zero_phase_lowpass(y_u, fs_hz, cutoff_hz)
    out = np.column_stack([np.interp(t, t_u, y_f[:, j]) for j in range(y.shape[1])])
    return out.reshape(q.shape)


def _zero_phase_lowpass(y: np.ndarray, fs_hz: float, cutoff_hz: float) -> np.ndarray:
    """sosfiltfilt of uniform samples y (N, n) with the ends extended (remove_tremor)."""
    sos = butter(TREMOR_FILTER_ORDER, cutoff_hz, fs=fs_hz, output="sos")
    n = y.shape[0]
    window = int(np.clip(round(fs_hz / (2 * cutoff_hz)), 3, n))
    pad = math.ceil(3 * fs_hz / cutoff_hz)  # ~3 periods of the cut-off: the start-up dies out
    front = _odd_extension(y, window, pad)
    back = _odd_extension(y[::-1], window, pad)[::-1]
    out = sosfiltfilt(sos, np.vstack([front, y, back]), axis=0, padtype=None)
    return out[pad : pad + n]


def _odd_extension(y: np.ndarray, window: int, pad: int) -> np.ndarray:
    """``pad`` rows to put before y (N, n): y(-k) = Q(-k) - (y(k) - Q(k)) for k = pad..1, Q the
    least-squares quadratic through the first ``window`` rows (y(k) - Q(k) taken as 0 for
    k >= N). The trend Q carries on with its value, slope and curvature; the tremor about it
    is reflected through the fitted end value, so the end sample's own tremor is not taken as
    the end point."""
    x = np.arange(window, dtype=float)
    basis = np.column_stack([np.ones_like(x), x, x**2])
    coef = np.linalg.lstsq(basis, y[:window], rcond=None)[0]
    k = np.arange(pad, 0, -1)
    trend = np.column_stack([np.ones(pad), -k, k**2]) @ coef
    mirrored = k < y.shape[0]
    kk = k[mirrored]
    trend[mirrored] -= y[kk] - np.column_stack([np.ones(kk.size), kk, kk**2]) @ coef
    return trend


# --- kinematics ---------------------------------------------------------------------------


def tool_path(desc: RobotDescription, q_rad: np.ndarray) -> np.ndarray:
    """Tool point in the world (T, 3) [m] at each joint position (T, n) [rad], by
    :func:`control.robot.kinematics.dh_tool_and_flange`."""
    q = _joint_array(q_rad, desc.n_dof, "q_rad")
    return dh_tool_and_flange(desc, q.reshape(-1, desc.n_dof))[0]


def fastest_point_m_s(desc: RobotDescription, q_rad: np.ndarray, dt_s: float) -> float:
    """The highest speed [m/s] of the tool point or the flange along joint samples (T, n)
    [rad] ``dt_s`` apart (from positions, as the CAN driver's speed monitor measures it);
    0 for fewer than two samples."""
    if len(q_rad) < 2:
        return 0.0
    tool, flange = dh_tool_and_flange(desc, q_rad)
    step = max(
        float(np.max(np.linalg.norm(np.diff(tool, axis=0), axis=1))),
        float(np.max(np.linalg.norm(np.diff(flange, axis=0), axis=1))),
    )
    return step / dt_s


def slow_down(
    desc: RobotDescription, q_rad: np.ndarray, dq_rad_s: np.ndarray, dt_s: float, limit_m_s: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """The same joint path played slower, uniformly in time, so that neither the tool point
    nor the flange passes ``limit_m_s`` [m/s]: (q, dq, factor), factor >= 1 the time stretch
    (1: unchanged). Rest-to-rest stays rest-to-rest (cubic Hermite through the samples and
    their velocities, resampled at ``dt_s``)."""
    factor = 1.0
    q, dq = q_rad, dq_rad_s
    for _ in range(4):  # the resampled curve can bulge a little: check again
        fastest = fastest_point_m_s(desc, q, dt_s)
        if fastest <= limit_m_s:
            return q, dq, factor
        stretch = fastest / limit_m_s * 1.01
        k = len(q_rad) - 1
        samples = max(1, math.ceil(k * factor * stretch - 1e-9))
        factor = samples / k
        t = np.arange(k + 1) * dt_s
        spline = CubicHermiteSpline(t, q_rad, dq_rad_s, axis=0)
        t_new = np.arange(samples + 1) * dt_s / factor
        t_new[-1] = t[-1]
        q = spline(t_new)
        dq = spline.derivative()(t_new) / factor
        q[0], q[-1], dq[0], dq[-1] = (
            q_rad[0],
            q_rad[-1],
            dq_rad_s[0] / factor,
            dq_rad_s[-1] / factor,
        )
    raise ValueError(f"cannot slow the path under {limit_m_s} m/s (still {fastest:.3g} m/s)")


def path_error_m(desc: RobotDescription, q_taught: np.ndarray, q_replayed: np.ndarray) -> float:
    """How far a replay strays from the taught path [m]: the 95th percentile, over the replayed
    samples, of the tool point's distance to the nearest point of the taught tool path (the
    polyline through the taught samples)."""
    taught, replayed = tool_path(desc, q_taught), tool_path(desc, q_replayed)
    if not (taught.size and replayed.size):
        raise ValueError("path_error_m needs at least one taught and one replayed sample")
    return float(np.quantile(_polyline_distance(taught, replayed), 0.95))


def _polyline_distance(vertices: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance [m] of each point (m, 3) to the polyline through vertices (B, 3): first the
    segments with the nearest midpoints (k-d tree), then, where a segment outside those could
    still be closer, every segment whose midpoint is near enough to be."""
    if len(vertices) == 1:
        return np.linalg.norm(points - vertices[0], axis=1)
    start, step = vertices[:-1], np.diff(vertices, axis=0)
    half_max = 0.5 * float(np.linalg.norm(step, axis=1).max())
    tree = cKDTree(start + 0.5 * step)
    k = min(_NEAREST_SEGMENTS, len(start))
    d_mid, idx = tree.query(points, k=k)
    d_mid, idx = d_mid.reshape(len(points), k), idx.reshape(len(points), k)
    best = _segment_distance(points[:, None, :], start[idx], step[idx]).min(axis=1)
    # a segment is no closer than its midpoint's distance less half_max: only those whose
    # midpoint lies within best + half_max can beat best
    unsure = np.flatnonzero(best > d_mid[:, -1] - half_max) if k < len(start) else []
    for i in unsure:
        near = tree.query_ball_point(points[i], best[i] + half_max)
        if near:
            best[i] = _segment_distance(points[i], start[near], step[near]).min()
    return best


def _segment_distance(p: np.ndarray, start: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Distance from p to the segment start + u·step, u in [0, 1] (broadcast over leading axes)."""
    length2 = np.sum(step * step, axis=-1)
    u = np.sum((p - start) * step, axis=-1) / np.where(length2 > 0, length2, 1.0)
    u = np.clip(u, 0.0, 1.0)
    return np.linalg.norm(p - (start + u[..., None] * step), axis=-1)


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


class _Limits(NamedTuple):
    """What a replay may do (constant_speed's arguments)."""

    speed_m_s: float  #: tool speed requested
    accel_m_s2: float  #: tool acceleration
    omega: np.ndarray  #: (n,) joint speed limits [rad/s]
    alpha: np.ndarray  #: (n,) joint acceleration limits [rad/s²]
    turn_accel: float  #: a turn's path parameter's acceleration [1/s] (_play_pieces)
    dt_s: float  #: sample period


class _Profile(NamedTuple):
    """A stroke's speed profile on its arc-length grid (N + 1 points), for the notes."""

    weight_m: np.ndarray  #: (N+1,) length each grid point stands for (trapezoid rule) [m]
    v_m_s: np.ndarray  #: (N+1,) the tool speed played
    v_free_m_s: np.ndarray  #: (N+1,) ... were the joint accelerations unlimited
    v_joint_m_s: np.ndarray  #: (N+1,) the highest the joint speeds allow, at most the request
    v_cap_m_s: np.ndarray  #: (N+1,) ... the joint speeds and path bends allow
    binding: np.ndarray  #: (N+1,) the joint whose speed limit sets v_joint_m_s
    rad_per_m: np.ndarray  #: (n,) each joint's steepest |dq/ds| on the stroke
    reached: bool  #: the tool reaches the highest speed the limits allow somewhere
    time_s: float  #: the stroke's duration (before the stretch to whole samples)
    time_free_s: float  #: ... were the joint accelerations unlimited


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


def _stroke(
    knots_s: np.ndarray, knots_q: np.ndarray, limits: _Limits, scale: float
) -> tuple[np.ndarray, np.ndarray, _Profile]:
    """A stroke, joint positions knots_q (m, n) at the tool's arc length knots_s (m,) [m] from
    0, played from rest to rest as fast as the limits allow (time-optimal path
    parametrisation), sampled every ``limits.dt_s``. Returns (q, dq, profile).

    On a grid of arc length s (_PROFILE_STEP_M apart) the tool speed v = ds/dt is bounded by
    the request, by ω_j·scale / |dq_j/ds| (each joint's speed limit, ``scale`` <= 1 a margin)
    and by α_j / |d²q_j/ds²| (where the joint path bends, its acceleration q'' v² alone must
    stay within α_j). The tool acceleration a = dv/dt is bounded by ``accel_m_s2`` and by
    |q''_j v² + q'_j a| <= α_j. A forward pass accelerates as hard as allowed from rest,
    a backward pass brakes as hard as allowed to rest (:func:`_speed_profile`); time follows
    from v, constant a between grid points, stretched to a whole number of samples."""
    length = float(knots_s[-1])
    path = PchipInterpolator(knots_s, knots_q, axis=0)
    slope = path.derivative()
    steps = int(
        np.clip(math.ceil(length / _PROFILE_STEP_M), _MIN_PROFILE_STEPS, _MAX_PROFILE_STEPS)
    )
    h = length / steps
    s = np.linspace(0.0, length, steps + 1)
    q1 = slope(s)  # dq/ds (N+1, n)
    # steepest |dq/ds| on each step (ends and middle), then on the two steps about each point:
    # ds/dt between two grid points is at most the larger of theirs
    cell = np.maximum(np.maximum(np.abs(q1[:-1]), np.abs(q1[1:])), np.abs(slope(s[:-1] + h / 2)))
    steep = np.vstack([cell[:1], np.maximum(cell[:-1], cell[1:]), cell[-1:]])
    bend_min, bend_max = _bend_range(path, knots_s, s)
    with np.errstate(divide="ignore"):
        v_each = limits.omega * scale / steep
        b_bend = np.min(limits.alpha / np.maximum(-bend_min, bend_max), axis=1)
    binding = np.argmin(v_each, axis=1)
    v_joint = np.minimum(limits.speed_m_s, v_each[np.arange(steps + 1), binding])
    b_cap = np.minimum(v_joint**2, b_bend)
    # joint j: |q''_j b + q'_j a| <= α_j with b = v², at its worst about each grid point
    sign = np.where(q1 < 0.0, -1.0, 1.0)
    lever = np.maximum(steep, _FLAT_RAD_PER_M)
    gain = np.column_stack([limits.alpha / lever, np.full(steps + 1, limits.accel_m_s2)])
    drag_up = np.maximum(sign * bend_min, sign * bend_max) / lever
    drag_down = np.minimum(sign * bend_min, sign * bend_max) / lever
    no_drag = np.zeros((steps + 1, 1))
    b = _speed_profile(
        b_cap, gain, np.hstack([drag_up, no_drag]), np.hstack([drag_down, no_drag]), h
    )
    b_free = _speed_profile_free(v_joint**2, limits.accel_m_s2, h)

    v = np.sqrt(b)
    step_s = 2.0 * h / np.maximum(v[:-1] + v[1:], 1e-300)  # constant acceleration per step
    t_grid = np.r_[0.0, np.cumsum(step_s)]
    samples = max(1, math.ceil(t_grid[-1] / limits.dt_s - 1e-9))
    stretch = samples * limits.dt_s / t_grid[-1]  # >= 1: slower by less than one sample
    t = np.arange(samples + 1) * limits.dt_s / stretch  # on the profile's clock
    i = np.clip(np.searchsorted(t_grid, t, side="right") - 1, 0, steps - 1)
    tau = t - t_grid[i]
    accel = (b[1:] - b[:-1]) / (2.0 * h)
    along = np.clip(s[i] + v[i] * tau + 0.5 * accel[i] * tau**2, 0.0, length)
    along_rate = np.clip(v[i] + accel[i] * tau, 0.0, None) / stretch
    along[-1], along_rate[[0, -1]] = length, 0.0
    q_out = path(along)
    dq_out = slope(along) * along_rate[:, None]
    q_out[0], q_out[-1] = knots_q[0], knots_q[-1]

    weight = np.full(steps + 1, h)
    weight[[0, -1]] = h / 2
    v_free = np.sqrt(b_free)
    profile = _Profile(
        weight_m=weight,
        v_m_s=v / stretch,
        v_free_m_s=v_free,
        v_joint_m_s=v_joint,
        v_cap_m_s=np.sqrt(b_cap),
        binding=binding,
        rad_per_m=np.abs(q1).max(axis=0),
        reached=bool(v.max() >= _SLOWER * np.sqrt(b_cap).max()),
        time_s=float(t_grid[-1]),
        time_free_s=float(np.sum(2.0 * h / np.maximum(v_free[:-1] + v_free[1:], 1e-300))),
    )
    return q_out, dq_out, profile


def _bend_range(
    path: PchipInterpolator, knots_s: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Least and greatest d²q/ds² (N+1, n) on the two grid steps about each grid point of s
    (N+1,). PCHIP is cubic between knots: d²q/ds² is linear there and jumps at knots, so its
    extremes on a step lie at the step's ends or on either side of a knot inside it."""
    steps = len(s) - 1
    inner = knots_s[1:-1]
    eps = 1e-9 * float(s[-1])
    sides = np.concatenate([inner - eps, inner + eps])
    curv = path.derivative(2)
    at_grid, at_sides = curv(s), curv(sides)
    step = np.concatenate(
        [
            np.arange(steps),  # a grid point ends one step and starts the next
            np.arange(steps),
            np.clip(np.searchsorted(s, sides, side="right") - 1, 0, steps - 1),
        ]
    )
    value = np.vstack([at_grid[:-1], at_grid[1:], at_sides])
    low = np.full((steps, value.shape[1]), np.inf)
    high = np.full((steps, value.shape[1]), -np.inf)
    np.minimum.at(low, step, value)
    np.maximum.at(high, step, value)
    low = np.vstack([low[:1], np.minimum(low[:-1], low[1:]), low[-1:]])
    high = np.vstack([high[:1], np.maximum(high[:-1], high[1:]), high[-1:]])
    return low, high


def _speed_profile(
    b_cap: np.ndarray, gain: np.ndarray, drag_up: np.ndarray, drag_down: np.ndarray, h: float
) -> np.ndarray:
    """Squared speed b = v² (N+1,) on a grid h apart: 0 at both ends, at most ``b_cap``, its
    acceleration a = db/ds / 2 within [max_k(-gain - drag_down·b), min_k(gain - drag_up·b)]
    (gain, drag_up, drag_down (N+1, K) at each grid point). A forward pass speeds up as hard
    as allowed, a backward pass brakes as hard as allowed; over each step a bound is taken at
    the end of the step where it is the tighter. Below b_cap both bounds must admit a = 0
    (the caller's job): the speed may always be held."""
    cap = b_cap.tolist()
    gain_l, up_l, down_l = gain.tolist(), drag_up.tolist(), drag_down.tolist()
    b = [0.0] * len(cap)
    for i in range(len(cap) - 1):
        bi, most = b[i], cap[i + 1]
        for g, d in zip(gain_l[i], up_l[i], strict=True):
            # a <= g - d·b: at b[i + 1] when it tightens with speed (d > 0), else at b[i]
            reach = (
                (bi + 2.0 * h * g) / (1.0 + 2.0 * h * d) if d > 0 else bi + 2.0 * h * (g - d * bi)
            )
            most = min(most, max(reach, bi))
        b[i + 1] = most
    b[-1] = 0.0
    for i in range(len(cap) - 2, -1, -1):
        bn, most = b[i + 1], b[i]
        for g, d in zip(gain_l[i + 1], down_l[i + 1], strict=True):
            # braking a >= -g - d·b: at b[i] when it tightens with speed (d < 0), else at b[i+1]
            reach = (
                (bn + 2.0 * h * g) / (1.0 - 2.0 * h * d) if d < 0 else bn + 2.0 * h * (g + d * bn)
            )
            most = min(most, max(reach, bn))
        b[i] = most
    return np.array(b)


def _speed_profile_free(b_cap: np.ndarray, accel: float, h: float) -> np.ndarray:
    """_speed_profile with the acceleration bounded by ``accel`` alone: b[i] = min over k of
    b_cap[k] + 2·accel·h·|i - k| (b_cap[0] = b_cap[-1] = 0 put in)."""
    cap = b_cap.copy()
    cap[[0, -1]] = 0.0
    ramp = 2.0 * accel * h * np.arange(len(cap))
    forward = np.minimum.accumulate(cap - ramp) + ramp
    backward = (np.minimum.accumulate((cap - ramp[::-1])[::-1]) + ramp)[::-1]
    return np.minimum(forward, backward)


def _cruise_speed(profiles: list[_Profile], speed_m_s: float) -> float:
    """The tool speed the joint limits allow over at least half of the strokes' length (the
    request where they do not slow the tool over most of it); the request without strokes."""
    if not profiles:
        return speed_m_s
    cap = np.concatenate([p.v_cap_m_s for p in profiles])
    weight = np.concatenate([p.weight_m for p in profiles])
    order = np.argsort(cap)[::-1]
    half = np.searchsorted(np.cumsum(weight[order]), 0.5 * weight.sum())
    return float(cap[order[min(half, len(order) - 1)]])


def _slow_down_notes(
    desc: RobotDescription, profiles: list[_Profile], speed_m_s: float, omega: np.ndarray
) -> list[str]:
    """Where the strokes run below the requested speed: each joint whose speed limit slows
    the tool (how much, over which share of the length), and the share the joint
    acceleration limits slow it further."""
    if not profiles:
        return []
    weight = np.concatenate([p.weight_m for p in profiles])
    total = float(weight.sum())
    v_joint = np.concatenate([p.v_joint_m_s for p in profiles])
    binding = np.concatenate([p.binding for p in profiles])
    rad_per_m = np.max([p.rad_per_m for p in profiles], axis=0)
    slowed = v_joint < _SLOWER * speed_m_s
    notes = []
    by_joint = sorted(
        ((float(weight[here].sum()), j, float(v_joint[here].min()))
         for j in range(len(omega))
         if (here := slowed & (binding == j)).any()),
        reverse=True,
    )  # fmt: skip
    if by_joint:
        share, j, low = by_joint[0]
        text = (
            f"joint {desc.joints[j].name} would turn at {rad_per_m[j] * speed_m_s:.3g} rad/s "
            f"at {speed_m_s} m/s (limit {omega[j]:.3g} rad/s): it limits the tool speed to "
            f"{low:.3g} m/s over {_percent(share / total)} of the strokes' {total:.3g} m"
        )
        text += "".join(
            f"; joint {desc.joints[j].name} to {low:.3g} m/s over {_percent(share / total)}"
            for share, j, low in by_joint[1:]
        )
        notes.append(text)
    v = np.concatenate([p.v_m_s for p in profiles])
    v_free = np.concatenate([p.v_free_m_s for p in profiles])
    further = float(weight[v < _SLOWER * v_free].sum())
    time_s = sum(p.time_s for p in profiles)
    time_free_s = sum(p.time_free_s for p in profiles)
    if time_s > (1.0 + _NOTE_LONGER) * time_free_s:
        notes.append(
            f"the joint acceleration limits slow the tool further over {_percent(further / total)}"
            f" of the strokes' length: {time_s - time_free_s:.2g} s longer"
        )
    return notes


def _percent(fraction: float) -> str:
    return f"{100 * fraction:.2g} %" if fraction < 0.1 else f"{100 * fraction:.0f} %"


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


# --- checks -------------------------------------------------------------------------------


def _finite_array(value: object, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numbers: {exc}") from None
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        where = ", ".join(str(int(i)) for i in bad[0])
        raise ValueError(f"{name} has a non-finite value {arr[tuple(bad[0])]} at [{where}]")
    return arr


def _joint_array(value: object, n: int, name: str) -> np.ndarray:
    arr = _finite_array(value, name)
    if arr.ndim != 2 or arr.shape[1] != n:
        raise ValueError(f"{name} must be (T, {n}) joint positions, got shape {arr.shape}")
    return arr


def _per_joint(value: object, n: int, name: str) -> np.ndarray:
    arr = _finite_array(value, name)
    try:
        arr = np.broadcast_to(arr, (n,)).copy()
    except ValueError:
        raise ValueError(f"{name} must be one value or {n}, got shape {arr.shape}") from None
    if np.any(arr <= 0):
        raise ValueError(f"{name} must be > 0, got {arr.tolist()}")
    return arr


def _require_positive(value: float, name: str) -> None:
    number = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool
    )
    if not (number and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def _check_within_limits(
    desc: RobotDescription, q: np.ndarray, t: np.ndarray | None = None
) -> None:
    """Raise ValueError naming the first sample and joint of q (T, n) outside the limits."""
    lower, upper = desc.lower_rad, desc.upper_rad
    bad = np.argwhere((q < lower) | (q > upper))
    if bad.size:
        i, j = (int(v) for v in bad[0])
        when = f" (t = {t[i]:.3f} s)" if t is not None else ""
        raise ValueError(
            f"sample {i}{when}: joint {desc.joints[j].name} at {q[i, j]:.4f} rad is outside "
            f"its limits [{lower[j]:.4f}, {upper[j]:.4f}] rad on {desc.name}; the taught path "
            "does not fit this robot"
        )
