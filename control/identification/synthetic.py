"""Synthetic measurements for tests and the benchmark: pinocchio inverse dynamics of a URDF,
eq. (15) friction, optional injected effects and cylinders, noise, along multi-sine trajectories.

A :class:`MultiSine` is a smooth, periodic excitation trajectory (sums of sines, as the Fourier
excitation of Gaz et al. and most identification experiments) kept inside the joint limits and
under a speed bound, with exact derivatives, so samples at shifted times (a torque delay) are
exact too.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from control.identification.datafile import Measurements
from control.identification.rigid import RobotRegressor
from control.model.cylinders import cylinder_torque_nm
from control.model.friction import FrictionParams, friction_eq15
from gateway.robot.description import RobotDescription

#: Torque noise per joint for the GR630ST [N·m], white at the recording rate.
GR630ST_NOISE_NM = (4.0, 6.0, 4.0, 0.4, 0.3, 0.2)
#: Speed bound per GR630ST joint for synthetic trajectories [rad/s].
GR630ST_MAX_SPEED_RAD_S = (0.6, 0.5, 0.6, 1.5, 1.5, 2.0)


@dataclass(frozen=True)
class MultiSine:
    """``q_j(t) = c_j + Σ_l a_jl sin(2π l f0 t + φ_jl)`` [rad], with exact dq and ddq."""

    center_rad: np.ndarray  # (n,)
    amplitude_rad: np.ndarray  # (n, L)
    phase_rad: np.ndarray  # (n, L)
    base_hz: float

    @classmethod
    def random(
        cls,
        lower_rad: np.ndarray,
        upper_rad: np.ndarray,
        rng: np.random.Generator,
        max_speed_rad_s: np.ndarray | Sequence[float],
        n_harmonics: int = 5,
        base_hz: float = 0.05,
        fill: float = 0.8,
        max_half_range_rad: float = np.pi,
    ) -> MultiSine:
        """Random trajectory within ``fill`` × the joint range (half-range capped at
        ``max_half_range_rad``) and under ``max_speed_rad_s`` per joint."""
        lower = np.asarray(lower_rad, dtype=float)
        upper = np.asarray(upper_rad, dtype=float)
        n = lower.size
        center = 0.5 * (lower + upper)
        half = np.minimum(0.5 * (upper - lower), max_half_range_rad) * fill
        harmonics = np.arange(1, n_harmonics + 1)
        amp = rng.normal(size=(n, n_harmonics)) / harmonics
        phase = rng.uniform(0, 2 * np.pi, size=(n, n_harmonics))
        traj = cls(center, amp, phase, base_hz)
        t = np.linspace(0, 1 / base_hz, 4000, endpoint=False)
        q, dq, _ = traj(t)
        span = np.max(np.abs(q - center), axis=0)
        speed = np.max(np.abs(dq), axis=0)
        scale = np.minimum(half / span, np.asarray(max_speed_rad_s, dtype=float) / speed)
        return cls(center, amp * scale[:, None], phase, base_hz)

    def __call__(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q [rad], dq [rad/s], ddq [rad/s²] at times ``t_s`` (T,), each (T, n)."""
        t = np.asarray(t_s, dtype=float)[:, None, None]
        w = 2 * np.pi * self.base_hz * np.arange(1, self.amplitude_rad.shape[1] + 1)
        arg = w * t + self.phase_rad
        q = self.center_rad + np.sum(self.amplitude_rad * np.sin(arg), axis=2)
        dq = np.sum(self.amplitude_rad * w * np.cos(arg), axis=2)
        ddq = -np.sum(self.amplitude_rad * w**2 * np.sin(arg), axis=2)
        return q, dq, ddq


def default_friction(
    gear_ratios: Sequence[float], torque_scale_nm: Sequence[float], rng: np.random.Generator
) -> list[FrictionParams]:
    """Plausible eq. (15) friction per joint, scaled by ``torque_scale_nm`` (Coulomb ≈ 2 %)."""
    out = []
    for ratio, scale in zip(gear_ratios, torque_scale_nm, strict=True):
        s = float(scale)
        out.append(
            FrictionParams(
                tau_s_nm=0.01 * s * rng.uniform(0.5, 1.0),
                tau_c_nm=0.02 * s * rng.uniform(0.7, 1.3),
                f1_nm=0.002 * s * rng.normal(),
                f2_nm=0.002 * s * rng.normal(),
                f3_nm=0.0,
                f4_nm=0.0,
                f5_nm=0.004 * s * rng.normal(),
                f6_nm=0.004 * s * rng.normal(),
                tau_v1_nm_s_per_rad=0.03 * s * rng.uniform(0.5, 1.5),
                tau_v2_nm_s2_per_rad2=0.005 * s * rng.uniform(0.0, 1.0),
                q_e_rad_s=0.05,
                gear_ratio=float(ratio),
            )
        )
    return out


def point_mass_torque(
    reg: RobotRegressor,
    q: np.ndarray,
    dq: np.ndarray,
    ddq: np.ndarray,
    mass_kg: float,
    com_m: Sequence[float],
) -> np.ndarray:
    """Joint torques [N·m] of a point mass fixed in the last link's frame at ``com_m`` [m]."""
    params = pin.Inertia(
        mass_kg, np.asarray(com_m, dtype=float), np.zeros((3, 3))
    ).toDynamicParameters()
    cols = np.arange(10 * (reg.n - 1), 10 * reg.n)
    y = reg.regressor_columns(q, dq, ddq, cols)  # (n, T, 10)
    return np.einsum("jtk,k->tj", y, params)


ExtraTorque = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def synthesize(
    reg: RobotRegressor,
    trajectory: MultiSine,
    t_s: np.ndarray,
    friction: Sequence[FrictionParams],
    noise_nm: Sequence[float],
    rng: np.random.Generator,
    q_noise_rad: float = 1e-6,
    delay_s: float = 0.0,
    extra: Sequence[ExtraTorque] = (),
    desc: RobotDescription | None = None,
    pressures_bar: np.ndarray | None = None,
    with_dq: bool = False,
    source: str = "synthetic",
) -> Measurements:
    """A measured recording: ``τ = rnea + friction (+ extras) (- T_cyl)`` plus noise.

    The torque is computed at the kinematics of ``t - delay_s`` (a lagging torque signal);
    each ``extra(q, dq, ddq, t)`` adds (T, n) joint torques [N·m]. With ``desc`` and
    ``pressures_bar`` (T, c) the cylinders' torque is subtracted (the motor holds
    ``g - T_cyl``) and the pressures are recorded as ``p<joint>`` columns.
    """
    t = np.asarray(t_s, dtype=float)
    q, dq, ddq = trajectory(t)
    qd, dqd, ddqd = trajectory(t - delay_s) if delay_s else (q, dq, ddq)
    tau = reg.rnea(qd, dqd, ddqd) + friction_eq15(qd, dqd, friction)
    for fn in extra:
        tau = tau + fn(qd, dqd, ddqd, t)
    p = None
    p_joints: tuple[int, ...] = ()
    if desc is not None and pressures_bar is not None:
        tau = tau - cylinder_torque_nm(qd, pressures_bar, desc)
        p = np.asarray(pressures_bar, dtype=float)
        p_joints = tuple(c.joint_index + 1 for c in desc.cylinders)
    tau = tau + rng.normal(size=tau.shape) * np.asarray(noise_nm, dtype=float)
    q_meas = q + rng.normal(size=q.shape) * q_noise_rad
    return Measurements(
        t=t,
        q=q_meas,
        dq=dq.copy() if with_dq else None,
        tau=tau,
        p=p,
        source=source,
        p_joints=p_joints,
    )
