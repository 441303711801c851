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

import math
from dataclasses import dataclass

import numpy as np


def _constant(values: np.ndarray) -> np.ndarray:
    arr = np.array(values, dtype=float)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class OuterLoopCommand:
    q_cmd_rad: np.ndarray
    dq_cmd_rad_s: np.ndarray
    offset_rad: np.ndarray  #: e = q_cmd - q after this step
    saturated: np.ndarray  #: per joint: the offset or velocity limit was hit


class OuterLoop:
    """Discrete eq. (21) with per-joint limits on the offset and the velocity command.

    ``omega`` is ω = 1/(K K_p) per joint [rad/s per N·m]; ``upsilon_i`` is Υ_I = K_I/K_p [1/s].
    They and the limits are fixed at construction (read-only arrays): :meth:`step_floats` keeps
    a copy as plain floats.
    """

    def __init__(
        self,
        omega: np.ndarray,
        upsilon_i: np.ndarray,
        max_offset_rad: np.ndarray,
        max_velocity_rad_s: np.ndarray,
    ) -> None:
        self.omega = _constant(omega)
        self.upsilon_i = _constant(upsilon_i)
        self.max_offset_rad = _constant(max_offset_rad)
        self.max_velocity_rad_s = _constant(max_velocity_rad_s)
        n = self.omega.shape[0]
        for name in ("upsilon_i", "max_offset_rad", "max_velocity_rad_s"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"{name} must have {n} values")
        if np.any(self.omega <= 0) or np.any(self.upsilon_i <= 0):
            raise ValueError("omega and upsilon_i must be positive (eq. 21)")
        #: per joint: ω, Υ_I, offset limit, velocity limit
        self._joints = list(
            zip(
                self.omega.tolist(),
                self.upsilon_i.tolist(),
                self.max_offset_rad.tolist(),
                self.max_velocity_rad_s.tolist(),
                strict=True,
            )
        )
        self._decay: tuple[float, list[float]] = (math.nan, [])  #: (dt, exp(-Υ_I dt)) cached
        self._offset: list[float] = [0.0] * n

    @property
    def offset_rad(self) -> np.ndarray:
        """e = q_cmd - q that the next command carries [rad] (a copy)."""
        return np.array(self._offset)

    @offset_rad.setter
    def offset_rad(self, value: np.ndarray) -> None:
        self._offset = np.asarray(value, dtype=float).tolist()

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

    def step_floats(
        self, q_rad: list[float], dq_rad_s: list[float], tau_d_nm: list[float], dt_s: float
    ) -> tuple[list[float], list[float]]:
        """:meth:`step` on plain floats, the per-cycle form: returns ``(q_cmd, dq_cmd)`` only
        (no saturation flags) and is equal to :meth:`step` to rounding. NaN passes through the
        limits, as in :meth:`step`, for the message layer to refuse."""
        if self._decay[0] != dt_s:
            self._decay = (dt_s, np.exp(-self.upsilon_i * dt_s).tolist())
        q_cmd, dq_cmd, offset = [], [], []
        for e, q, dq, tau, dec, (omega, ups, max_e, max_v) in zip(
            self._offset, q_rad, dq_rad_s, tau_d_nm, self._decay[1], self._joints, strict=True
        ):
            target = omega * tau / ups
            e_next = target + (e - target) * dec
            dq_c = dq + (-ups * e + omega * tau)
            offset.append(max_e if e_next > max_e else -max_e if e_next < -max_e else e_next)
            dq_cmd.append(max_v if dq_c > max_v else -max_v if dq_c < -max_v else dq_c)
            q_cmd.append(q + e)
        self._offset = offset
        return q_cmd, dq_cmd
