"""The admittance's soft joint walls: a spring and a damper on each joint past its soft limit.

Inside its soft limits a joint is free; past one, the wall pushes its reference back with
``k`` × the depth ([control] wall_stiffness_nm_per_rad) and damps the reference's speed
deeper into it. Only deeper: a painter guiding a joint along inside its wall zone or out of it
pays no damper. (Seed 110's raster keeps J3 in its wall zone for 20-35 s; its painter sat at
the hand's 80 N for long stretches with a damper either way, since the path asks J3 past its
soft limit there; without one, the run ended on the speed monitor below.)

A spring alone is no wall for an admittance: against the share α of the arm's inertia the
reference renders, 2,000 N·m/rad rings at about 1.3 Hz on J3 (α M ≈ 30
kg·m²), and the law's own damping (a few N·m·s/rad where the hand pushes, so the painter does
not pay it) leaves it almost undamped; the spring acts on the measured position, a vendor loop
behind the reference, and a delayed spring feeds the ringing. On plant seed 110 (teach-bench,
session 96) J3 bounced off its wall at ±0.55 rad/s until the CAN driver's speed monitor
stopped the arm at 311 mm/s. The damper is critical for the rendered inertia, ``2 √(k α
M_jj)``, at most ``α M_jj / dt``: the law adds a wall's torque explicitly, and a damper that
took more than the reference's whole speed in one step would reverse it.
"""

from __future__ import annotations

import numpy as np


def wall_torque_nm(
    q: np.ndarray,
    dq_r: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    stiffness_nm_per_rad: float,
    rendered_inertia: np.ndarray,
    dt_s: float,
) -> np.ndarray:
    """The walls' torque on the reference per joint [N·m] (module docs): ``q`` the measured
    positions [rad], ``dq_r`` the reference's speed [rad/s], ``lower``/``upper`` the soft
    limits [rad], ``rendered_inertia`` α M̂_jj per joint [kg·m²], ``dt_s`` the law's step [s]."""
    if not dt_s > 0:
        raise ValueError(f"soft walls: step {dt_s} s must be > 0")
    k = stiffness_nm_per_rad
    above, below = np.maximum(q - upper, 0.0), np.maximum(lower - q, 0.0)
    inertia = np.maximum(rendered_inertia, 0.0)
    damping = np.minimum(2.0 * np.sqrt(k * inertia), inertia / dt_s)
    deeper = ((above > 0.0) & (dq_r > 0.0)) | ((below > 0.0) & (dq_r < 0.0))
    return -k * above + k * below - np.where(deeper, damping * dq_r, 0.0)
