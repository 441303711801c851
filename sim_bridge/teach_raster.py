"""teach-bench's painter's target: a spray raster (passes joined by steps down) as timed
waypoints from where the tool starts, laid in the plane the gun faces if asked.

The target is the painter's intent, not a path the product is told: the bench's hand pulls the
tool towards it (:mod:`sim_bridge.teach_bench`).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from sim_bridge.config import load_sim_config
from sim_bridge.teach_bench_metrics import flange_poses

#: the raster: horizontal width, covered height [m], horizontal passes
WIDTH_M, HEIGHT_M, PASSES = 1.0, 0.6, 4
#: the painter's tool speed along the path [m/s] and stop at each corner [s]
SPEED_M_S, DWELL_S = 0.1, 0.5
#: still at the start before the first leg [s]
START_S = 1.0


def raster_path(
    width_m: float = WIDTH_M,
    height_m: float = HEIGHT_M,
    passes: int = PASSES,
    speed_m_s: float = SPEED_M_S,
    dwell_s: float = DWELL_S,
    start_s: float = START_S,
) -> list[list[float]]:
    """The painter's target as ``[t_s, dx, dy, dz]`` waypoints from the tool's start: to the
    raster's top-left corner, then ``passes`` horizontal passes joined by steps down."""
    if passes < 2 or width_m <= 0 or height_m <= 0 or speed_m_s <= 0:
        raise ValueError("a raster needs >= 2 passes, a positive size and speed")
    corners = [(0.0, 0.0)]
    for k in range(passes):
        z = height_m / 2 - k * height_m / (passes - 1)
        ends = (-width_m / 2, width_m / 2) if k % 2 == 0 else (width_m / 2, -width_m / 2)
        corners += [(ends[0], z), (ends[1], z)]
    path = [[0.0, 0.0, 0.0, 0.0], [start_s, 0.0, 0.0, 0.0]]
    t = start_s
    for (y0, z0), (y1, z1) in itertools.pairwise(corners):
        if (y0, z0) == (y1, z1):
            continue
        t += math.hypot(y1 - y0, z1 - z0) / speed_m_s
        path.append([t, 0.0, y1, z1])
        t += dwell_s
        path.append([t, 0.0, y1, z1])
    return path


def raster_facing(path: list[list[float]], normal: np.ndarray) -> list[list[float]]:
    """``path`` (:func:`raster_path`: passes along y, steps along z) laid in the plane normal
    to ``normal`` instead of the world's y-z plane: its passes along the plane's horizontal,
    its steps along the plane's steepest direction. A painter guided in a plane paints the
    panel the gun faces (``--guide plane``: the plane normal to the tool's z at the start)."""
    n = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    across = np.cross([0.0, 0.0, 1.0], n)
    if np.linalg.norm(across) < 1e-6:  # a gun pointing straight up or down: passes along y
        across = np.array([0.0, 1.0, 0.0])
    across /= np.linalg.norm(across)
    up = np.cross(n, across)
    up = up if up[2] >= 0.0 else -up
    return [[w[0], *(w[1] * n + w[2] * across + w[3] * up).tolist()] for w in path]


def tool_axis_at_start(plant_seed: int) -> np.ndarray:
    """The tool's z (the gun's axis) where the plant of ``plant_seed`` starts, world axes,
    from the plant's own kinematics."""
    q0 = np.array([load_sim_config().initial_q_rad])
    _, rot = flange_poses(plant_seed, q0)
    return rot[0][:, 2]
