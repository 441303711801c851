"""The admittance's soft joint walls: a spring and a damper on each joint past its soft limit.
Compiled, on the admittance's cycle: control/rt/src/law/admittance/soft_walls.rs says why and
how.

``wall_torque_nm(q, dq_r, lower, upper, stiffness_nm_per_rad, rendered_inertia, dt_s)`` → the
walls' torque on the reference per joint (a list) [N·m]; ValueError for a step not > 0.
"""

from __future__ import annotations

from control._rt import wall_torque_nm

__all__ = ["wall_torque_nm"]
