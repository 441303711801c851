"""Standard-DH geometry shared by the URDF and MJCF writers, plus a plain-numpy DH reference.

Frames. ``F_i`` is the standard-DH frame i of Table I (``F_0`` = world = robot base), with::

    F_{i-1}_T_F_i = Rz(θ_i) · Tz(d_i) · Tx(a_i) · Rx(α_i),   θ_i = q_i + θ_offset_i

Joint i turns about ``z_{i-1}``, through the origin of ``F_{i-1}``. URDF and MJCF need each
joint axis to pass through its child body's origin, so the engine body of link i is

    B_i = F_{i-1} · Rz(θ_offset_i + q_i)

i.e. frame i-1 turned by the joint about its z axis. Then the joint placement in the parent
body is ``B_{i-1}_T_B_i(q=0) = D_{i-1} · Rz(θ_offset_i)`` with ``D_j = Tz(d_j) Tx(a_j) Rx(α_j)``
(``D_0`` = identity, parent = world), the joint axis is the body's z axis, and link i's DH frame
is ``F_i = B_i · D_i``. Link inertials and the tool point, given in ``F_i`` / ``F_6``, are
mapped into ``B_i`` / ``B_6`` through ``D_i``. Both writers use :func:`body_placements`, so
both engines get the same numbers.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from gateway.robot.description import RobotDescription


def rot_x(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def homogeneous(rotation: np.ndarray, translation_m: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation_m
    return out


def dh_transforms(a_m: float, alpha_rad: float, d_m: float, theta_rad: np.ndarray) -> np.ndarray:
    """Standard DH: ``Rz(θ) Tz(d) Tx(a) Rx(α)`` as (T, 4, 4), one per angle of ``theta_rad``
    (T,) (Table I rows, read as standard DH)."""
    theta = np.asarray(theta_rad, dtype=float)
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = math.cos(alpha_rad), math.sin(alpha_rad)
    out = np.zeros((theta.size, 4, 4))
    out[:, 0, 0], out[:, 0, 1], out[:, 0, 2], out[:, 0, 3] = ct, -st * ca, st * sa, a_m * ct
    out[:, 1, 0], out[:, 1, 1], out[:, 1, 2], out[:, 1, 3] = st, ct * ca, -ct * sa, a_m * st
    out[:, 2, 1], out[:, 2, 2], out[:, 2, 3] = sa, ca, d_m
    out[:, 3, 3] = 1.0
    return out


def dh_transform(a_m: float, alpha_rad: float, d_m: float, theta_rad: float) -> np.ndarray:
    """:func:`dh_transforms` for one angle: a 4x4."""
    return dh_transforms(a_m, alpha_rad, d_m, np.array([theta_rad]))[0]


def _d_transform(desc: RobotDescription, i: int) -> np.ndarray:
    """``D_i = Tz(d_i) Tx(a_i) Rx(α_i)`` for 0-based joint index i (DH row i+1)."""
    j = desc.joints[i]
    return homogeneous(rot_x(j.alpha_rad), np.array([j.a_m, 0.0, j.d_m]))


class BodyPlacement(NamedTuple):
    """Engine body of link i (0-based): where it sits and what it carries, in its own frame B_i.

    ``parent_T_body`` places B_i in B_{i-1} (world for i = 0) at q = 0; the joint turns about
    B_i's z axis. ``com_in_body_m`` [m] and ``inertia_in_body_kgm2`` (about the COM, B_i axes)
    [kg·m²] are link i's inertial data moved from F_i into B_i.
    """

    parent_T_body: np.ndarray
    com_in_body_m: np.ndarray
    inertia_in_body_kgm2: np.ndarray
    mass_kg: float


def body_placements(desc: RobotDescription) -> list[BodyPlacement]:
    """One :class:`BodyPlacement` per link, in chain order."""
    out = []
    for i, (joint, link) in enumerate(zip(desc.joints, desc.links, strict=True)):
        parent_T_body = homogeneous(rot_z(joint.theta_offset_rad), np.zeros(3))
        if i > 0:
            parent_T_body = _d_transform(desc, i - 1) @ parent_T_body
        body_T_link = _d_transform(desc, i)
        rot = body_T_link[:3, :3]
        com = body_T_link[:3, :3] @ np.asarray(link.com_m) + body_T_link[:3, 3]
        inertia = rot @ link.inertia_kgm2 @ rot.T
        out.append(BodyPlacement(parent_T_body, com, 0.5 * (inertia + inertia.T), link.mass_kg))
    return out


def last_body_T_tool(desc: RobotDescription) -> np.ndarray:
    """The tool frame in the last engine body B_n (4x4, metres); axes are those of F_n."""
    body_T_link = _d_transform(desc, desc.n_dof - 1)
    link_T_tool = homogeneous(np.eye(3), np.asarray(desc.tool.position_in_link6_m))
    return body_T_link @ link_T_tool


def dh_frames(desc: RobotDescription, q_rad: np.ndarray) -> list[np.ndarray]:
    """``world_T_F_i`` for i = 0..n by plain standard-DH products (the reference chain)."""
    q = np.asarray(q_rad, dtype=float)
    frames = [np.eye(4)]
    for j, qi in zip(desc.joints, q, strict=True):
        frames.append(frames[-1] @ dh_transform(j.a_m, j.alpha_rad, j.d_m, qi + j.theta_offset_rad))
    return frames


def dh_world_T_tool(desc: RobotDescription, q_rad: np.ndarray) -> np.ndarray:
    """Tool pose in the world by standard DH (4x4, metres), independent of either engine."""
    link_T_tool = homogeneous(np.eye(3), np.asarray(desc.tool.position_in_link6_m))
    return dh_frames(desc, q_rad)[-1] @ link_T_tool


def dh_tool_and_flange(desc: RobotDescription, q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tool point and the flange (link 6's origin) in the world, (T, 3) each [m], at the
    joint positions (T, n) [rad]: :func:`dh_world_T_tool` for many samples at once."""
    q = np.atleast_2d(np.asarray(q_rad, dtype=float))
    frame = np.broadcast_to(np.eye(4), (q.shape[0], 4, 4)).copy()
    for k, j in enumerate(desc.joints):
        frame = frame @ dh_transforms(j.a_m, j.alpha_rad, j.d_m, q[:, k] + j.theta_offset_rad)
    flange = frame[:, :3, 3]
    tool = flange + frame[:, :3, :3] @ np.asarray(desc.tool.position_in_link6_m, dtype=float)
    return tool, flange


