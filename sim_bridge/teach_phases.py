"""The phases of a teaching run, and the painter's force in each (`leadthrough teach-bench`).

Where the force goes tells which part of a law is missing: stiction shows when a joint starts
from rest or reverses, inertia and viscous friction while the tool cruises, the law's hold (or
its creep) while the painter's target stands. Each row of a run is one of

- ``dwell``: the painter's target stands still (a corner of the raster, the start);
- ``startup``: the first :data:`STARTUP_S` of each leg, the target moving after a stand: the
  arm breaks away from rest;
- ``reversal``: within :data:`REVERSAL_S` of a joint's velocity changing sign while the target
  moves (a straight line on the panel reverses joints mid-leg), outside a start-up;
- ``cruise``: the rest of the moving rows.

The phases come from the target's timeline (the same rows for every strategy of a seed) and the
arm's measured joint positions (where its joints reverse): a scorer's reading of the plant's
log, never the product's.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

PHASES = ("startup", "cruise", "reversal", "dwell")
#: the target moves when it moves faster than this [m/s]
MOVING_M_S = 1e-3
#: a leg's start-up [s]: at the raster's 0.1 m/s the target leads a tool held by stiction by
#: 50 mm after 0.5 s, 75 N of the bench's 1500 N/m hand: by then the arm has broken away or
#: the hand is at its 80 N limit
STARTUP_S = 0.5
#: the joint velocity that finds reversals is averaged over this [s]: longer than one period of
#: the hand's 9 Hz tremor (0.11 s), whose 0.5 mm wobble alone reverses a joint that barely moves
VELOCITY_WINDOW_S = 0.2
#: rows either side of a reversal that belong to it [s]: the joint's speed then is below
#: 0.25 s x its deceleration, the stiction band a law must carry the arm through
REVERSAL_S = 0.25
#: a joint reverses when it moved at least this fast [rad/s] within REVERSAL_S before the sign
#: change and within REVERSAL_S after it (slower: a joint at rest, not reversing); 0.02 rad/s
#: is 20 mm/s at a metre, a fifth of the painter's speed
REVERSAL_MIN_RAD_S = 0.02


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average of ``x`` (T, k) over ``n`` rows (shorter at the ends)."""
    if n <= 1:
        return x
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    half = n // 2
    idx = np.arange(x.shape[0])
    lo, hi = np.maximum(idx - half, 0), np.minimum(idx + half + 1, x.shape[0])
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def reversal_rows(t_s: np.ndarray, q_rad: np.ndarray) -> np.ndarray:
    """(T,) true within :data:`REVERSAL_S` of a reversal of any joint of ``q_rad`` (T, n) at
    times ``t_s`` (T,) [s]."""
    out = np.zeros(t_s.size, dtype=bool)
    if t_s.size < 3:
        return out
    step = float(np.median(np.diff(t_s)))
    dq = np.gradient(q_rad, t_s, axis=0)
    dq = _moving_average(dq, max(1, round(VELOCITY_WINDOW_S / step)))
    span = max(1, round(REVERSAL_S / step))
    for j in range(dq.shape[1]):
        v = dq[:, j]
        sign = np.sign(v)
        nonzero = np.flatnonzero(sign)
        if not nonzero.size:
            continue
        # a speed of exactly zero keeps the sign before it: one reversal, not two or none
        last = np.maximum.accumulate(np.where(sign != 0, np.arange(sign.size), nonzero[0]))
        sign = sign[last]
        for k in np.flatnonzero(sign[:-1] * sign[1:] < 0):
            before = np.abs(v[max(k - span, 0) : k + 1]).max()
            after = np.abs(v[k + 1 : k + 1 + span]).max()
            if min(before, after) >= REVERSAL_MIN_RAD_S:
                out[max(k - span, 0) : k + 1 + span] = True
    return out


def classify(
    tau_s: np.ndarray, target_speed_m_s: np.ndarray, end_s: float, q_rad: np.ndarray | None
) -> np.ndarray:
    """The phase of each row (T,) as an index into :data:`PHASES`, -1 after the path's end
    ``end_s``: rows at times ``tau_s`` (T,) since the hand took the tool [s], the target's speed
    ``target_speed_m_s`` (T,), the arm's joint positions ``q_rad`` (T, n) (None: no reversal
    rows, they count as cruise)."""
    during = tau_s <= end_s
    moving = (target_speed_m_s > MOVING_M_S) & during
    leg_start = np.full(tau_s.size, -math.inf)
    starts = np.flatnonzero(moving & ~np.r_[False, moving[:-1]])
    # (a run the product stopped before the target moved has no leg: its rows are dwell)
    for k, stop in zip(starts, np.r_[starts[1:], tau_s.size][: starts.size], strict=True):
        leg_start[k:stop] = tau_s[k]
    startup = moving & (tau_s - leg_start < STARTUP_S)
    reversal = moving & ~startup
    if q_rad is not None:
        reversal &= reversal_rows(tau_s, q_rad)
    else:
        reversal[:] = False
    phase = np.full(tau_s.size, -1)
    phase[moving] = PHASES.index("cruise")
    phase[startup] = PHASES.index("startup")
    phase[reversal] = PHASES.index("reversal")
    phase[during & ~moving] = PHASES.index("dwell")
    return phase


def phase_forces(tau_s: np.ndarray, force_n: np.ndarray, phase: np.ndarray) -> dict[str, Any]:
    """Per phase: the hand's force magnitude ``force_n`` (T,) [N] in it (mean, p95, peak) and
    its duration [s] (the rows' share of the run's time), NaN figures for a phase with no
    rows."""
    dt = np.gradient(tau_s) if tau_s.size > 1 else np.zeros(tau_s.size)
    out = {}
    for i, name in enumerate(PHASES):
        rows = phase == i
        f = force_n[rows]
        out[name] = {
            "mean_force_n": float(f.mean()) if f.size else math.nan,
            "p95_force_n": float(np.percentile(f, 95)) if f.size else math.nan,
            "peak_force_n": float(f.max()) if f.size else math.nan,
            "seconds": float(dt[rows].sum()),
        }
    return out
