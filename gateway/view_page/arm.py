"""The arm in Foxglove's 3D panel: forward kinematics of the cell's URDF at a joint state.

:meth:`ArmKinematics.forward` places every URDF link in the world (pinocchio, model/data
split). From that pose come ``foxglove.FrameTransforms`` (one transform per link, parent →
child, frames named after the URDF links under :data:`WORLD_FRAME`), a ``foxglove.SceneUpdate``
that draws the arm without meshes (a cylinder from each link's origin to its parent's, a sphere
at each joint, the tool point), and the same points as plain JSON for the browser page, which
cannot decode protobuf.

The robot is the one the cell's control compensates (:func:`cell_description`), and the URDF
is :func:`gateway.robot.urdf.to_urdf`'s: ``q`` is in description order, as in the joint
states, and ``q = 0`` is the Table I zero pose.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pinocchio as pin
from foxglove.messages import (
    Color,
    CylinderPrimitive,
    FrameTransform,
    FrameTransforms,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)
from foxglove.websocket import ChannelView, Client, ServerListener

from gateway.config import load_toml, resolve_path
from gateway.errors import ConfigError
from gateway.mcap_json import PREFIX
from gateway.robot.description import RobotDescription, load_description
from gateway.robot.urdf import TOOL_LINK, to_urdf

#: the root frame of the transforms and the scene
WORLD_FRAME = "world"
TF_TOPIC = "/tf"
ARM_TOPIC = "/arm"
ARM_POINTS_TOPIC = "/arm/points"
DESCRIPTION_TOPIC = "/robot_description"
#: Foxglove's URDF layer lists topics of this schema name as robot sources
DESCRIPTION_SCHEMA_NAME = "std_msgs/String"
DESCRIPTION_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": DESCRIPTION_SCHEMA_NAME,
    "description": "the robot's URDF (XML text)",
    "type": "object",
    "properties": {"data": {"type": "string"}},
    "required": ["data"],
}
ARM_POINTS_SCHEMA_NAME = PREFIX + "ArmPoints"
_XYZ: dict[str, Any] = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
ARM_POINTS_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": ARM_POINTS_SCHEMA_NAME,
    "description": "the arm's link origins in the world at one joint state (forward kinematics)",
    "type": "object",
    "properties": {
        "cycle": {"type": "integer", "description": "controller cycle of the joint state"},
        "q_rad": {"type": "array", "items": {"type": "number"}},
        "links": {"type": "array", "items": {"type": "string"}},
        "parents": {
            "type": "array",
            "items": {"type": "string"},
            "description": f"each link's parent link ('{WORLD_FRAME}': the root)",
        },
        "positions_m": {"type": "array", "items": _XYZ, "description": "link origins [m]"},
        "tool_m": {**_XYZ, "description": "the tool point in the world [m]"},
    },
    "required": ["cycle", "q_rad", "links", "parents", "positions_m", "tool_m"],
}

#: link origins closer than this get one sphere and no cylinder between them [m]
SAME_POINT_M = 1e-3
LINK_DIAMETER_M = 0.10
JOINT_DIAMETER_M = 0.16
TOOL_DIAMETER_M = 0.08
#: RGBA
LINK_COLOR = (0.55, 0.62, 0.70, 1.0)
JOINT_COLOR = (0.95, 0.55, 0.10, 1.0)
TOOL_COLOR = (0.85, 0.10, 0.10, 1.0)


def cell_description(cell_path: str | Path) -> RobotDescription:
    """The robot of a cell config: ``[control].model``'s ``robot`` for a TOML model (resolved as
    control/declared_model.py does), else the packaged GR630ST (an identified ``model.json`` or
    no model yet: the control uses the packaged description then too)."""
    model = load_toml(cell_path).get("control", {}).get("model")
    if model and Path(model).suffix != ".json":
        model_path = resolve_path(cell_path, model)
        robot = load_toml(model_path).get("robot", "gr630st")
        if robot != "gr630st":
            return load_description(resolve_path(model_path, robot))
    return load_description()


class DescriptionSubscribed(ServerListener):
    """A Foxglove server listener: ``callback()`` when a client subscribes to
    :data:`DESCRIPTION_TOPIC`, so that the view sends the URDF again (the protocol has no
    latched channels). Called on the server's thread: the callback must be quick."""

    def __init__(self, callback: Callable[[], None]) -> None:
        self._callback = callback

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        if channel.topic == DESCRIPTION_TOPIC:
            self._callback()


