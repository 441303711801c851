"""Online estimate of the vendor's inner-loop gains from the measured motor current.

Eq. (19) is the drive's current command, ``i = K_p (dq_c - dq) + K_I (q_c - q)``, and the drive
reports its current averaged over each cycle (drivers/can/PROTOCOL.md §2.1). Over the cycle
that a command (q_cmd, dq_cmd) drove, between the states at its start (q₀) and end (q₁), the
means are, with the controller's reference ``q_cmd + dq_cmd (t - t_N)`` (§5):

    mean(dq_c - dq) = dq_cmd - (q₁ - q₀)/T,
    mean(q_c - q)   = q_cmd + dq_cmd T/2 - (q₀ + q₁)/2,

so every cycle the drive followed as sent is one linear equation in (K_p, K_I): eq. (26)'s
regressors for Δω and Δω_I written on the current (τ_d and q_c - q, since the outer loop
sets dq_c - dq = ω̂ τ_d - Υ̂_I (q_c - q)). Per joint, recursive least squares with exponential
forgetting (time constant ``memory_s``) estimates ``θ = (K_p/K_p0, K_I/K_I0, b)``, scaled by
the commissioned gains so the three unknowns are of order one, b a current offset the sensor
zero missed [A]. It starts at the commissioned values (θ = (1, 1, 0)) with a prior of
``prior_rel`` relative standard deviation, which the forgetting lets go of: what it reports
after guided motion is measured, not told.

The paper adapts ω̂ and ω̂_I with the gradient laws (28) and (30) on the same regressors; least
squares converges in a few seconds of motion where a gradient with the paper's Λ = 0.01 would
take minutes at our rate, and it gives its own uncertainty. Reported as ω̂ = 1/(K K̂_p) with
K the datasheet's torque constant (the product measures torque as K i, so that is the ω̂ its
eq. (21) needs) and Υ̂_I = K̂_I / K̂_p. The control law keeps using its own ω̂ (eq. 28) and
the commissioned Υ_I; this estimate is telemetry and commissioning's check.

**Excitation.** In zero-moment teaching the command offset q_c - q follows the slowly changing
desired torque, so dq_c - dq is small: on the virtual cell (seed 0, 20 s of raster teaching) the
K_p term of the current was 0.001-0.09 A against 0.02 A of noise while the K_I term was
0.07-1.4 A, and K_p (hence ω̂ and Υ̂_I) was not observable on J1-J3 and J6. ``[control]
inner_loop_dither_a`` adds to the desired torque a sinusoid per joint (K times that current,
at 4.0 + 0.4 j Hz for joint j + 1, near the offset filter's corner Υ_I/2π ≈ 5 Hz, where the K_p
and K_I terms are of one size and 90° apart). With 0.03 A, after 25 s of raster teaching on
the virtual cell (seed 0), ω̂ and Υ̂_I were within 1.8 % of the plant's on J3-J6 and 6.7 % on
J1-J2, where K_p reads ~6 % low (a bias not yet traced: with the true gains the regression's
residual is at the current's noise, 0.025 A). A white dither at the cycle rate excited the
zero-moment loop itself and a velocity dither made it shake.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

#: a joint's cycle is an outlier beyond this many standard deviations of its prediction
REJECT_SIGMA = 5.0


def cycle_means(
    q_cmd: Sequence[float],
    dq_cmd: Sequence[float],
    q_start: Sequence[float],
    q_end: Sequence[float],
    period_s: float,
    dq_start: Sequence[float] | None = None,
    dq_end: Sequence[float] | None = None,
    ticks: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """``(u₁, u₂)`` = (mean(dq_c - dq) [rad/s], mean(q_c - q) [rad]) per joint over the cycle
    the command (q_cmd, dq_cmd) drove, from the measured positions at its start and end (module
    docstring); with the drive's servo ``ticks`` per cycle and the measured velocities, the
    means its PI saw (it samples the state at each tick's start). Non-finite inputs give
    non-finite means."""
    qc, dqc = np.asarray(q_cmd, float), np.asarray(dq_cmd, float)
    q0, q1 = np.asarray(q_start, float), np.asarray(q_end, float)
    with np.errstate(all="ignore"):
        u1 = dqc - (q1 - q0) / period_s
        if ticks and dq_start is not None and dq_end is not None:
            dq0, dq1 = np.asarray(dq_start, float), np.asarray(dq_end, float)
            u1 = u1 - (dq0 - dq1) / ticks
            u2 = (
                qc
                + 0.5 * period_s * (1 - 1 / ticks) * dqc
                - 0.5 * (q0 + q1)
                + (q1 - q0) / (2 * ticks)
            )
        else:
            u2 = qc + 0.5 * period_s * dqc - 0.5 * (q0 + q1)
    return u1, u2


class InnerLoopEstimator:
    """Per-joint RLS on eq. (19) (module docstring). Feed it one cycle at a time."""

    def __init__(
        self,
        kp0_a_s_per_rad: Sequence[float],
        ki0_a_per_rad: Sequence[float],
        drive_gain_nm_per_a: Sequence[float],
        memory_s: float = 30.0,
        prior_rel: float = 1.0,
    ) -> None:
        self.kp0 = np.asarray(kp0_a_s_per_rad, dtype=float)
        self.ki0 = np.asarray(ki0_a_per_rad, dtype=float)
        self.k = np.asarray(drive_gain_nm_per_a, dtype=float)
        n = self.kp0.size
        if self.ki0.shape != (n,) or self.k.shape != (n,):
            raise ValueError("inner-loop estimate: K_p0, K_I0 and K need one value per joint")
        if not (np.all(self.kp0 > 0) and np.all(self.ki0 > 0) and np.all(self.k > 0)):
            raise ValueError("inner-loop estimate: commissioned gains must be > 0")
        if not (memory_s > 0 and prior_rel > 0):
            raise ValueError("inner-loop estimate: memory_s and prior_rel must be > 0")
        self.memory_s = memory_s
        self.theta = np.tile(np.array([1.0, 1.0, 0.0]), (n, 1))
        self.p = np.tile(np.diag([prior_rel**2, prior_rel**2, 0.1**2]), (n, 1, 1))
        #: without excitation P grows as 1/λ^t: its gain part is capped at the prior's
        self._cap = 2.0 * prior_rel**2
        self.updates = 0
        #: per joint, cycles whose residual was rejected as an outlier
        self.rejected = np.zeros(n, dtype=int)
        self.seconds = 0.0

    def update(
        self,
        q_cmd: Sequence[float],
        dq_cmd: Sequence[float],
        q_start: Sequence[float],
        q_end: Sequence[float],
        current_a: Sequence[float],
        period_s: float,
        noise_a: float = 0.02,
        dq_start: Sequence[float] | None = None,
        dq_end: Sequence[float] | None = None,
        ticks: int = 0,
    ) -> None:
        """One cycle the drive followed as sent: its command, the measured positions at the
        cycle's start and end [rad], the reported mean current [A], the cycle [s]."""
        i = np.asarray(current_a, float)
        u1, u2 = cycle_means(q_cmd, dq_cmd, q_start, q_end, period_s, dq_start, dq_end, ticks)
        with np.errstate(all="ignore"):  # a non-finite state is skipped below
            x = np.stack([self.kp0 * u1, self.ki0 * u2, np.ones_like(u1)], axis=1)  # (n, 3)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(i))):
            return
        lam = math.exp(-period_s / self.memory_s)
        px = np.einsum("nij,nj->ni", self.p, x)
        denom = lam * noise_a**2 + np.einsum("ni,ni->n", x, px)
        gain = px / denom[:, None]
        resid = i - np.einsum("ni,ni->n", x, self.theta)
        # A cycle the drive did not run as logged (a command replaced or late on its way: a
        # few per minute, up to 17 A off on J1) must not throw the estimate away: a joint's
        # update is skipped when its residual is beyond REJECT_SIGMA of what the noise and
        # the estimate's own uncertainty allow.
        bound = REJECT_SIGMA * np.sqrt(lam * noise_a**2 + np.einsum("ni,ni->n", x, px))
        out = np.abs(resid) > bound
        if np.any(out):
            self.rejected += out
            gain = np.where(out[:, None], 0.0, gain)
            px = np.where(out[:, None], 0.0, px)
        self.theta = self.theta + gain * resid[:, None]
        self.p = (self.p - np.einsum("ni,nj->nij", gain, px)) / lam
        # keep P symmetric and bounded (no excitation for a while: it grows as 1/λ^t)
        self.p = 0.5 * (self.p + np.transpose(self.p, (0, 2, 1)))
        trace = self.p[:, 0, 0] + self.p[:, 1, 1]
        big = trace > self._cap
        if np.any(big):
            self.p[big] *= (self._cap / trace[big])[:, None, None]
        self.updates += 1
        self.seconds += period_s

    @property
    def kp_hat_a_s_per_rad(self) -> np.ndarray:
        return self.kp0 * self.theta[:, 0]

    @property
    def ki_hat_a_per_rad(self) -> np.ndarray:
        return self.ki0 * self.theta[:, 1]

    @property
    def omega_rad_s_per_nm(self) -> np.ndarray:
        """ω̂ = 1/(K K̂_p) per joint (NaN where K̂_p is not positive)."""
        kp = self.kp_hat_a_s_per_rad
        return np.where(kp > 0, 1.0 / (self.k * np.where(kp > 0, kp, 1.0)), math.nan)

    @property
    def upsilon_i_per_s(self) -> np.ndarray:
        """Υ̂_I = K̂_I / K̂_p per joint (NaN where K̂_p is not positive)."""
        kp = self.kp_hat_a_s_per_rad
        return np.where(kp > 0, self.ki_hat_a_per_rad / np.where(kp > 0, kp, 1.0), math.nan)

    @property
    def rel_std(self) -> np.ndarray:
        """Relative standard deviation of (K̂_p, K̂_I) per joint, (n, 2), from the RLS
        covariance (current noise ``noise_a``)."""
        return np.sqrt(np.maximum(np.stack([self.p[:, 0, 0], self.p[:, 1, 1]], axis=1), 0.0))
