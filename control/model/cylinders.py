"""Assist-cylinder torques of the paper, eqs. (3)-(12).

J2 (crank, eq. 10), with the cylinder pivots A2, B2, C2 of Fig. 3::

    T2 = P2 S2 |A2B2| |A2C2| sin(π - θ2) / sqrt(|A2B2|² + |A2C2|² - 2 |A2B2| |A2C2| cos(π - θ2))

J3 (lever, eq. 12)::

    T3 = P3 S3 |A3B3| cos(θ3)

with piston area S = π d²/4 (eq. 9) and pressure P in Pa (the API takes bar, 1 bar = 1e5 Pa).

Angle convention (ours; the figures are missing from the text): θ2 = q2 and θ3 = q3, the joint's
own angle from the Table I zero pose where the upper arm is upright. So T2 vanishes with the
upper arm upright and T3 peaks with the forearm near horizontal. Each cylinder's
``torque_sign`` (+1/-1) then maps the equation's torque onto the joint's positive direction,
chosen so the cylinder opposes gravity. The returned torque *drives* the joint, so the motor's
holding torque is ``g(q) - T_cyl(q, p)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from gateway.robot.description import BAR_TO_PA, CylinderSpec, RobotDescription


def _specs(desc_or_specs: RobotDescription | Sequence[CylinderSpec]) -> tuple[CylinderSpec, ...]:
    if isinstance(desc_or_specs, RobotDescription):
        return desc_or_specs.cylinders
    return tuple(desc_or_specs)


def _n_dof(desc_or_specs: RobotDescription | Sequence[CylinderSpec], q: np.ndarray) -> int:
    if isinstance(desc_or_specs, RobotDescription):
        return desc_or_specs.n_dof
    return q.shape[-1]


def torque_per_pa(spec: CylinderSpec, q_joint_rad: np.ndarray) -> np.ndarray:
    """Signed joint torque per pascal [N·m/Pa] of one cylinder: eq. (10) or (12) with P = 1 Pa.

    ``q_joint_rad`` is the angle of the cylinder's own joint, any shape.
    """
    q = np.asarray(q_joint_rad, dtype=float)
    area = spec.piston_area_m2
    if spec.kind == "j2_crank":
        ab, ac = spec.ab_m, float(spec.ac_m)  # type: ignore[arg-type]
        phi = np.pi - q  # ∠B2A2C2 of eqs. (4)-(8)
        bc = np.sqrt(ab**2 + ac**2 - 2.0 * ab * ac * np.cos(phi))  # eq. (5)
        gain = area * ab * ac * np.sin(phi) / bc  # eq. (10) / P2
    elif spec.kind == "j3_lever":
        gain = area * spec.ab_m * np.cos(q)  # eq. (12) / P3
    else:  # pragma: no cover - CylinderSpec refuses other kinds
        raise ValueError(f"unknown cylinder kind {spec.kind!r}")
    return spec.torque_sign * gain


def cylinder_torque_nm(
    q_rad: np.ndarray,
    p_bar: np.ndarray | Sequence[float],
    desc_or_specs: RobotDescription | Sequence[CylinderSpec],
) -> np.ndarray:
    """Joint torques the cylinders apply [N·m], eqs. (10) and (12); zero on other joints.

    ``q_rad`` has shape (n,) or (T, n); ``p_bar`` [bar] has one pressure per cylinder (in the
    description's ``cylinders`` order), shape (c,) or (T, c). Returns the shape of ``q_rad``.
    """
    specs = _specs(desc_or_specs)
    q = np.asarray(q_rad, dtype=float)
    p = np.asarray(p_bar, dtype=float)
    if p.shape[-1:] != (len(specs),):
        raise ValueError(f"p_bar needs {len(specs)} pressures (one per cylinder), got {p.shape}")
    n = _n_dof(desc_or_specs, q)
    if q.shape[-1] != n:
        raise ValueError(f"q_rad needs {n} joints, got shape {q.shape}")
    tau = np.zeros(np.broadcast_shapes(q.shape, (*p.shape[:-1], n)))
    for k, spec in enumerate(specs):
        j = spec.joint_index
        tau[..., j] = torque_per_pa(spec, q[..., j]) * p[..., k] * BAR_TO_PA
    return tau


def pressure_for_torque(
    q_rad: np.ndarray,
    tau_nm: np.ndarray,
    desc_or_specs: RobotDescription | Sequence[CylinderSpec],
    min_gain_nm_per_bar: float = 1e-6,
) -> np.ndarray:
    """Inverse of :func:`cylinder_torque_nm`: pressures [bar] giving joint torques ``tau_nm``.

    ``tau_nm`` is a joint-torque vector like ``q_rad`` ((n,) or (T, n)); only the entries of
    cylinder joints are used. Returns (c,) or (T, c). Where the cylinder has no lever (eq. (10)
    at q2 = 0, eq. (12) at q3 = ±90°, gain below ``min_gain_nm_per_bar``) the pressure is NaN.
    The result may be negative: a cylinder can only push, so callers clip to what it can give.
    """
    specs = _specs(desc_or_specs)
    q = np.asarray(q_rad, dtype=float)
    tau = np.asarray(tau_nm, dtype=float)
    out = np.empty((*np.broadcast_shapes(q.shape, tau.shape)[:-1], len(specs)))
    for k, spec in enumerate(specs):
        j = spec.joint_index
        gain = torque_per_pa(spec, q[..., j]) * BAR_TO_PA
        ok = np.abs(gain) >= min_gain_nm_per_bar
        out[..., k] = np.where(ok, tau[..., j] / np.where(ok, gain, 1.0), np.nan)
    return out


def with_measured_cylinders(
    desc: RobotDescription, measured: Sequence[dict[str, Any]], where: str
) -> RobotDescription:
    """``desc`` with the piston diameters an identified model measured
    (:mod:`control.identification.cylinders`: its force scale as a diameter, the model file's
    ``analysis.cylinders.cylinders`` entries). Each entry names the joint and the diameter the
    description had when it was measured: a description whose cylinder has neither that nor
    the measured diameter (another cylinder was mounted since) raises ``ValueError`` naming
    ``where``, since the measurement is of a cylinder that is no longer there. Applying it to
    a description that already has the measured diameters changes nothing."""
    cylinders = list(desc.cylinders)
    for entry in measured:
        j = int(entry["joint_index"])
        found = [k for k, c in enumerate(cylinders) if c.joint_index == j]
        if not found:
            raise ValueError(f"{where}: a cylinder on J{j + 1} was measured; {desc.name} has none")
        k = found[0]
        have = cylinders[k].piston_diameter_m
        described = float(entry["described_piston_diameter_m"])
        measured_d = float(entry["piston_diameter_m"])
        if not (np.isfinite(measured_d) and measured_d > 0):
            raise ValueError(f"{where}: J{j + 1} cylinder's piston diameter {measured_d!r}")
        if not (np.isclose(have, described, rtol=1e-9) or np.isclose(have, measured_d, rtol=1e-9)):
            raise ValueError(
                f"{where}: J{j + 1} cylinder was measured on a {1000 * described:.4g} mm piston "
                f"as described then; {desc.name} now describes {1000 * have:.4g} mm: identify again"
            )
        cylinders[k] = replace(cylinders[k], piston_diameter_m=measured_d)
    return replace(desc, cylinders=tuple(cylinders))
