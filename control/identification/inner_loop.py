"""The vendor's inner loop, eq. (19), estimated from what the host sees: its own commands and
the joints' measured positions, velocities and motor currents.

The drive computes, at every servo tick (period ``servo_s``, the manual's 1 kHz) inside a
communication cycle (period ``cycle_s``),

    i = K_p (dq_c - dq) + K_I (q_c - q),      q_c(t) = q_cmd + dq_cmd (t - t_start)

and reports the current averaged over the cycle. Averaged the same way, each cycle gives one
linear equation in (K_p, K_I)::

    ī = K_p (dq_cmd - <dq>) + K_I (q_cmd + dq_cmd (T - h)/2 - <q>) + i_0

where <·> is the mean over the ticks computed from the cycle's end samples, T = ``cycle_s``,
h = ``servo_s``, and i_0 takes a current-sensor offset. <q> is the cubic (Hermite) mean of q
less (h/2)(q_b - q_a)/T. <dq> is the cycle's mean velocity (q_b - q_a)/T less c times its
mean acceleration (dq_b - dq_a)/T, with c how far back within its tick the drive's velocity
looks: h/2 for the instantaneous velocity at each tick's start, h for a velocity differenced
from encoder counts over the last tick (or a plant stepped by semi-implicit Euler at the
tick). The drive's manual does not say, so both are tried, like the delays below, and the
one that leaves the smaller residual is kept (one for all joints: one drive design; a free
coefficient per joint let the velocity noise through, J1's K_p off by up to 10 %). With c
taken as h/2, the virtual robot's K_p read 2-11 % high (J1 the most; K_I within 2.7 %) on
every plant seed even without noise (tests/unit/test_ident_inner_loop.py).

A velocity step makes the velocity error large for a few cycles, which separates the two
gains (:func:`control.experiments.velocity_steps`); in smooth motion the velocity error
stays near the noise and K_p is poorly determined.

A command takes effect some whole number of cycles after the measurement it answers: every
delay in ``delays`` is tried and the one with the smallest residual is kept (and reported).
The outer loop of eq. (21) wants ω = 1/(K K_p) and Υ_I = K_I/K_p, K the drive's torque
constant (joint side), which the datasheet gives.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.errors import ConfigError

#: Delays tried between a command and the cycle it is followed in [cycles].
DELAYS = (0, 1, 2, 3)
#: How far back within its tick the drive's velocity looks, tried, in servo ticks: the
#: instantaneous velocity at the tick's start (1/2), an encoder difference over the tick (1).
VELOCITY_LOOKBACKS = (0.5, 1.0)


@dataclass(frozen=True)
class InnerLoopEstimate:
    """Per joint (n,) arrays: K_p [A·s/rad], K_I [A/rad], ω [rad/s per N·m], Υ_I [1/s], the
    fit's residual RMS [A] and its share of the current's variance it leaves (1 - R²); the
    command delay found [cycles] and the rows used."""

    k_p_a_s_per_rad: np.ndarray
    k_i_a_per_rad: np.ndarray
    omega_rad_s_per_nm: np.ndarray
    upsilon_i_per_s: np.ndarray
    residual_a: np.ndarray
    unexplained: np.ndarray
    delay_cycles: int
    rows: int
    #: the velocity lookback kept, in servo ticks (:data:`VELOCITY_LOOKBACKS`)
    velocity_lookback_ticks: float = 0.5

    def to_json(self) -> dict[str, object]:
        return {
            "k_p_a_s_per_rad": self.k_p_a_s_per_rad.tolist(),
            "k_i_a_per_rad": self.k_i_a_per_rad.tolist(),
            "omega_rad_s_per_nm": self.omega_rad_s_per_nm.tolist(),
            "upsilon_i_per_s": self.upsilon_i_per_s.tolist(),
            "residual_a": self.residual_a.tolist(),
            "unexplained_variance": self.unexplained.tolist(),
            "delay_cycles": self.delay_cycles,
            "rows": self.rows,
            "velocity_lookback_ticks": self.velocity_lookback_ticks,
        }


def _errors(
    q_cmd: np.ndarray,
    dq_cmd: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    delay: int,
    cycle_s: float,
    servo_s: float,
) -> tuple[np.ndarray, np.ndarray, slice]:
    """Per cycle (T', n): the velocity error against the cycle's mean velocity, the tick-mean
    position error, and the cycle's mean acceleration (the velocity the drive samples at its
    ticks is the cycle's mean less ``c`` times it, c fitted: module docstring); and the slice
    of measurement rows that closes each of those cycles."""
    t, h = cycle_s, servo_s
    m = q.shape[0] - delay - 1
    qc, dqc = q_cmd[:m], dq_cmd[:m]
    qa, qb = q[delay : delay + m], q[delay + 1 : delay + 1 + m]
    dqa, dqb = dq[delay : delay + m], dq[delay + 1 : delay + 1 + m]
    mean_q = 0.5 * (qa + qb) - t * (dqb - dqa) / 12.0 - (h / 2.0) * (qb - qa) / t
    ev = dqc - (qb - qa) / t  # the velocity error less the tick sampling's share (docstring)
    acc = (dqb - dqa) / t
    return ev, qc + dqc * (t - h) / 2.0 - mean_q, acc, slice(delay + 1, delay + 1 + m)


@dataclass(frozen=True)
class InnerLoopRun:
    """One contiguous run of cycle-aligned arrays (T, n): row k holds the command answering
    the measurement of row k (``q``, ``dq`` at the cycle boundary, ``current_a`` the mean over
    the cycle that ended there); ``valid`` (T,) marks the commands the drive really got from
    the host's experiment (None: all)."""

    q_cmd: np.ndarray
    dq_cmd: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    current_a: np.ndarray
    valid: np.ndarray | None = None

    def checked(self) -> InnerLoopRun:
        arrays = [np.asarray(a, dtype=float) for a in
                  (self.q_cmd, self.dq_cmd, self.q, self.dq, self.current_a)]  # fmt: skip
        shape = arrays[0].shape
        if len(shape) != 2 or any(a.shape != shape for a in arrays):
            raise ValueError(f"command and measurement arrays must share one (T, n) shape: "
                             f"{[a.shape for a in arrays]}")  # fmt: skip
        if not all(np.all(np.isfinite(a)) for a in arrays):
            raise ValueError("inner-loop data hold NaN or inf")
        valid = np.ones(shape[0], bool) if self.valid is None else np.asarray(self.valid, bool)
        if valid.shape != (shape[0],):
            raise ValueError(f"valid must be ({shape[0]},), got {valid.shape}")
        return InnerLoopRun(*arrays, valid)


def fit_inner_loop(
    q_cmd: np.ndarray,
    dq_cmd: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    current_a: np.ndarray,
    gains_nm_per_a: Sequence[float],
    cycle_s: float,
    servo_s: float,
    delays: Sequence[int] = DELAYS,
) -> InnerLoopEstimate:
    """:func:`fit_inner_loop_runs` on one run (:class:`InnerLoopRun` says how rows align)."""
    run = InnerLoopRun(q_cmd, dq_cmd, q, dq, current_a)
    return fit_inner_loop_runs([run], gains_nm_per_a, cycle_s, servo_s, delays)


def fit_inner_loop_runs(
    runs: Sequence[InnerLoopRun],
    gains_nm_per_a: Sequence[float],
    cycle_s: float,
    servo_s: float,
    delays: Sequence[int] = DELAYS,
) -> InnerLoopEstimate:
    """Eq. (19) per joint from one or more runs (module docstring). Raises ValueError on
    mismatched shapes, non-finite values or a fit the data cannot support (a gain <= 0)."""
    checked = [r.checked() for r in runs]
    if not checked:
        raise ValueError("no inner-loop run to fit")
    n = checked[0].q.shape[1]
    if any(r.q.shape[1] != n for r in checked):
        raise ValueError("inner-loop runs differ in their number of joints")
    gains = np.asarray(gains_nm_per_a, dtype=float)
    if gains.shape != (n,) or np.any(gains <= 0):
        raise ValueError(f"need {n} drive gains > 0, got {gains_nm_per_a}")
    if not 0 < servo_s <= cycle_s:
        raise ValueError(f"servo period {servo_s} s must be in (0, cycle {cycle_s} s]")
    best: tuple[float, int, np.ndarray, np.ndarray, np.ndarray, int, float] | None = None
    for delay in delays:
        parts = []
        for r in checked:
            if r.q.shape[0] - delay - 1 < 1:
                continue
            ev, eq, acc, rows = _errors(r.q_cmd, r.dq_cmd, r.q, r.dq, delay, cycle_s, servo_s)
            keep = r.valid[: ev.shape[0]]
            parts.append((ev[keep], eq[keep], acc[keep], r.current_a[rows][keep]))
        if sum(len(p[3]) for p in parts) < 10:
            continue
        ev, eq, acc, i = (np.concatenate([p[k] for p in parts]) for k in range(4))
        for lookback in VELOCITY_LOOKBACKS:
            ev_c = ev + lookback * servo_s * acc
            coef, resid = np.zeros((n, 3)), np.zeros(n)
            for j in range(n):
                a = np.column_stack([ev_c[:, j], eq[:, j], np.ones(len(i))])
                coef[j], *_ = np.linalg.lstsq(a, i[:, j], rcond=None)
                resid[j] = np.sqrt(np.mean((i[:, j] - a @ coef[j]) ** 2))
            unexplained = resid**2 / np.maximum(np.var(i, axis=0), 1e-300)
            score = float(np.sum(unexplained))
            if best is None or score < best[0]:
                best = (score, delay, coef, resid, unexplained, len(i), lookback)
    if best is None:
        raise ValueError("too few cycles to fit the inner loop")
    _, delay, coef, resid, unexplained, rows_used, lookback = best
    kp, ki = coef[:, 0], coef[:, 1]
    bad = np.flatnonzero((kp <= 0) | (ki <= 0))
    if bad.size:
        raise ValueError(
            f"joint {int(bad[0]) + 1}: the fit gives K_p {kp[bad[0]]:.4g}, K_I {ki[bad[0]]:.4g} "
            "(need > 0): the data do not excite the inner loop (run the velocity steps)"
        )
    return InnerLoopEstimate(kp, ki, 1.0 / (gains * kp), ki / kp, resid, unexplained,
                             delay, rows_used, lookback)  # fmt: skip


def read_outer_loop_gains(path: str | Path, n_joints: int) -> tuple[list[float], list[float], int]:
    """ω [rad/s per N·m] and Υ_I [1/s] per joint, and the command delay [cycles] (0 when not
    given) from an ``inner_loop.json`` that ``leadthrough identify`` wrote. Raises
    ConfigError naming the file and what is wrong."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except FileNotFoundError:
        raise ConfigError(
            f"{p}: inner-loop estimate not found (run `leadthrough identify`)"
        ) from None
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{p}: not a readable inner-loop estimate: {exc}") from None
    out = []
    for key in ("omega_rad_s_per_nm", "upsilon_i_per_s"):
        values = doc.get(key) if isinstance(doc, dict) else None
        if not isinstance(values, list) or len(values) != n_joints:
            raise ConfigError(f"{p}: {key} must list {n_joints} values, got {values!r}")
        try:
            floats = [float(v) for v in values]
        except (TypeError, ValueError):
            raise ConfigError(f"{p}: {key} holds a value that is not a number: {values}") from None
        if not all(np.isfinite(v) and v > 0 for v in floats):
            raise ConfigError(f"{p}: {key} values must be finite and > 0, got {floats}")
        out.append(floats)
    delay = doc.get("delay_cycles", 0)
    if not isinstance(delay, int) or isinstance(delay, bool) or not 0 <= delay <= 10:
        raise ConfigError(f"{p}: delay_cycles must be a whole number of cycles 0..10, "
                          f"got {delay!r}")  # fmt: skip
    return out[0], out[1], delay
