"""Outer loop of the paper: desired torque → position/velocity commands for a closed PI loop.

The vendor's inner loop is eq. (19): ``i_c = -K_p (dq - dq_c) - K_I (q - q_c)``, so the torque it
produces is ``K i_c = K* [(dq_c - dq) + Υ_I (q_c - q)]`` with ``K* = K K_p`` and
``Υ_I = K_p⁻¹ K_I`` (eq. 20). Eq. (21) chooses the command so that this torque equals
``diag(ω) τ_d`` scaled back by ``K*``:

    dq_c + Υ_I q_c = dq + Υ_I q + diag(ω) τ_d                                   (21)

Writing the command as an offset from the measurement, ``e = q_c - q``, eq. (21) is the stable
first-order filter ``de/dt = -Υ_I e + ω τ_d``. We integrate it exactly over one controller cycle
(zero-order hold on τ_d) and send ``q_c = q + e``, ``dq_c = dq + de/dt``. With ω = 1/K* and the
true Υ_I, the inner loop delivers τ = τ_d (eq. 23 with Δω = 0, ΔΥ_I = 0).

The adaptive laws (28)–(30) that learn ω and Υ_I are a later step; here both are fixed from
configuration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OuterLoopCommand:
    q_cmd_rad: np.ndarray
    dq_cmd_rad_s: np.ndarray
    offset_rad: np.ndarray  #: e = q_cmd - q after this step
    saturated: np.ndarray  #: per joint: the offset or velocity limit was hit


class OuterLoop:
    """Discrete eq. (21) with per-joint limits on the offset and the velocity command.

    ``omega`` is ω = 1/(K K_p) per joint [rad/s per N·m]; ``upsilon_i`` is Υ_I = K_I/K_p [1/s].
    """

    def __init__(
        self,
        omega: np.ndarray,
        upsilon_i: np.ndarray,
        max_offset_rad: np.ndarray,
        max_velocity_rad_s: np.ndarray,
    ) -> None:
        self.omega = np.asarray(omega, dtype=float)
        self.upsilon_i = np.asarray(upsilon_i, dtype=float)
        self.max_offset_rad = np.asarray(max_offset_rad, dtype=float)
        self.max_velocity_rad_s = np.asarray(max_velocity_rad_s, dtype=float)
        n = self.omega.shape[0]
        for name in ("upsilon_i", "max_offset_rad", "max_velocity_rad_s"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"{name} must have {n} values")
        if np.any(self.omega <= 0) or np.any(self.upsilon_i <= 0):
            raise ValueError("omega and upsilon_i must be positive (eq. 21)")
        self.offset_rad = np.zeros(n)

    def reset(self, offset_rad: np.ndarray) -> None:
        """Take over from the command the robot currently follows (bumpless transfer)."""
        self.offset_rad = np.clip(
            np.asarray(offset_rad, dtype=float), -self.max_offset_rad, self.max_offset_rad
        )

    def step(
        self, q_rad: np.ndarray, dq_rad_s: np.ndarray, tau_d_nm: np.ndarray, dt_s: float
    ) -> OuterLoopCommand:
        """One controller cycle of eq. (21); returns the command to send now."""
        e = self.offset_rad
        target = self.omega * tau_d_nm / self.upsilon_i  # steady-state offset
        decay = np.exp(-self.upsilon_i * dt_s)
        e_next = target + (e - target) * decay
        de = -self.upsilon_i * e + self.omega * tau_d_nm
        sat = np.abs(e_next) > self.max_offset_rad
        e_next = np.clip(e_next, -self.max_offset_rad, self.max_offset_rad)
        dq_cmd = dq_rad_s + de
        vsat = np.abs(dq_cmd) > self.max_velocity_rad_s
        dq_cmd = np.clip(dq_cmd, -self.max_velocity_rad_s, self.max_velocity_rad_s)
        q_cmd = q_rad + e
        self.offset_rad = e_next
        return OuterLoopCommand(q_cmd, dq_cmd, e.copy(), sat | vsat)
