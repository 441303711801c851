"""A stroke's time-optimal speed profile (:func:`_stroke`): the tool along its arc length
at the requested speed wherever the joint speed and acceleration limits allow it, from and
to rest, slowed down only where (and as much as) a joint would exceed a limit; and the notes
saying where and by how much the strokes were slowed (:func:`_slow_down_notes`). Used by
:func:`control.taught_path.constant_speed`."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.interpolate import PchipInterpolator

from gateway.robot.description import RobotDescription

_PROFILE_STEP_M = 0.5e-3  #: arc-length grid of a stroke's speed profile [m]
_MIN_PROFILE_STEPS = 50  #: a short stroke's grid has this many steps all the same
_MAX_PROFILE_STEPS = 20_000  #: a long stroke's grid is coarser (the passes loop in Python)
_FLAT_RAD_PER_M = 1e-9  #: |dq/ds| below this is a joint standing still along the path
_SLOWER = 0.99  #: a tool below this fraction of a speed counts as slowed (notes)
_NOTE_LONGER = 0.01  #: joint accelerations lengthening the strokes more than this are noted


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