def matrix_to_rpy(rotation: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw [rad] with ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    r = np.asarray(rotation, dtype=float)
    cos_pitch = math.hypot(r[0, 0], r[1, 0])
    pitch = math.atan2(-r[2, 0], cos_pitch)
    if cos_pitch > 1e-12:
        roll = math.atan2(r[2, 1], r[2, 2])
        yaw = math.atan2(r[1, 0], r[0, 0])
    else:  # gimbal lock: put the whole turn about x into yaw
        roll = 0.0
        yaw = math.atan2(-r[0, 1], r[1, 1])
    return roll, pitch, yaw


def matrix_to_quat_wxyz(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method), w >= 0."""
    r = np.asarray(rotation, dtype=float)
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    quat = np.array(q)
    quat /= np.linalg.norm(quat)
    return quat if quat[0] >= 0.0 else -quat


_SNAP_TO_ZERO = 1e-15  #: round-off of cos(90°) etc.; far below any length or inertia here


def fmt(value: float) -> str:
    """Shortest exact text for a float, so both engines read back the same double."""
    v = float(value)
    return "0" if abs(v) < _SNAP_TO_ZERO else repr(v)


def fmt_vec(values: np.ndarray | tuple[float, ...]) -> str:
    return " ".join(fmt(v) for v in np.asarray(values, dtype=float).ravel())
