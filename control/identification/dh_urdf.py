"""A URDF from a Denavit–Hartenberg table, for identifying robots that come only with DH data.

Identification needs the kinematic structure only: link inertials are placeholders
(:data:`PLACEHOLDER_MASS_KG` at the joint origin, a small sphere-like inertia), since the
regressor does not depend on them.

Conventions (row i describes joint i, 1-based; θ_i = q_i + θ_offset_i):

- ``"modified"`` (Craig; Franka publishes this): the row holds ``(a_{i-1}, α_{i-1}, d_i)`` and
  ``F_{i-1}_T_F_i = Rx(α_{i-1}) Tx(a_{i-1}) Rz(θ_i) Tz(d_i)``. Link i *is* frame i; joint i
  turns about its z axis.
- ``"standard"``: the row holds ``(a_i, α_i, d_i)`` and
  ``F_{i-1}_T_F_i = Rz(θ_i) Tz(d_i) Tx(a_i) Rx(α_i)``; joint i turns about ``z_{i-1}``, so link
  i's body is ``F_{i-1} Rz(θ_i)`` (as in :mod:`gateway.robot.kinematics`), and a fixed link
  ``<name>_dh_end`` marks the last DH frame ``F_n``.

A row with ``fixed=True`` adds a fixed frame (e.g. Franka's flange, ``d = 0.107``) computed
like a joint at q = 0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np

from gateway.errors import ConfigError
from gateway.robot.kinematics import fmt, fmt_vec, homogeneous, matrix_to_rpy, rot_x, rot_z

PLACEHOLDER_MASS_KG = 1.0
PLACEHOLDER_INERTIA_KGM2 = 0.01
PLACEHOLDER_EFFORT_NM = 100.0
PLACEHOLDER_VELOCITY_RAD_S = 10.0
CONVENTIONS = ("modified", "standard")


@dataclass(frozen=True)
class DHRow:
    """One DH row [m, rad]; ``lower_rad``/``upper_rad`` are the joint limits."""

    a_m: float
    alpha_rad: float
    d_m: float
    theta_offset_rad: float = 0.0
    lower_rad: float = -math.pi
    upper_rad: float = math.pi
    fixed: bool = False


def _row(row: DHRow | Sequence[float]) -> DHRow:
    if isinstance(row, DHRow):
        return row
    values = [float(v) for v in row]
    if not 3 <= len(values) <= 6:
        raise ConfigError(f"DH row {row!r}: need (a, alpha, d[, offset[, lower, upper]])")
    return DHRow(*values)  # type: ignore[arg-type]


def _tz_tx_rx(a: float, alpha: float, d: float) -> np.ndarray:
    return homogeneous(rot_x(alpha), np.array([a, 0.0, d]))


def urdf_from_dh(
    rows: Sequence[DHRow | Sequence[float]],
    convention: str = "modified",
    name: str = "robot",
) -> str:
    """URDF text of a serial arm from its DH rows (conventions in the module docstring).

    Joints are named ``joint1..`` and links ``link1..`` (base ``link0``); fixed rows add
    ``frame<k>`` links. Placeholder inertials: identification needs kinematics only.
    """
    if convention not in CONVENTIONS:
        raise ConfigError(f"convention {convention!r} is not one of {list(CONVENTIONS)}")
    parsed = [_row(r) for r in rows]
    if not any(not r.fixed for r in parsed):
        raise ConfigError("DH table has no moving joint")
    lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(name)}>", '  <link name="link0"/>']
    parent = "link0"
    pending = np.eye(4)  # standard DH: D of the previous row, applied before the next joint
    n_joint = 0
    n_fixed = 0
    for row in parsed:
        if convention == "modified":
            placement = (
                homogeneous(rot_x(row.alpha_rad), np.zeros(3))
                @ homogeneous(np.eye(3), np.array([row.a_m, 0.0, 0.0]))
                @ homogeneous(rot_z(row.theta_offset_rad), np.array([0.0, 0.0, row.d_m]))
            )
        else:
            placement = pending @ homogeneous(rot_z(row.theta_offset_rad), np.zeros(3))
            pending = _tz_tx_rx(row.a_m, row.alpha_rad, row.d_m)
        origin = (
            f'    <origin xyz="{fmt_vec(placement[:3, 3])}"'
            f' rpy="{fmt_vec(matrix_to_rpy(placement[:3, :3]))}"/>'
        )
        if row.fixed:
            n_fixed += 1
            child = f"frame{n_fixed}"
            lines += [
                f'  <joint name="fixed{n_fixed}" type="fixed">',
                f'    <parent link="{parent}"/>',
                f'    <child link="{child}"/>',
                origin,
                "  </joint>",
                f'  <link name="{child}"/>',
            ]
        else:
            n_joint += 1
            child = f"link{n_joint}"
            if not row.lower_rad < row.upper_rad:
                raise ConfigError(f"joint{n_joint}: lower limit must be below upper limit")
            inertia = fmt(PLACEHOLDER_INERTIA_KGM2)
            lines += [
                f'  <joint name="joint{n_joint}" type="revolute">',
                f'    <parent link="{parent}"/>',
                f'    <child link="{child}"/>',
                origin,
                '    <axis xyz="0 0 1"/>',
                f'    <limit lower="{fmt(row.lower_rad)}" upper="{fmt(row.upper_rad)}"'
                f' effort="{fmt(PLACEHOLDER_EFFORT_NM)}"'
                f' velocity="{fmt(PLACEHOLDER_VELOCITY_RAD_S)}"/>',
                "  </joint>",
                f'  <link name="{child}">',
                "    <inertial>",
                '      <origin xyz="0 0 0" rpy="0 0 0"/>',
                f'      <mass value="{fmt(PLACEHOLDER_MASS_KG)}"/>',
                f'      <inertia ixx="{inertia}" ixy="0" ixz="0" iyy="{inertia}" iyz="0"'
                f' izz="{inertia}"/>',
                "    </inertial>",
                "  </link>",
            ]
        parent = child
    if convention == "standard":
        lines += [
            f'  <joint name="{name}_dh_end_joint" type="fixed">',
            f'    <parent link="{parent}"/>',
            f'    <child link="{name}_dh_end"/>',
            f'    <origin xyz="{fmt_vec(pending[:3, 3])}"'
            f' rpy="{fmt_vec(matrix_to_rpy(pending[:3, :3]))}"/>',
            "  </joint>",
            f'  <link name="{name}_dh_end"/>',
        ]
    lines += ["</robot>", ""]
    return "\n".join(lines)


#: Franka Emika Panda, modified DH (Craig) as published by Franka, with its joint limits [rad];
#: the last row is the flange (fixed). Used by tests on the Gaz et al. 2019 data.
PANDA_DH_ROWS: tuple[DHRow, ...] = (
    DHRow(0.0, 0.0, 0.333, 0.0, -2.8973, 2.8973),
    DHRow(0.0, -math.pi / 2, 0.0, 0.0, -1.7628, 1.7628),
    DHRow(0.0, math.pi / 2, 0.316, 0.0, -2.8973, 2.8973),
    DHRow(0.0825, math.pi / 2, 0.0, 0.0, -3.0718, -0.0698),
    DHRow(-0.0825, -math.pi / 2, 0.384, 0.0, -2.8973, 2.8973),
    DHRow(0.0, math.pi / 2, 0.0, 0.0, -0.0175, 3.7525),
    DHRow(0.088, math.pi / 2, 0.0, 0.0, -2.8973, 2.8973),
    DHRow(0.0, 0.0, 0.107, fixed=True),
)
