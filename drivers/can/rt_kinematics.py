"""The speed monitor's kinematics as a table for the compiled CAN cycle (issue 48).

Hand guiding's tool point and flange follow from the joint positions with the datasheet's
kinematics: :meth:`control.model.dynamics.RigidBodyModel.world_T_tool` (pinocchio, on the URDF of
:func:`gateway.robot.urdf.to_urdf`) gives the tool's pose, whose origin is the tool point; the
flange is that point less the pose's rotation applied to the description's tool offset
(``tool.position_in_link6_m``). The compiled cycle (``drivers/can/rt``,
``speed_monitor.rs`` ``KinematicChain``) has no pinocchio: it gets the same chain as numbers,
made here once at start from the same robot description, and evaluates it itself::

    world_T_body_i = world_T_body_{i-1} · parent_T_joint_i · Rot(axis_i, q_i)
    tool   = world_T_body_n · tool_m        flange = world_T_body_n · flange_m

``parent_T_joint`` places joint i's body in its parent's at q = 0 (the URDF joint origin,
:func:`gateway.robot.kinematics.body_placements`; world for the first), ``axis`` is the joint
axis in the body (every joint of the description turns about its body's z), ``tool_m`` the tool
point and ``flange_m`` the flange (link 6's DH origin) in the last body [m]. The table is plain
JSON: lists of floats, no NaN.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from gateway.robot.kinematics import body_placements, last_body_T_tool

if TYPE_CHECKING:
    from gateway.robot.description import RobotDescription

#: the table's format name and version (speed_monitor.rs checks both)
CHAIN_FORMAT = "leadthrough-kinematic-chain"
CHAIN_VERSION = 1


def _floats(values: np.ndarray) -> list[Any]:
    """Nested lists of Python floats (JSON numbers) of ``values``."""
    return np.asarray(values, dtype=float).tolist()


def chain_table(desc: RobotDescription | None = None) -> dict[str, Any]:
    """The kinematic chain of ``desc`` (default: the datasheet's description, as
    :func:`~gateway.robot.description.load_description` loads it) as a JSON-serialisable dict:
    ``format``, ``version``, ``joints`` (per joint ``name``, ``parent_T_joint`` 4x4 row-major
    [m], ``axis`` unit 3-vector), ``tool_m`` and ``flange_m`` (3-vectors in the last joint's
    body [m]). The same numbers RigidBodyModel.world_T_tool evaluates, without the URDF's text
    round trip."""
    if desc is None:
        from gateway.robot.description import load_description

        desc = load_description()
    placements = body_placements(desc)
    body_T_tool = last_body_T_tool(desc)
    tool_in_6 = np.asarray(desc.tool.position_in_link6_m, dtype=float)
    # flange = tool - world_R_tool @ tool_in_6 (module docstring), here in the last body
    flange = body_T_tool[:3, 3] - body_T_tool[:3, :3] @ tool_in_6
    return {
        "format": CHAIN_FORMAT,
        "version": CHAIN_VERSION,
        "joints": [
            {
                "name": joint.name,
                "parent_T_joint": _floats(body.parent_T_body),
                "axis": [0.0, 0.0, 1.0],
            }
            for joint, body in zip(desc.joints, placements, strict=True)
        ],
        "tool_m": _floats(body_T_tool[:3, 3]),
        "flange_m": _floats(flange),
    }
