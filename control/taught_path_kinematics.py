"""The tool and flange along a taught or replayed joint path: :func:`tool_path`, the
fastest point (:func:`fastest_point_m_s`) and a path played slower to keep under a point
speed (:func:`slow_down`, the CAN driver's speed monitor), and :func:`path_error_m`, which
judges a replay against the taught path."""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import CubicHermiteSpline
from scipy.spatial import cKDTree

from control.taught_path_checks import _joint_array
from gateway.robot.description import RobotDescription
from gateway.robot.kinematics import dh_tool_and_flange

_NEAREST_SEGMENTS = 8  #: polyline segments tried first per point in path_error_m


def tool_path(desc: RobotDescription, q_rad: np.ndarray) -> np.ndarray:
    """Tool point in the world (T, 3) [m] at each joint position (T, n) [rad], by
    :func:`gateway.robot.kinematics.dh_tool_and_flange`."""
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
