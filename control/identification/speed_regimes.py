"""Where in speed a model was measured and how it does at the speeds a painter teaches.

A model's friction is known only over the speeds its training files slid at; the operator
drags the arm at 0.5-2 °/s, reverses and rests. Two figures say how far the model can be
trusted there (``summary.json``, ``report.md``):

- :func:`friction_coverage`, per joint, over the training rows the friction was fitted on (the
  sliding ones, :func:`.preprocess.sliding_mask`): the speeds slid at (1st and 99th
  percentile), the share of them at teaching speeds (below :data:`TEACHING_RAD_S`), the
  reversals and the share of rows at rest;
- :func:`raw_by_speed`, per joint, the raw held-out error (measured minus predicted torque,
  unfiltered: :mod:`.heldout`) split by the measured speed of each row: at rest (below the
  stick velocity), at teaching speeds, and faster. The speed only sorts the rows; the torque
  scored is the raw one.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: teaching speeds: a painter drags the gun at 0.5-2 °/s on the joints [rad/s]
TEACHING_RAD_S = math.radians(2.0)
#: percentiles of the sliding speeds reported as the range the friction was measured over
RANGE_PERCENTILES = (1.0, 99.0)
#: the regimes of :func:`raw_by_speed`, in order
REGIMES = ("rest", "teaching", "faster")


def _reversals(dq: np.ndarray, stick_rad_s: float) -> int:
    """Sign changes of ``dq`` (T,) among the rows faster than ``stick_rad_s``."""
    moving = dq[np.abs(dq) >= stick_rad_s] if stick_rad_s > 0 else dq[dq != 0]
    return int(np.count_nonzero(np.diff(np.sign(moving)) != 0))


def friction_coverage(
    dq: np.ndarray, sliding: np.ndarray, stick_rad_s: float
) -> list[dict[str, Any]]:
    """Per joint the speeds its friction was measured over, from the training rows' velocity
    ``dq`` (T, n) [rad/s] and the rows fitted (``sliding`` (T, n), nonzero where the joint
    slides); None figures where it never slid."""
    out = []
    for j in range(dq.shape[1]):
        speed = np.abs(dq[:, j])
        slid = speed[sliding[:, j] > 0]
        entry: dict[str, Any] = {
            "sliding_rows": int(slid.size),
            "rest_share": float(np.mean(speed < stick_rad_s)) if speed.size else None,
            "reversals": _reversals(dq[:, j], stick_rad_s),
        }
        if slid.size:
            lo, hi = np.percentile(slid, RANGE_PERCENTILES)
            entry.update(
                speed_range_rad_s=[float(lo), float(hi)],
                teaching_share=float(np.mean(slid < TEACHING_RAD_S)),
            )
        else:
            entry.update(speed_range_rad_s=None, teaching_share=None)
        out.append(entry)
    return out


def regime_masks(dq: np.ndarray, stick_rad_s: float) -> dict[str, np.ndarray]:
    """(R, n) bool per regime of :data:`REGIMES` from the rows' measured velocity [rad/s]."""
    speed = np.abs(dq)
    rest = speed < stick_rad_s
    teaching = ~rest & (speed < TEACHING_RAD_S)
    return {"rest": rest, "teaching": teaching, "faster": ~rest & ~teaching}


def raw_by_speed(
    errors: dict[str, np.ndarray], dq: np.ndarray, answered: np.ndarray, stick_rad_s: float
) -> dict[str, Any]:
    """Per regime the share of the scored rows and each model's per-joint RMS of its raw
    residual (``errors``: name → (R, n) measured minus predicted [N·m]) over the rows
    ``answered`` (R,) whose measured speed ``dq`` (R, n) falls in it; None where a joint has
    no row in a regime."""
    masks = regime_masks(dq, stick_rad_s)
    out: dict[str, Any] = {
        "teaching_below_rad_s": TEACHING_RAD_S,
        "rest_below_rad_s": stick_rad_s,
    }
    for name in REGIMES:
        m = masks[name] & answered[:, None]
        counts = m.sum(axis=0)
        entry: dict[str, Any] = {"share": (counts / max(int(answered.sum()), 1)).tolist()}
        for model, e in errors.items():
            sq = np.where(m, np.nan_to_num(e) ** 2, 0.0).sum(axis=0)
            entry[model] = [
                float(math.sqrt(s / c)) if c else None for s, c in zip(sq, counts, strict=True)
            ]
        out[name] = entry
    return out


def measured_velocity(m: Any) -> np.ndarray:
    """A measurement file's velocity (T, n) [rad/s]: its own columns, or its positions'
    finite-difference derivative where it has none (a state, never the scored torque)."""
    return m.dq if m.dq is not None else np.gradient(m.q, m.t, axis=0)


def scored_velocity(measurements: list[Any], rows: list[np.ndarray]) -> np.ndarray:
    """The measured velocity (R, n) [rad/s] of the scored rows of each file (``rows``: bool
    per file), stacked as :func:`.heldout.residuals` stacks them (:func:`measured_velocity`)."""
    return np.concatenate(
        [measured_velocity(m)[keep] for m, keep in zip(measurements, rows, strict=True)]
    )
