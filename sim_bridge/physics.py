"""The virtual robot's own joint friction and assist-cylinder forces.

The plant computes with this code and nothing of the product's model (a test walks the
imports): a simplification or a bug in the product's friction or cylinder model must show as a
model error, not be copied into the "robot".

Friction per joint (joint side [N·m]), with the gear ratio R::

    τ_f = [τ_s exp(-|dq|/q_e) + τ_c + f1 sin(q/R) + f2 cos(q/R) + f3 sin(2q/R) + f4 cos(2q/R)
           + f5 sin q + f6 cos q] tanh(dq / 2 q_e) + τ_v1 dq + τ_v2 dq |dq|

(the static level τ_s + τ_c decays towards Coulomb τ_c over the Stribeck velocity q_e; every
term opposes the motion). Assist cylinders push with p·S along their rod: a crank (pivot A,
rod end B on the link |AB| from the joint, barrel end C fixed |AC| from it, the angle BAC =
π - q) turns the joint with the moment arm |AB||AC| sin(BAC) / |BC|; a lever turns it with
|AB| cos q. By virtual work the rod extends by the moment arm per radian, so a chamber whose gas
column is L₀ long at q = 0 holds the volume S (L₀ + x(q)) (x the extension since q = 0); the
gas is isothermal, p_abs V constant, between the regulator's refills (a first-order lag of the
pressure towards its set-point).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from sim_bridge.config import CylinderUnit, FrictionTruth

PA_PER_BAR = 1.0e5
#: atmospheric pressure [bar]: the transmitters read gauge pressure
ATMOSPHERE_BAR = 1.01325


class JointFriction:
    """Friction torque of every joint; parameters gathered into arrays once."""

    def __init__(self, joints: Sequence[FrictionTruth], gear_ratio: Sequence[float]) -> None:
        def col(name: str) -> np.ndarray:
            return np.array([getattr(f, name) for f in joints], dtype=float)

        self.tau_s, self.tau_c = col("tau_s_nm"), col("tau_c_nm")
        self.v1, self.v2 = col("tau_v1_nm_s_per_rad"), col("tau_v2_nm_s2_per_rad2")
        self.q_e = col("q_e_rad_s")
        self.fourier = np.array([f.fourier_nm for f in joints], dtype=float)  # (n, 6)
        self.inv_r = 1.0 / np.asarray(gear_ratio, dtype=float)

    def __call__(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Friction torque [N·m] at positions ``q`` [rad] and velocities ``dq`` [rad/s], (n,)."""
        qr = q * self.inv_r
        f = self.fourier
        level = (
            self.tau_s * np.exp(-np.abs(dq) / self.q_e)
            + self.tau_c
            + f[:, 0] * np.sin(qr)
            + f[:, 1] * np.cos(qr)
            + f[:, 2] * np.sin(2.0 * qr)
            + f[:, 3] * np.cos(2.0 * qr)
            + f[:, 4] * np.sin(q)
            + f[:, 5] * np.cos(q)
        )
        return level * np.tanh(dq / (2.0 * self.q_e)) + self.v1 * dq + self.v2 * dq * np.abs(dq)


class AssistCylinders:
    """Joint torques of the assist cylinders at their chamber pressures."""

    def __init__(self, units: Sequence[CylinderUnit], n_joints: int) -> None:
        self.units = tuple(units)
        self.n = n_joints
        self.area_m2 = [math.pi * u.piston_diameter_m**2 / 4.0 for u in self.units]

    @staticmethod
    def moment_arm_m(unit: CylinderUnit, q_joint: float) -> float:
        """Signed moment arm [m] of the cylinder's push about its joint at angle ``q_joint``."""
        if unit.kind == "crank":
            bac = math.pi - q_joint
            bc = math.sqrt(
                unit.ab_m**2 + unit.ac_m**2 - 2.0 * unit.ab_m * unit.ac_m * math.cos(bac)
            )
            return unit.sign * unit.ab_m * unit.ac_m * math.sin(bac) / bc
        return unit.sign * unit.ab_m * math.cos(q_joint)

    @staticmethod
    def extension_m(unit: CylinderUnit, q_joint: float) -> float:
        """The rod's extension [m] since q = 0 (its derivative is :meth:`moment_arm_m`)."""
        if unit.kind == "crank":

            def bc(q: float) -> float:
                return math.sqrt(
                    unit.ab_m**2 + unit.ac_m**2 + 2.0 * unit.ab_m * unit.ac_m * math.cos(q)
                )

            return -unit.sign * (bc(q_joint) - bc(0.0))
        return unit.sign * unit.ab_m * math.sin(q_joint)

    def gas_columns_m(self, q: np.ndarray) -> np.ndarray:
        """Each chamber's gas volume over its piston area [m] at joint angles ``q``
        (``inf`` for an ideal reservoir, ``gas_length_m`` 0); never below a tenth of L₀."""
        out = np.full(len(self.units), np.inf)
        for k, unit in enumerate(self.units):
            if unit.gas_length_m > 0:
                x = self.extension_m(unit, float(q[unit.joint - 1]))
                out[k] = max(unit.gas_length_m + x, 0.1 * unit.gas_length_m)
        return out

    def torque_nm(self, q: np.ndarray, p_bar: np.ndarray) -> np.ndarray:
        """Joint torques [N·m] (n,), zero on joints without a cylinder."""
        tau = np.zeros(self.n)
        for unit, area, p in zip(self.units, self.area_m2, p_bar, strict=True):
            j = unit.joint - 1
            tau[j] += area * p * PA_PER_BAR * self.moment_arm_m(unit, float(q[j]))
        return tau
