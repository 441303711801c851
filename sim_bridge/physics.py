"""The virtual robot's own joint friction and assist-cylinder forces.

The plant computes with this code and nothing of the product's model (a test walks the
imports): a simplification or a bug in the product's friction or cylinder model must show as a
model error, not be copied into the "robot".

Friction per joint (joint side [N·m]), with the gear ratio R::

    τ_f = [τ_s exp(-|dq|/q_e) + F(q)] s(dq) + τ_v1 dq + τ_v2 dq |dq|,
    F(q) = τ_c + f1 sin(q/R) + f2 cos(q/R) + f3 sin(2q/R) + f4 cos(2q/R) + f5 sin q + f6 cos q

(the static level τ_s + F decays towards the Coulomb level F over the Stribeck velocity q_e;
every term opposes the motion). The truth's ``stiction`` chooses s:

- ``false`` (the default plant): s = tanh(dq / 2 q_e), a steep but smooth function of
  velocity; a joint under half its static level creeps at ~10 mrad/s;
- ``true``: s = sign(dq) sliding, and at rest |τ_f| ≤ τ_s + F(q), whatever holds the joint
  still: a joint at rest stays until the torque on it exceeds the static level. The plant
  solves it as MuJoCo's joint friction loss, a constraint (:class:`sim_bridge.plant.Plant`).

Assist cylinders push with p·S along their rod: a crank (pivot A,
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
        # f1, f3, f5 multiply sin(q/R), sin(2q/R), sin q; f2, f4, f6 the cosines; (3, n)
        self._f_sin, self._f_cos = self.fourier[:, 0::2].T.copy(), self.fourier[:, 1::2].T.copy()
        self.inv_r = 1.0 / np.asarray(gear_ratio, dtype=float)
        self.inv_q_e, self._minus_inv_q_e = 1.0 / self.q_e, -1.0 / self.q_e
        self._inv_2q_e = 0.5 / self.q_e
        # The ripple as amplitudes and phases, f_s sin x + f_c cos x = A sin(x + φ), over the
        # angles x = (q/R, 2q/R, q) of every joint, (3, n): one sine per term per cycle.
        self._angle_per_rad = np.stack((self.inv_r, 2.0 * self.inv_r, np.ones_like(self.inv_r)))
        self._ripple_amp = np.hypot(self._f_sin, self._f_cos)
        self._ripple_phase = np.arctan2(self._f_cos, self._f_sin)
        self._angles = np.zeros_like(self._ripple_amp)

    def coulomb_level(self, q: np.ndarray) -> np.ndarray:
        """F(q) [N·m] at positions ``q`` [rad], (n,): the Coulomb level with its position
        ripple (module docstring), never below 0. It changes with position only, so the plant
        evaluates it once per controller cycle."""
        angles = self._angles
        np.multiply(self._angle_per_rad, q, out=angles)
        angles += self._ripple_phase
        np.sin(angles, out=angles)
        angles *= self._ripple_amp
        level = angles.sum(axis=0)
        level += self.tau_c
        return np.maximum(level, 0.0, out=level)

    def dry_level_nm(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """The dry friction's level [N·m] at ``q`` [rad], ``dq`` [rad/s], (n,): the static
        level τ_s + F(q) at rest, decaying towards the Coulomb level F(q) over the Stribeck
        velocity. At rest it is the most the joint holds against (stiction); sliding, the
        torque it opposes the motion with."""
        return self._level(dq, self.coulomb_level(q))

    def _level(self, dq: np.ndarray, coulomb: np.ndarray) -> np.ndarray:
        """:meth:`dry_level_nm` with the Coulomb level ``coulomb`` already evaluated."""
        return self.tau_s * np.exp(-np.abs(dq) * self.inv_q_e) + coulomb

    def torque_nm(self, dq: np.ndarray, coulomb: np.ndarray) -> np.ndarray:
        """The smooth law's friction torque [N·m] at velocities ``dq`` [rad/s] with the
        Coulomb level ``coulomb`` (:meth:`coulomb_level`), without the linear viscous term
        τ_v1 dq (the plant's MuJoCo joint damping), (n,): the dry level times
        tanh(dq / 2 q_e), which lets a joint under any torque creep (module docstring)."""
        return self._level(dq, coulomb) * np.tanh(dq * self._inv_2q_e) + self.v2 * dq * np.abs(dq)

    def stribeck_into(self, dq: np.ndarray, coulomb: np.ndarray, out: np.ndarray) -> None:
        """:meth:`dry_level_nm` at velocities ``dq`` with the Coulomb level ``coulomb`` (at the
        same position) into ``out``: the plant's per-tick update, so the level drops as a
        joint breaks away, not a cycle later."""
        np.abs(dq, out=out)
        out *= self._minus_inv_q_e
        np.exp(out, out=out)
        out *= self.tau_s
        out += coulomb

    def damping_nm_s_per_rad(self, dq: np.ndarray) -> np.ndarray:
        """The viscous terms τ_v1 dq + τ_v2 dq |dq| as a damping coefficient at ``dq``
        [rad/s]: τ_v1 + τ_v2 |dq| [N·m·s/rad], (n,)."""
        return self.v1 + self.v2 * np.abs(dq)


class AssistCylinders:
    """Joint torques of the assist cylinders at their chamber pressures."""

    def __init__(self, units: Sequence[CylinderUnit], n_joints: int) -> None:
        self.units = tuple(units)
        self.n = n_joints
        self.area_m2 = [math.pi * u.piston_diameter_m**2 / 4.0 for u in self.units]
        #: per unit, what :meth:`arms_and_gas` needs: (joint index, crank?, sign, |AB||AC|,
        #: |AB|² + |AC|², 2|AB||AC|, |BC| at q = 0, |AB|, L₀)
        self._plain = [
            (
                u.joint - 1,
                u.kind == "crank",
                float(u.sign),
                u.ab_m * u.ac_m,
                u.ab_m**2 + u.ac_m**2,
                2.0 * u.ab_m * u.ac_m,
                math.sqrt(u.ab_m**2 + u.ac_m**2 + 2.0 * u.ab_m * u.ac_m),
                u.ab_m,
                u.gas_length_m,
            )
            for u in self.units
        ]

    def arms_and_gas(self, q: Sequence[float]) -> tuple[list[float], list[float]]:
        """Per unit at joint angles ``q`` [rad] (a list of floats): the signed moment arm [m]
        (:meth:`moment_arm_m`) and the gas column [m] (L₀ plus :meth:`extension_m`, never
        below a tenth of L₀; ``inf`` for an ideal reservoir), in one pass of plain floats with
        each unit's constants gathered once. :meth:`gas_columns_m` and :meth:`torque_nm` are
        this; :meth:`moment_arm_m` and :meth:`extension_m` state the geometry one unit at a
        time (a test keeps the two equal)."""
        arms, gas = [], []
        for j, crank, sign, ab_ac, sum_sq, two_ab_ac, bc0, ab, gas0 in self._plain:
            qj = q[j]
            if crank:  # the angle BAC = π - q: cos BAC = -cos q, sin BAC = sin q
                bc = math.sqrt(sum_sq + two_ab_ac * math.cos(qj))
                arms.append(sign * ab_ac * math.sin(qj) / bc)
                extension = -sign * (bc - bc0)
            else:
                arms.append(sign * ab * math.cos(qj))
                extension = sign * ab * math.sin(qj)
            gas.append(max(gas0 + extension, 0.1 * gas0) if gas0 > 0 else math.inf)
        return arms, gas

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

    def gas_columns_m(self, q: np.ndarray) -> list[float]:
        """Each chamber's gas volume over its piston area [m] at joint angles ``q``
        (``inf`` for an ideal reservoir, ``gas_length_m`` 0); never below a tenth of L₀."""
        return self.arms_and_gas(np.asarray(q, dtype=float).tolist())[1]

    def torque_from_arms(self, arms: Sequence[float], p_bar: Sequence[float]) -> np.ndarray:
        """Joint torques [N·m] (n,) from the units' moment arms (:meth:`arms_and_gas`) at
        chamber pressures ``p_bar``."""
        tau = [0.0] * self.n
        for unit, area, arm, p in zip(self._plain, self.area_m2, arms, p_bar, strict=True):
            tau[unit[0]] += area * p * PA_PER_BAR * arm
        return np.array(tau)

    def torque_nm(self, q: np.ndarray, p_bar: np.ndarray) -> np.ndarray:
        """Joint torques [N·m] (n,), zero on joints without a cylinder."""
        arms = self.arms_and_gas(np.asarray(q, dtype=float).tolist())[0]
        return self.torque_from_arms(arms, np.asarray(p_bar, dtype=float).tolist())