class ArmPose(NamedTuple):
    """The arm at one joint state: ``world_T_link[i]`` (4x4, metres) places ``links[i]`` of its
    :class:`ArmKinematics`."""

    q_rad: np.ndarray
    world_T_link: tuple[np.ndarray, ...]


class ArmKinematics:
    """pinocchio model and data of one URDF; :meth:`forward` places every link (the URDF links,
    pinocchio's BODY frames, in the URDF's tree order)."""

    def __init__(self, urdf_xml: str, tool_link: str = TOOL_LINK) -> None:
        self.urdf_xml = urdf_xml
        self.model = pin.buildModelFromXML(urdf_xml)
        self.data = self.model.createData()
        self.n = self.model.nq
        if self.model.nv != self.n:
            raise ConfigError("URDF: only 1-DOF joints can be drawn (nq != nv)")
        #: the joints ``q`` is ordered by
        self.joint_names = tuple(self.model.names[1:])
        frames = self.model.frames
        self._frame_ids = [i for i, f in enumerate(frames) if f.type == pin.FrameType.BODY]
        self.links = tuple(frames[i].name for i in self._frame_ids)
        self.parents = tuple(self._parent_link(i) for i in self._frame_ids)
        if tool_link not in self.links:
            raise ConfigError(f"URDF: no link {tool_link!r} for the tool point")
        self.tool_index = self.links.index(tool_link)

    @classmethod
    def from_description(cls, desc: RobotDescription) -> ArmKinematics:
        kin = cls(to_urdf(desc))
        if kin.joint_names != desc.joint_names:
            raise ConfigError(f"URDF joint order {kin.joint_names} != {desc.joint_names}")
        return kin

    def _parent_link(self, frame_id: int) -> str:
        """The link a BODY frame hangs from: up through its joint frames to the next BODY."""
        frames = self.model.frames
        f = frames[frame_id].parentFrame
        while frames[f].type != pin.FrameType.BODY:
            if f == 0:
                return WORLD_FRAME
            f = frames[f].parentFrame
        return frames[f].name

    def forward(self, q_rad: np.ndarray) -> ArmPose:
        """Every link's placement at ``q_rad`` (n,) [rad]."""
        q = np.asarray(q_rad, dtype=float)
        if q.shape != (self.n,):
            raise ValueError(f"expected {self.n} joint positions, got shape {q.shape}")
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        placements = tuple(self.data.oMf[i].homogeneous.copy() for i in self._frame_ids)
        return ArmPose(q.copy(), placements)

    def world_T_parents(self, pose: ArmPose) -> list[np.ndarray]:
        """Each link's parent placed in the world (identity for the root's ``world``)."""
        by_name = dict(zip(self.links, pose.world_T_link, strict=True))
        return [by_name.get(parent, np.eye(4)) for parent in self.parents]


def _inverse(a_T_b: np.ndarray) -> np.ndarray:
    """``b_T_a`` of a rigid transform."""
    out = np.eye(4)
    out[:3, :3] = a_T_b[:3, :3].T
    out[:3, 3] = -a_T_b[:3, :3].T @ a_T_b[:3, 3]
    return out


def _vector3(p: np.ndarray) -> Vector3:
    return Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _quaternion(rotation: np.ndarray) -> Quaternion:
    x, y, z, w = pin.Quaternion(rotation).coeffs().tolist()
    return Quaternion(x=x, y=y, z=z, w=w)


