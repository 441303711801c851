"""URDF rendering of a :class:`RobotDescription`, for pinocchio.

Bodies follow :mod:`gateway.robot.kinematics`: link ``i`` is frame ``F_{i-1}`` turned by the
joint (``B_i``), every revolute joint turns about its child's z axis, and the link inertials and
the fixed ``tool`` link are moved from the DH frames into those bodies. The MJCF writer uses the
same placements, so both engines describe one arm.
"""

from __future__ import annotations

import math
from xml.sax.saxutils import quoteattr

from gateway.robot.description import RobotDescription
from gateway.robot.kinematics import body_placements, fmt, fmt_vec, last_body_T_tool, matrix_to_rpy

#: URDF requires a velocity limit; the description has none. Informational only, unused here.
URDF_VELOCITY_LIMIT_RAD_S = math.pi

BASE_LINK = "base_link"
TOOL_LINK = "tool"


def link_name(index: int) -> str:
    """Engine body name of 0-based link ``index`` (``link1`` .. ``link6``)."""
    return f"link{index + 1}"


def to_urdf(desc: RobotDescription) -> str:
    """The arm as a URDF string: revolute joints with limits, link inertials, a fixed tool link."""
    lines = [
        '<?xml version="1.0"?>',
        f"<robot name={quoteattr(desc.name)}>",
        f'  <link name="{BASE_LINK}"/>',
    ]
    parent = BASE_LINK
    for i, (joint, body) in enumerate(zip(desc.joints, body_placements(desc), strict=True)):
        child = link_name(i)
        inertia = body.inertia_in_body_kgm2
        lines += [
            f'  <joint name={quoteattr(joint.name)} type="revolute">',
            f'    <parent link="{parent}"/>',
            f'    <child link="{child}"/>',
            f'    <origin xyz="{fmt_vec(body.parent_T_body[:3, 3])}"'
            f' rpy="{fmt_vec(matrix_to_rpy(body.parent_T_body[:3, :3]))}"/>',
            '    <axis xyz="0 0 1"/>',
            f'    <limit lower="{fmt(joint.lower_rad)}" upper="{fmt(joint.upper_rad)}"'
            f' effort="{fmt(joint.max_torque_nm)}" velocity="{fmt(URDF_VELOCITY_LIMIT_RAD_S)}"/>',
            "  </joint>",
            f'  <link name="{child}">',
            "    <inertial>",
            f'      <origin xyz="{fmt_vec(body.com_in_body_m)}" rpy="0 0 0"/>',
            f'      <mass value="{fmt(body.mass_kg)}"/>',
            f'      <inertia ixx="{fmt(inertia[0, 0])}" ixy="{fmt(inertia[0, 1])}"'
            f' ixz="{fmt(inertia[0, 2])}" iyy="{fmt(inertia[1, 1])}"'
            f' iyz="{fmt(inertia[1, 2])}" izz="{fmt(inertia[2, 2])}"/>',
            "    </inertial>",
            "  </link>",
        ]
        parent = child
    body_T_tool = last_body_T_tool(desc)
    lines += [
        '  <joint name="tool_joint" type="fixed">',
        f'    <parent link="{parent}"/>',
        f'    <child link="{TOOL_LINK}"/>',
        f'    <origin xyz="{fmt_vec(body_T_tool[:3, 3])}"'
        f' rpy="{fmt_vec(matrix_to_rpy(body_T_tool[:3, :3]))}"/>',
        "  </joint>",
        f'  <link name="{TOOL_LINK}"/>',
        "</robot>",
        "",
    ]
    return "\n".join(lines)
