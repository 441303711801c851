"""The hard world's recording faults (:mod:`.world`): irregular time stamps, missing stretches
and torque outliers.

Stamps: sample k is taken at t_k = (k + e_k) / rate, e_k = U(-J, J), J drawn per draw in
5-20 % of the period; the true motion is evaluated at t_k (the samples are taken at the
stamped times), so stamps are irregular but strictly increasing (J < 1/2). The first stamp is
J / rate ahead of zero, never negative.

Gaps: per file 2-4 stretches of 2-50 consecutive samples are missing (dropped rows, never the
first or last 5 % of the file), apart from each other.

Outliers: per file U(0.02 %, 0.1 %) of its torque samples (rows × joints, at least one), each a
single sample of one joint, ± U(10, 50) × that joint's torque noise std added to the reading.
"""

from __future__ import annotations

import numpy as np

JITTER_FRACTION = (0.05, 0.20)
GAPS_PER_FILE = (2, 4)
GAP_SAMPLES = (2, 50)
OUTLIER_SHARE = (0.0002, 0.001)
OUTLIER_NOISE_MULTIPLE = (10.0, 50.0)


def jittered_times(n: int, rate_hz: float, jitter: float, rng) -> np.ndarray:
    """n stamps [s] at ``rate_hz`` each moved by U(-jitter, jitter) periods."""
    e = rng.uniform(-jitter, jitter, n)
    return (np.arange(n) + jitter + e) / rate_hz


def gap_mask(n: int, rng) -> np.ndarray:
    """(n,) True for the rows kept: a few missing stretches (module docstring)."""
    keep = np.ones(n, dtype=bool)
    lo, hi = int(0.05 * n), int(0.95 * n)
    count = int(rng.integers(GAPS_PER_FILE[0], GAPS_PER_FILE[1] + 1))
    longest = max(GAP_SAMPLES[0], min(GAP_SAMPLES[1], (hi - lo) // (4 * count)))
    for _ in range(100 * count):
        length = int(rng.integers(GAP_SAMPLES[0], longest + 1))
        start = int(rng.integers(lo, max(hi - length, lo + 1)))
        if not keep[max(start - 2, 0) : start + length + 2].all():
            continue
        keep[start : start + length] = False
        count -= 1
        if count == 0:
            break
    return keep


def outliers(shape: tuple[int, int], sigma: np.ndarray, rng) -> tuple[np.ndarray, int]:
    """(T, n) spikes [N·m] to add to a file's torque and their count (module docstring)."""
    rows, n = shape
    count = max(1, round(rng.uniform(*OUTLIER_SHARE) * rows * n))
    flat = rng.choice(rows * n, size=min(count, rows * n), replace=False)
    out = np.zeros(rows * n)
    size = rng.uniform(*OUTLIER_NOISE_MULTIPLE, flat.size) * rng.choice([-1.0, 1.0], flat.size)
    out[flat] = size * np.asarray(sigma)[flat % n]
    return out.reshape(rows, n), int(flat.size)
