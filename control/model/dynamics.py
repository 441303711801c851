"""Rigid-body dynamics of eq. (1) with pinocchio: M(q), C(q, dq) dq, g(q), the regressor of eq. (2).

The model is built from the URDF of :func:`gateway.robot.urdf.to_urdf`, so ``q`` is the Table I
joint angle (offsets are inside the model; ``q = 0`` is the Table I zero pose) in description
order. Results are rigid-body only unless a method says otherwise: the reflected rotor inertia
(armature, ``J_rotor R²``) is kept apart and added on request, because the regressor of eq. (2)
is over link parameters and MuJoCo adds armature to its own mass matrix.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from gateway.robot.description import RobotDescription
from gateway.robot.urdf import TOOL_LINK, to_urdf

#: Order of the 10 dynamic parameters per link in :meth:`RigidBodyModel.regressor` (pinocchio's
#: ``Inertia.toDynamicParameters``): first moments are m·c, inertias are about the body origin.
LINK_PARAMETER_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")


class RigidBodyModel:
    """pinocchio model and data for one serial arm; all methods take ``q_rad`` of shape (n,)."""

    def __init__(
        self,
        urdf_xml: str,
        gravity_m_s2: tuple[float, float, float] | np.ndarray = (0.0, 0.0, -9.81),
        armature_kgm2: np.ndarray | None = None,
        tool_frame: str = TOOL_LINK,
    ) -> None:
        self.model = pin.buildModelFromXML(urdf_xml)
        self.model.gravity = pin.Motion(np.asarray(gravity_m_s2, dtype=float), np.zeros(3))
        self.data = self.model.createData()
        self.n = self.model.nv
        if self.model.nq != self.n:
            raise ValueError("only revolute (1-DOF) joints are supported")
        self.armature_kgm2 = (
            np.zeros(self.n) if armature_kgm2 is None else np.asarray(armature_kgm2, dtype=float)
        )
        if self.armature_kgm2.shape != (self.n,):
            raise ValueError(f"armature_kgm2 needs {self.n} values")
        if not self.model.existFrame(tool_frame):
            raise ValueError(f"URDF has no frame {tool_frame!r}")
        self.tool_frame_id = self.model.getFrameId(tool_frame)
        self.joint_names = tuple(self.model.names[1:])

    @classmethod
    def from_description(cls, desc: RobotDescription) -> RigidBodyModel:
        """Model of ``desc`` with its gravity and armature; joint order = description order."""
        model = cls(to_urdf(desc), desc.gravity_m_s2, desc.armature_kgm2)
        if model.joint_names != desc.joint_names:
            raise ValueError(f"joint order {model.joint_names} != {desc.joint_names}")
        return model

    def _q(self, q_rad: np.ndarray) -> np.ndarray:
        q = np.asarray(q_rad, dtype=float)
        if q.shape != (self.n,):
            raise ValueError(f"expected shape ({self.n},), got {q.shape}")
        return q

    def gravity_nm(self, q_rad: np.ndarray) -> np.ndarray:
        """g(q) of eq. (1) [N·m]: the joint torques that hold the arm still at q."""
        return pin.computeGeneralizedGravity(self.model, self.data, self._q(q_rad)).copy()

    def rnea_nm(
        self,
        q_rad: np.ndarray,
        dq_rad_s: np.ndarray,
        ddq_rad_s2: np.ndarray,
        include_armature: bool = False,
    ) -> np.ndarray:
        """Inverse dynamics ``M(q) ddq + C(q, dq) dq + g(q)`` of eq. (1) [N·m].

        With ``include_armature`` the reflected rotor inertia adds ``J_rotor R² · ddq``.
        """
        ddq = self._q(ddq_rad_s2)
        tau = pin.rnea(self.model, self.data, self._q(q_rad), self._q(dq_rad_s), ddq).copy()
        if include_armature:
            tau += self.armature_kgm2 * ddq
        return tau

    def mass_matrix(self, q_rad: np.ndarray, include_armature: bool = False) -> np.ndarray:
        """M(q) of eq. (1) [kg·m²], symmetric; optionally plus ``diag(J_rotor R²)``."""
        m = pin.crba(self.model, self.data, self._q(q_rad)).copy()
        m = np.triu(m) + np.triu(m, 1).T
        if include_armature:
            m += np.diag(self.armature_kgm2)
        return m

    def regressor(
        self, q_rad: np.ndarray, dq_rad_s: np.ndarray, ddq_rad_s2: np.ndarray
    ) -> np.ndarray:
        """Joint-torque regressor Y of eq. (2), shape (n, 10 n): ``rnea = Y @ parameters()``.

        Columns are grouped per link in :data:`LINK_PARAMETER_NAMES` order
        ``[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (kg, kg·m, kg·m²), expressed in the
        engine body frame of each link (``B_i`` of :mod:`gateway.robot.kinematics`), inertias
        about the body origin. Armature is not included.
        """
        return pin.computeJointTorqueRegressor(
            self.model,
            self.data,
            self._q(q_rad),
            self._q(dq_rad_s),
            self._q(ddq_rad_s2),
        ).copy()

    def parameters(self) -> np.ndarray:
        """The model's own link parameters, shape (10 n,), in :meth:`regressor` column order."""
        return np.concatenate(
            [self.model.inertias[i].toDynamicParameters() for i in range(1, self.model.njoints)]
        )

    def world_T_tool(self, q_rad: np.ndarray) -> np.ndarray:
        """Pose of the tool frame in the world (4x4 homogeneous, metres)."""
        q = self._q(q_rad)
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.tool_frame_id].homogeneous.copy()

    def tool_jacobian_world(self, q_rad: np.ndarray) -> np.ndarray:
        """Tool Jacobian (6, n), LOCAL_WORLD_ALIGNED: rows [v_x, v_y, v_z (m/s), ω (rad/s)].

        Linear rows are the velocity of the tool point, angular rows the angular velocity, both
        in world axes, per unit joint velocity [rad/s].
        """
        return pin.computeFrameJacobian(
            self.model,
            self.data,
            self._q(q_rad),
            self.tool_frame_id,
            pin.ReferenceFrame.LOCAL_WORLD_ALIGNED,
        ).copy()
