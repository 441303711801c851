"""MJCF rendering of a :class:`RobotDescription`, for MuJoCo.

Same bodies as :mod:`gateway.robot.urdf` (see :mod:`gateway.robot.kinematics`): bodies
``link1`` .. ``link6`` with hinge joints about their z axes, a ``tool`` site at the tool point.
Each joint's ``armature`` is the reflected rotor inertia ``J_rotor · R²``. There is no joint
damping or frictionloss (the simulator applies eq. (15) itself), no contacts, and geoms are
visual only (``inertiafromgeom="false"``: masses come from the description alone).
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

import numpy as np

from gateway.robot.description import RobotDescription
from gateway.robot.kinematics import (
    body_placements,
    fmt,
    fmt_vec,
    last_body_T_tool,
    matrix_to_quat_wxyz,
)
from gateway.robot.urdf import link_name

TOOL_SITE = "tool"
_MIN_CAPSULE_M = 1e-3


def _visual_radius_m(mass_kg: float) -> float:
    return max(0.03, 0.1 * (mass_kg / 100.0) ** (1.0 / 3.0))


def _segment_geom(indent: str, start_m: np.ndarray, end_m: np.ndarray, radius_m: float) -> str:
    if np.linalg.norm(end_m - start_m) < _MIN_CAPSULE_M:
        return f'{indent}<geom type="sphere" pos="{fmt_vec(start_m)}" size="{fmt(radius_m)}"/>'
    return (
        f'{indent}<geom type="capsule" fromto="{fmt_vec(start_m)} {fmt_vec(end_m)}"'
        f' size="{fmt(radius_m)}"/>'
    )


def to_mjcf(desc: RobotDescription, timestep_s: float = 0.0005) -> str:
    """The arm as an MJCF string: limited hinges, armature, gravity, implicitfast, a tool site."""
    bodies = body_placements(desc)
    lines = [
        f"<mujoco model={quoteattr(desc.name)}>",
        '  <compiler angle="radian" autolimits="true" inertiafromgeom="false"/>',
        f'  <option timestep="{fmt(timestep_s)}" gravity="{fmt_vec(desc.gravity_m_s2)}"'
        ' integrator="implicitfast">',
        '    <flag contact="disable"/>',
        "  </option>",
        "  <default>",
        '    <joint damping="0" frictionloss="0"/>',
        '    <geom contype="0" conaffinity="0" rgba="0.9 0.5 0.1 1"/>',
        "  </default>",
        "  <worldbody>",
        '    <geom name="base" type="cylinder" size="0.3 0.1" pos="0 0 0.1" rgba="0.3 0.3 0.3 1"/>',
    ]
    indent = "    "
    for i, (joint, body) in enumerate(zip(desc.joints, bodies, strict=True)):
        quat = matrix_to_quat_wxyz(body.parent_T_body[:3, :3])
        inertia = body.inertia_in_body_kgm2
        full = (
            inertia[0, 0],
            inertia[1, 1],
            inertia[2, 2],
            inertia[0, 1],
            inertia[0, 2],
            inertia[1, 2],
        )
        # The segment from this joint to the next: D_i's translation (a_i, 0, d_i) in B_i.
        end = np.array([joint.a_m, 0.0, joint.d_m])
        lines += [
            f'{indent}<body name="{link_name(i)}" pos="{fmt_vec(body.parent_T_body[:3, 3])}"'
            f' quat="{fmt_vec(quat)}">',
            f'{indent}  <inertial pos="{fmt_vec(body.com_in_body_m)}" mass="{fmt(body.mass_kg)}"'
            f' fullinertia="{fmt_vec(full)}"/>',
            f'{indent}  <joint name={quoteattr(joint.name)} type="hinge" axis="0 0 1"'
            f' limited="true" range="{fmt(joint.lower_rad)} {fmt(joint.upper_rad)}"'
            f' armature="{fmt(joint.armature_kgm2)}"/>',
            _segment_geom(indent + "  ", np.zeros(3), end, _visual_radius_m(body.mass_kg)),
        ]
        indent += "  "
    body_T_tool = last_body_T_tool(desc)
    lines += [
        _segment_geom(indent, np.zeros(3), body_T_tool[:3, 3], 0.02),
        f'{indent}<site name="{TOOL_SITE}" pos="{fmt_vec(body_T_tool[:3, 3])}"'
        f' quat="{fmt_vec(matrix_to_quat_wxyz(body_T_tool[:3, :3]))}" size="0.01"/>',
    ]
    for _ in desc.joints:
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    lines += ["  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)
