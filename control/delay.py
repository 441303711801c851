"""The arm's state when a command takes effect: a Smith predictor over the command delay.

The drive follows a command ``d`` cycles after the state it answers (the inner-loop experiment
measures ``d``, ``inner_loop.json`` ``delay_cycles``): when the controller applies a command it
starts its reference there, ``q_c + dq_c (t - t_apply)``, with the arm ``d`` cycles further on.
Eq. (21) sent for the stale state acts on a stale offset: the arm's travel over the delay, ``dq
h`` (h = d T), is a damper of ``K K_I h`` (J2 of the GR630ST at 8 ms: some 6,600 N·m·s/rad,
a 20 N push moves nothing), and its speed-up an inertia of ``K K_p h``. Extrapolating the
measurement does not cure it: the drive's own velocity loop (``K K_p / J`` ≈ 110/s, a 9 ms time
constant) moves the arm within the delay more than the hand does, and an extrapolated velocity
fed back as the command destabilises the drive as soon as ``K K_p h / J`` nears 1 (a 1-DOF
scan over inertias and gains ±50 % in the note of 2026-11-25).

The predictor therefore runs what happens within the delay, as the plant will:

- the references already in flight: for a delay of d cycles, the commands the driver sent for
  the last d states, as each state's echo (``JointState.q_cmd_rad``/``dq_cmd_rad_s``) reports
  them, holds and coasts included; the one echoed by the newest state starts now;
- the drive's PI loop of eq. (19) with the estimated gains (``1/ω̂ = K K_p``, ``Υ̂_I``) on the
  arm's inertia ``M(q)`` (the datasheet's nominal rigid body with its rotor inertias);
- everything else (gravity, cylinders, friction, the operator's hand) held at what the last
  cycle showed: ``M a - τ_last``, ``a`` the difference of the last two measured velocities
  over their cycle and ``τ_last`` the drive's torque in that cycle by the same PI model (the
  reference then applied against the cycle's mean state), so ``ddq = a + M⁻¹ (τ_drive -
  τ_last)``. The model rather than the measured current: the current's noise (0.02 A, 0.1 N·m
  on a wrist whose inertia is a fraction of a kg·m²) would enter the predicted velocity each
  cycle and the wrist would wander (4-5 mrad in 5 s on the virtual cell, against 0.7 with the
  model);

integrated in steps of at most :data:`SUBSTEP_S` (semi-implicit Euler), and shorter where the
drive model is stiffer than that step can integrate: its velocity loop's rate ``K K_p
(M⁻¹)ⱼⱼ`` times the step stays below :data:`STIFF_STEP` (a K̂* 26 times the drive's, as the
paper's Υ̂_I(0) gives with the commissioned static gain, made 1 ms steps diverge: commands
10⁴ rad off on the virtual cell), in at most :data:`MAX_SUBSTEPS` per cycle, beyond which the
velocity carries on unchanged over the delay. Eq. (21) is then sent
for the predicted state. Without a consecutive history (start, a gap, a missing echo) the
velocity carries on unchanged over the delay. The scan: with ±30 % inertia and ±20 % gain
errors the loop stays stable and as light as without delay, for delays of 1 and 2 cycles.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

#: longest integration step of the prediction [s] (the drive's servo tick is about 1 ms)
SUBSTEP_S = 0.001
#: the drive model's velocity-loop rate K K_p (M⁻¹)ⱼⱼ × the step stays below this (explicit
#: damping is stable below 2; the GR630ST's commissioned drives reach 0.44 at 1 ms)
STIFF_STEP = 1.0
#: most integration steps per cycle of delay (module docstring)
MAX_SUBSTEPS = 64


class DelayPredictor:
    """Predicts the measured state ``delay_cycles`` cycles on (module docstring). Call
    :meth:`predict` once per state, in order; :meth:`reset` when the history breaks."""

    def __init__(self, delay_cycles: int) -> None:
        if not 0 <= delay_cycles <= 10:
            raise ValueError(f"command delay {delay_cycles} not in 0..10 cycles")
        self.delay_cycles = delay_cycles
        self._echoes: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=max(delay_cycles, 1))
        self._last: tuple[np.ndarray, np.ndarray] | None = None  #: (q, dq) of the last state
        #: the reference the drive followed since the last state (None: unknown)
        self._applied: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self) -> None:
        self._echoes.clear()
        self._last = None
        self._applied = None

    def predict(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        echo_q: np.ndarray,
        echo_dq: np.ndarray,
        period_s: float,
        consecutive: bool,
        m_inv: np.ndarray,
        k_star: np.ndarray,
        upsilon: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(q, dq)`` when the command answering this state takes effect. ``echo_*`` the
        command the driver sent last (this state's echo), ``consecutive`` this state follows
        the last by one cycle, ``m_inv`` M(q)⁻¹,
        ``k_star`` = 1/ω̂ [N·m·s/rad], ``upsilon`` Υ̂_I [1/s]."""
        d = self.delay_cycles
        if d == 0:
            return q, dq
        last, applied = self._last, self._applied
        self._last = (q, dq)
        if not consecutive:
            self._echoes.clear()
            last = applied = None
        self._echoes.append((echo_q, echo_dq))
        full = len(self._echoes) == d
        self._applied = self._echoes[0] if full else None  # followed from now on
        h = d * period_s
        if last is None or applied is None or not full:
            return q + h * dq, dq

        def drive_nm(ref_q: np.ndarray, ref_dq: np.ndarray, qa: np.ndarray, dqa: np.ndarray):
            """Eq. (19)'s torque at arm state (qa, dqa) against the reference (ref_q, ref_dq)."""
            return k_star * ((ref_dq - dqa) + upsilon * (ref_q - qa))

        ref_q, ref_dq = applied  # at the middle of the last cycle, against its mean state
        tau_last = drive_nm(ref_q + 0.5 * period_s * ref_dq, ref_dq, 0.5 * (q + last[0]),
                            0.5 * (dq + last[1]))  # fmt: skip
        base = (dq - last[1]) / period_s - m_inv @ tau_last
        rate = float(np.max(np.diag(m_inv) * k_star))
        steps = max(1, math.ceil(period_s / SUBSTEP_S - 1e-9))
        if not rate * period_s / steps < STIFF_STEP:  # NaN too
            steps = math.ceil(rate * period_s / STIFF_STEP) if math.isfinite(rate) else 0
            if not 0 < steps <= MAX_SUBSTEPS:
                return q + h * dq, dq
        step = period_s / steps
        qp, dqp = q.copy(), dq.copy()
        for ref_q, ref_dq in self._echoes:  # oldest first: the one applied now
            for s in range(steps):
                tau = drive_nm(ref_q + ref_dq * (s * step), ref_dq, qp, dqp)
                dqp = dqp + step * (base + m_inv @ tau)
                qp = qp + step * dqp
        return qp, dqp