def _color(rgba: tuple[float, float, float, float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _timestamp(stamp_ns: int) -> Timestamp:
    return Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


def frame_transforms(kin: ArmKinematics, pose: ArmPose, stamp_ns: int) -> FrameTransforms:
    """``parent_T_link`` of every link, stamped ``stamp_ns`` (wall clock [ns])."""
    stamp = _timestamp(stamp_ns)
    transforms = []
    for link, parent, world_T_link, world_T_parent in zip(
        kin.links, kin.parents, pose.world_T_link, kin.world_T_parents(pose), strict=True
    ):
        parent_T_link = _inverse(world_T_parent) @ world_T_link
        transforms.append(
            FrameTransform(
                timestamp=stamp,
                parent_frame_id=parent,
                child_frame_id=link,
                translation=_vector3(parent_T_link[:3, 3]),
                rotation=_quaternion(parent_T_link[:3, :3]),
            )
        )
    return FrameTransforms(transforms=transforms)


def _sphere(center_m: np.ndarray, diameter_m: float, rgba: tuple[float, ...]) -> SpherePrimitive:
    return SpherePrimitive(
        pose=Pose(position=_vector3(center_m), orientation=_quaternion(np.eye(3))),
        size=Vector3(x=diameter_m, y=diameter_m, z=diameter_m),
        color=_color(rgba),
    )


def _cylinder(start_m: np.ndarray, end_m: np.ndarray) -> CylinderPrimitive:
    """A link from ``start_m`` to ``end_m``: a cylinder's axis is its z, turned onto the
    segment and centred on it."""
    length_m = float(np.linalg.norm(end_m - start_m))
    turn = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), (end_m - start_m) / length_m)
    x, y, z, w = turn.coeffs().tolist()
    return CylinderPrimitive(
        pose=Pose(
            position=_vector3(0.5 * (start_m + end_m)), orientation=Quaternion(x=x, y=y, z=z, w=w)
        ),
        size=Vector3(x=LINK_DIAMETER_M, y=LINK_DIAMETER_M, z=length_m),
        bottom_scale=1.0,
        top_scale=1.0,
        color=_color(LINK_COLOR),
    )


def scene_update(kin: ArmKinematics, pose: ArmPose, stamp_ns: int) -> SceneUpdate:
    """One entity ``arm`` in :data:`WORLD_FRAME`, replaced at each update: a cylinder from each
    link's parent origin to its own, a sphere at each link origin, a red one at the tool."""
    cylinders, spheres = [], []
    for i, (world_T_link, world_T_parent) in enumerate(
        zip(pose.world_T_link, kin.world_T_parents(pose), strict=True)
    ):
        start_m, end_m = world_T_parent[:3, 3], world_T_link[:3, 3]
        if i == kin.tool_index:
            spheres.append(_sphere(end_m, TOOL_DIAMETER_M, TOOL_COLOR))
        else:
            spheres.append(_sphere(end_m, JOINT_DIAMETER_M, JOINT_COLOR))
        if np.linalg.norm(end_m - start_m) >= SAME_POINT_M:
            cylinders.append(_cylinder(start_m, end_m))
    entity = SceneEntity(
        timestamp=_timestamp(stamp_ns),
        frame_id=WORLD_FRAME,
        id="arm",
        spheres=spheres,
        cylinders=cylinders,
    )
    return SceneUpdate(entities=[entity])


def arm_points(kin: ArmKinematics, pose: ArmPose, cycle: int) -> dict[str, Any]:
    """The pose as the JSON of :data:`ARM_POINTS_SCHEMA` (for the browser page)."""
    positions = [[round(float(v), 6) for v in t[:3, 3]] for t in pose.world_T_link]
    return {
        "cycle": int(cycle),
        "q_rad": [float(v) for v in pose.q_rad],
        "links": list(kin.links),
        "parents": list(kin.parents),
        "positions_m": positions,
        "tool_m": positions[kin.tool_index],
    }
