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

**ω adapts to the measured motor current, eq. (28).** With estimates ω̂ and Υ̂_I the inner loop
delivers ``τ = K*[ω̂ τ_d + (Υ_I - Υ̂_I) e]`` (eq. 23); holding a load (e at its steady value
ω̂ τ_d / Υ̂_I) that is ``τ = τ_d · K* ω̂ Υ_I / Υ̂_I``: a static gain that is 1 only for exact
estimates. A zero-moment arm has nothing else holding it, so a 2 % error in the identified
K_I lets a 1,000 kg arm sink (measured on the virtual cell: 0.6 m in 5 s with a spray gun
mounted, against 0.5 mm with the exact gains). The drive reports its motor current, so the
torque it delivered is measured (``τ_m = K i``, K the datasheet's torque constant) and eq. (28),
``dω̂/dt = -Λ τ_d (τ_m - τ_d)``, drives the error to zero. As for the paper's laws below, the
regressor is the command the drive actually followed, not the designed τ_d: with the cycle
means u₁ = mean(dq_c - dq) and u₂ = mean(q_c - q) of the command that drove the cycle, the
estimates predict ``τ̂ = (u₁ + Υ̂_I u₂) / ω̂``, which is τ_d when the arm moved as the delay
predictor said (control/rt/src/law/delay.rs). When it did not (the hand pushed, the model's
inertia is off), τ_d no longer says what the drive was asked for, and a gradient on it learnt the
mismatch as a gain error (teach-bench, seed 0: J6's ω̂ ended at 0.67 of the drive's after
59 s of teaching, J1's at 0.93; with τ̂, see the README). We take the normalised gradient
Λ = γ ω̂ / τ̂² per joint, in the log of ω̂, which makes the convergence rate γ independent of
the load and keeps ω̂ > 0::

    ω̂ ← ω̂ · exp(-γ dt · clip((τ_m - τ̂) / τ̂, ±0.5)),   projected onto [ω̂₀/2, 2 ω̂₀]

with ω̂₀ the commissioned value. Before the first cycle, while the drive still holds the arm at
rest (q_c fixed, dq = dq_c = 0), eq. (19) reads ``K i = K K_I (q_c - q)``: the held offset and
the reported current measure K K_I, and :meth:`OuterLoop.calibrate_from_hold` sets the ω̂ for
which the static gain is 1 before the arm is released (from the mean of the hold's last
states, :class:`HoldAverage`). It adapts only on a cycle the drive followed as sent (no hold,
no coast, the cycle after it not missed: the caller's business) and whose |τ̂| is above
``min_torque_nm`` (the current's noise would otherwise dominate). A command the tool speed
limit scaled is the command the drive followed, so its cycle teaches as any other. γ
(``rate_per_s``, about 1/s) is far below Υ_I (~30/s), so the offset filter settles long
before ω̂ moves. The operator's hand does not enter τ_m - τ̂ (both are the drive's torque):
holding the tool against a stop does not drift ω̂. Υ̂_I and the dynamic parameters (eqs. 29,
30) stay at their identified values.

**The paper's laws (28) and (30) together** (:class:`PaperAdaptation`, ``[control] strategy =
"paper"``). Eq. (23) says the torque the drive delivers is

    τ = τ_d + K* [(ω̂ - ω) τ_d - (Υ̂_I - Υ_I)(q_c - q)],

so with e = τ_m - τ_d (measured minus desired), gradient descent on e²/2 is eq. (28),
``dω̂/dt = -Λ τ_d e``, and ``dΥ̂_I/dt = +Λ_I (q_c - q) e``. The paper prints eq. (30) with a
minus sign; with its eq. (26) its Lyapunov derivative (31) is then ``-eᵀe`` plus a cross term
of either sign, so we take the sign for which V̇ ≤ 0 (only the two laws' relative sign
matters: the paper's e = τ̂_d - τ_d flips both). Three things keep the laws from being used as
printed:

- *The drive does not receive eq. (21) as designed.* Commands arrive a cycle late, are held
  over a cycle and limited, so ``(dq_c - dq) + Υ̂_I (q_c - q) = ω̂ τ_d`` holds only roughly,
  and a gradient on the designed τ_d and q_c - q learns that mismatch as a gain error (a
  one-joint simulation of the drive with a one-cycle command delay ended 20-75 % off). So
  the regressors are the ones the drive actually saw, the cycle means u₁ = mean(dq_c - dq)
  and u₂ = mean(q_c - q) of the command that drove the cycle (:func:`cycle_means` of
  control/rt/src/law/inner_estimate.rs):
  eq. (19) says ``τ_m = K* (u₁ + Υ_I u₂)``, the estimates predict
  ``τ̂ = (u₁ + Υ̂_I u₂)/ω̂`` (= τ_d when the command went out as designed, which makes this
  eqs. 28 and 30), and the laws descend the gradient of ``(τ_m - τ̂)²/2``.
- *The paper's gains diverge at our rate.* Λ = 0.01 in SI units makes the step of eq. (28)
  over one 4 ms cycle Λ τ_d² K* T ≈ 10⁴ (J2: τ_d ≈ 500 N·m, K* ≈ 2.6·10⁴ N·m·s/rad), where a
  discrete gradient diverges beyond 2. The laws run as one normalised gradient in the logs of
  ω̂ and Υ̂_I (which keeps both positive), the paper's ratio Λ_I/Λ = 2 kept
  (``upsilon_ratio``): with φ = ∂τ̂/∂(ln ω̂, ln Υ̂_I) = (-τ̂, Υ̂_I u₂ / ω̂) [N·m],

      (ln ω̂, ln Υ̂_I) ← (ln ω̂, ln Υ̂_I) + γ T diag(1, Λ_I/Λ) φ s / |φ|,
      s = clip((τ_m - τ̂) / |φ|, ±0.5),

  outside a dead zone |τ_m - τ̂| ≤ ν (3 standard deviations of the motor torque measured in
  the hold before teaching, at least ``dead_zone_nm``: below it the error is the current's
  noise, the paper's bound ν on the unmodelled part) and with |φ| above the adaptation's
  torque floor.
- *ω̂(0) = 0 commands no torque*: the arm would fall while ω̂ grows. ω̂(0) is the hold's
  calibration (:meth:`OuterLoop.calibrate_from_hold`, which makes the static gain 1 for any
  Υ̂_I); Υ̂_I(0) is the commissioned value or the paper's 1.2/s. Both stay within
  ``bound_factor`` of where they started.

**What the gradient cannot do quickly.** K_p enters only through u₁, the velocity error,
which in teaching is a few per cent of Υ_I u₂ (the offset filter keeps dq_c close to dq; the
online estimate measured 1-6 % on the virtual cell). φ then points almost along (-1, 1): the
static gain K K_I = Υ_I/ω converges in seconds, but ω̂ and Υ̂_I apart converge with a time
constant of about 20 s at u₁ = 10 % of Υ_I u₂, 70 s at 3 % and 200 s at 1 % (γ = 1/s,
one joint fed eq. 19's torque: tests/unit/test_paper_adaptation.py). Least squares, which
inverts the regressors' covariance, separates them within seconds where the data allow
(control/rt/src/law/inner_estimate.rs).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np


def _constant(values: np.ndarray) -> np.ndarray:
    arr = np.array(values, dtype=float)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class OmegaAdaptation:
    """Settings of eq. (28) (module docstring)."""

    #: γ: how fast ω̂ converges [1/s]
    rate_per_s: float
    #: per joint: no adaptation while |τ̂| is below this [N·m]
    min_torque_nm: tuple[float, ...]

    def check(self, n: int) -> None:
        if not (math.isfinite(self.rate_per_s) and self.rate_per_s >= 0):
            raise ValueError(f"adaptation rate {self.rate_per_s} must be >= 0")
        if len(self.min_torque_nm) != n or not all(v > 0 for v in self.min_torque_nm):
            raise ValueError(f"adaptation min_torque_nm needs {n} values > 0")


@dataclass(frozen=True)
class PaperAdaptation:
    """Settings of eqs. (28) and (30) together (module docstring, "The paper's laws")."""

    #: γ: how fast the estimates converge [1/s] (the paper's Λ, normalised)
    rate_per_s: float
    #: per joint: no adaptation while |φ| is below this [N·m]
    min_torque_nm: tuple[float, ...]
    #: Λ_I / Λ (the paper: 0.02 / 0.01)
    upsilon_ratio: float = 2.0
    #: per joint: the dead zone's floor on |τ_m - τ̂| [N·m] (the hold's noise may widen it)
    dead_zone_nm: tuple[float, ...] = ()
    #: ω̂ and Υ̂_I stay within this factor of where they started
    bound_factor: float = 50.0

    def check(self, n: int) -> None:
        OmegaAdaptation(self.rate_per_s, self.min_torque_nm).check(n)
        if not (math.isfinite(self.upsilon_ratio) and self.upsilon_ratio >= 0):
            raise ValueError(f"adaptation upsilon_ratio {self.upsilon_ratio} must be >= 0")
        if self.dead_zone_nm and (
            len(self.dead_zone_nm) != n or not all(v >= 0 for v in self.dead_zone_nm)
        ):
            raise ValueError(f"adaptation dead_zone_nm needs {n} values >= 0")
        if not (math.isfinite(self.bound_factor) and self.bound_factor > 1):
            raise ValueError(f"adaptation bound_factor {self.bound_factor} must be > 1")


class HoldAverage:
    """Mean held offset q_c - q and measured motor torque over the last ``size`` states of a
    drive holding the arm at rest, for :meth:`OuterLoop.calibrate_from_hold` (one state's
    current noise would set ω̂ of a lightly loaded wrist joint tens of per cent off)."""

    def __init__(self, size: int = 64) -> None:
        self._rows: deque[tuple[list[float], list[float]]] = deque(maxlen=size)

    def add(self, offset_rad: list[float], tau_m_nm: list[float]) -> None:
        self._rows.append((offset_rad, tau_m_nm))

    def clear(self) -> None:
        self._rows.clear()

    def __len__(self) -> int:
        return len(self._rows)

    def torque_std(self) -> list[float]:
        """The held motor torque's standard deviation per joint [N·m] (its noise at rest);
        raises ValueError with fewer than two states."""
        if len(self._rows) < 2:
            raise ValueError("fewer than two held states")
        return np.std([t for _, t in self._rows], axis=0, ddof=1).tolist()

    def mean(self) -> tuple[list[float], list[float]]:
        """(offset, torque) averaged per joint; raises ValueError when empty."""
        if not self._rows:
            raise ValueError("no hold observed")
        offs, taus = zip(*self._rows, strict=True)
        return np.mean(offs, axis=0).tolist(), np.mean(taus, axis=0).tolist()


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
        adaptation: OmegaAdaptation | PaperAdaptation | None = None,
    ) -> None:
        self.omega0 = _constant(omega)
        self.upsilon_i0 = _constant(upsilon_i)
        self.max_offset_rad = _constant(max_offset_rad)
        self.max_velocity_rad_s = _constant(max_velocity_rad_s)
        n = self.omega0.shape[0]
        for name in ("upsilon_i0", "max_offset_rad", "max_velocity_rad_s"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"{name} must have {n} values")
        if np.any(self.omega0 <= 0) or np.any(self.upsilon_i0 <= 0):
            raise ValueError("omega and upsilon_i must be positive (eq. 21)")
        self.adaptation = adaptation
        if adaptation is not None:
            adaptation.check(n)
        #: ω̂ and Υ̂_I per joint (eq. 28 adapts ω̂; PaperAdaptation both, eqs. 28 and 30)
        self._omega: list[float] = self.omega0.tolist()
        self._ups: list[float] = self.upsilon_i0.tolist()
        wide = adaptation.bound_factor if isinstance(adaptation, PaperAdaptation) else 2.0
        self._omega_lo = (self.omega0 / wide).tolist()
        self._omega_hi = (self.omega0 * wide).tolist()
        self._ups_lo = (self.upsilon_i0 / wide).tolist()
        self._ups_hi = (self.upsilon_i0 * wide).tolist()
        #: per joint, PaperAdaptation's dead zone [N·m] (:meth:`set_dead_zone`)
        self._dead_zone: list[float] = [0.0] * n
        if isinstance(adaptation, PaperAdaptation) and adaptation.dead_zone_nm:
            self._dead_zone = list(adaptation.dead_zone_nm)
        #: per joint: offset limit, velocity limit
        self._joints = list(
            zip(self.max_offset_rad.tolist(), self.max_velocity_rad_s.tolist(), strict=True)
        )
        #: (dt, the Υ̂_I, exp(-Υ̂_I dt)) cached
        self._decay: tuple[float, list[float], list[float]] = (math.nan, [], [])
        self._offset: list[float] = [0.0] * n

    @property
    def omega(self) -> np.ndarray:
        """ω̂ per joint now [rad/s per N·m] (a copy)."""
        return np.array(self._omega)

    @property
    def upsilon_i(self) -> np.ndarray:
        """Υ̂_I per joint now [1/s] (a copy)."""
        return np.array(self._ups)

    def set_dead_zone(self, noise_std_nm: list[float]) -> None:
        """PaperAdaptation's dead zone from the motor torque's noise measured at rest [N·m]:
        3 standard deviations per joint, at least the configured floor."""
        a = self.adaptation
        if isinstance(a, PaperAdaptation):
            floor = a.dead_zone_nm or (0.0,) * len(self._dead_zone)
            self._dead_zone = [max(f, 3.0 * s) for f, s in zip(floor, noise_std_nm, strict=True)]

    @property
    def offset_rad(self) -> np.ndarray:
        """e = q_cmd - q that the next command carries [rad] (a copy)."""
        return np.array(self._offset)

    @offset_rad.setter
    def offset_rad(self, value: np.ndarray) -> None:
        self._offset = np.asarray(value, dtype=float).tolist()

    def reset(self, offset_rad: np.ndarray) -> None:
        """Take over from the command the robot currently follows (bumpless transfer). ω̂
        keeps what it learnt: it is the drive's, not the engagement's."""
        self.offset_rad = np.clip(
            np.asarray(offset_rad, dtype=float), -self.max_offset_rad, self.max_offset_rad
        )

    def adapt(
        self,
        u1_rad_s: list[float],
        u2_rad: list[float],
        tau_m_nm: list[float],
        dt_s: float,
    ) -> None:
        """Eq. (28) (OmegaAdaptation) or eqs. (28) and (30) (PaperAdaptation) for a cycle the
        drive followed as sent (module docstring): its means u₁ = mean(dq_c - dq) [rad/s] and
        u₂ = mean(q_c - q) [rad], and the motor torque measured over it [N·m]."""
        a = self.adaptation
        if isinstance(a, OmegaAdaptation):
            self._adapt_omega(a, u1_rad_s, u2_rad, tau_m_nm, dt_s)
            return
        if not isinstance(a, PaperAdaptation):
            return
        step = a.rate_per_s * dt_s
        for j, (u1, u2, tm, floor, nu) in enumerate(
            zip(u1_rad_s, u2_rad, tau_m_nm, a.min_torque_nm, self._dead_zone, strict=True)
        ):
            w, u = self._omega[j], self._ups[j]
            p2 = u * u2 / w
            p1 = -(u1 / w + p2)  # -τ̂
            r = tm + p1  # τ_m - τ̂
            norm = math.hypot(p1, p2)
            if not (norm > floor and (r > nu or r < -nu)):  # NaN: no step
                continue
            s = r / norm
            s = 0.5 if s > 0.5 else -0.5 if s < -0.5 else s
            self._project(j, w * math.exp(step * p1 / norm * s))
            u *= math.exp(step * a.upsilon_ratio * p2 / norm * s)
            self._ups[j] = min(max(u, self._ups_lo[j]), self._ups_hi[j])

    def _adapt_omega(
        self,
        a: OmegaAdaptation,
        u1_rad_s: list[float],
        u2_rad: list[float],
        tau_m_nm: list[float],
        dt_s: float,
    ) -> None:
        """Eq. (28) alone: ω̂ on τ̂ = (u₁ + Υ̂_I u₂) / ω̂ (module docstring)."""
        step = a.rate_per_s * dt_s
        for j, (u1, u2, tm, floor) in enumerate(
            zip(u1_rad_s, u2_rad, tau_m_nm, a.min_torque_nm, strict=True)
        ):
            w = self._omega[j]
            tau_hat = (u1 + self._ups[j] * u2) / w
            if tau_hat > floor or tau_hat < -floor:  # NaN: no step
                r = (tm - tau_hat) / tau_hat
                if r != r:
                    continue
                r = 0.5 if r > 0.5 else -0.5 if r < -0.5 else r
                self._project(j, w * math.exp(-step * r))

    def calibrate_from_hold(self, offset_rad: list[float], tau_m_nm: list[float]) -> None:
        """ω̂ from the drive holding the arm at rest (module docstring): there eq. (19) is
        ``K i = K K_I (q_c - q)``, so the measured ``tau_m_nm`` over the held offset
        ``offset_rad`` = q_c - q is K K_I, and the static gain K K_I ω̂ / Υ̂_I of eq. (23) is 1
        for ω̂ = Υ̂_I (q_c - q) / τ_m. Joints below the adaptation's torque floor, or whose
        torque and offset disagree in sign, keep their ω̂; the result is projected as eq. (28)
        projects."""
        a = self.adaptation
        if a is None:
            return
        for j, (e, tm, floor, ups) in enumerate(
            zip(offset_rad, tau_m_nm, a.min_torque_nm, self._ups, strict=True)
        ):
            if (tm > floor or tm < -floor) and e * tm > 0:
                self._project(j, ups * e / tm)

    def _project(self, j: int, omega: float) -> None:
        """Set ω̂ of joint j to ``omega`` projected onto [ω̂₀/2, 2 ω̂₀] (PaperAdaptation:
        ``bound_factor`` either side of ω̂₀)."""
        self._omega[j] = min(max(omega, self._omega_lo[j]), self._omega_hi[j])

    def step(
        self, q_rad: np.ndarray, dq_rad_s: np.ndarray, tau_d_nm: np.ndarray, dt_s: float
    ) -> OuterLoopCommand:
        """One controller cycle of eq. (21); returns the command to send now."""
        e = self.offset_rad
        omega = self.omega
        target = omega * tau_d_nm / self.upsilon_i  # steady-state offset
        decay = np.exp(-self.upsilon_i * dt_s)
        e_next = target + (e - target) * decay
        de = -self.upsilon_i * e + omega * tau_d_nm
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
        if self._decay[0] != dt_s or self._decay[1] != self._ups:
            ups = list(self._ups)
            self._decay = (dt_s, ups, [math.exp(-u * dt_s) for u in ups])
        q_cmd, dq_cmd, offset = [], [], []
        for e, q, dq, tau, dec, omega, ups, (max_e, max_v) in zip(
            self._offset, q_rad, dq_rad_s, tau_d_nm, self._decay[2], self._omega, self._ups,
            self._joints, strict=True,
        ):  # fmt: skip
            target = omega * tau / ups
            e_next = target + (e - target) * dec
            dq_c = dq + (-ups * e + omega * tau)
            offset.append(max_e if e_next > max_e else -max_e if e_next < -max_e else e_next)
            dq_cmd.append(max_v if dq_c > max_v else -max_v if dq_c < -max_v else dq_c)
            q_cmd.append(q + e)
        self._offset = offset
        return q_cmd, dq_cmd
