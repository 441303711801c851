"""Held-out folds of the training rows that stand as far from their fit as the test does.

The guard (:func:`.guard.guard_joints`) asks, per joint, which predictor does best on data
its fit did not see: the model, plain least squares, the URDF's nominal rigid body, or zero.
The answer depends on *where* the unseen data lie. Contiguous folds of one run hold out whole
stretches of the trajectory: the fit must extrapolate into them, and a predictor without
shared physics (plain least squares, each joint's regressor row with coefficients of its own)
does badly there. A test run that retraces the training trajectory (the Panda excitation run:
its 13.3 s period fits in the 14.6 s of training) asks the opposite question, interpolation,
where plain least squares' freedom wins.

So the guard's held-out error is measured where the test run's inputs lie (positions and
velocities, never its torques). For each test row, the distance to the nearest training row in
(q, dq) standardised by the training spread; for each fold scheme, the median distance of its
held-out rows to the nearest row their fit sees. The schemes are the contiguous K folds,
interleaved blocks (block b goes to fold b mod K) of halving length down to
:data:`MIN_BLOCK_S` (a block shorter than a few periods of the torque filter would leak its
neighbours' samples through the filter), and the in-sample fit, whose distance is each training
row's to its nearest other row: a test that retraces the training trajectory is that close, and
there the guard compares in-sample errors corrected for the parameters each predictor spends
(generalised cross-validation: SSE / (1 - p/N)², :func:`gcv_factor`).

Each test row counts for the scheme whose median distance is nearest its own on a log scale
(rows farther than every scheme count for the farthest); the guard's error is the mix of the
schemes' held-out errors in those shares (:attr:`FoldPlan.schemes`, shares below
:data:`MIN_SHARE` folded into the nearest kept scheme). This is importance-weighted
cross-validation's idea (Sugiyama et al., JMLR 2007: validate under the test's covariate shift)
in a coarse, stratified form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from control.identification.lsq import contiguous_folds

#: shortest interleaved block [s]: at least a few periods of any torque filter we choose
MIN_BLOCK_S = 0.5
#: a scheme fewer test rows than this share count for is not evaluated (its rows go to the
#: kept scheme nearest them)
MIN_SHARE = 0.1
#: query rows of a median distance, at most (thinned evenly); the rows searched are all kept
MAX_QUERY_ROWS = 2000
#: a spread below this is a joint that did not move: its coordinate is left out [rad, rad/s]
_MIN_SPREAD = 1e-9
#: distances below this are the same point [standardised units]
_TINY = 1e-12

CONTIGUOUS, INTERLEAVED, IN_SAMPLE = "contiguous", "interleaved blocks", "in-sample (GCV)"

Fold = np.ndarray | slice


@dataclass(frozen=True)
class Scheme:
    """One way of holding out training rows, and the share of test rows it stands for."""

    name: str
    folds: list[Fold]
    block_s: float | None
    median_distance: float
    share: float = 0.0

    @property
    def in_sample(self) -> bool:
        return self.name == IN_SAMPLE

    def label(self) -> str:
        return self.name + (f" of {self.block_s:.2f} s" if self.block_s is not None else "")

    def to_json(self) -> dict[str, Any]:
        return {
            "scheme": self.name,
            "block_s": self.block_s,
            "folds": len(self.folds),
            "median_distance": self.median_distance,
            "share": self.share,
        }


@dataclass(frozen=True)
class FoldPlan:
    """The schemes the guard mixes (share > 0), all candidates, and the test's distances."""

    schemes: list[Scheme]
    candidates: list[Scheme]
    test_median: float
    beyond_share: float  #: test rows farther from the training rows than every scheme's median

    @property
    def extrapolates(self) -> bool:
        """Most test rows lie farther from the training rows than any fold from its fit."""
        return self.beyond_share > 0.5

    def describe(self) -> str:
        mix = ", ".join(f"{s.share:.0%} {s.label()}" for s in self.schemes)
        return (
            f"{mix} (test rows' median distance to the nearest training row "
            f"{self.test_median:.3g}; {self.beyond_share:.0%} of them farther than any fold "
            "from its fit)"
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "schemes": [s.to_json() for s in self.schemes],
            "candidates": [s.to_json() for s in self.candidates],
            "median_distance_test": self.test_median,
            "beyond_share": self.beyond_share,
            "rule": "each test row counts for the fold scheme whose held-out rows' median "
            "distance to the nearest row their fit sees is nearest (log scale) its own distance "
            "to the nearest training row, in (q, dq) standardised by the training spread; the "
            "guard mixes the schemes' held-out errors in those shares; in-sample errors are "
            "multiplied by 1 / (1 - p/N)^2 (generalised cross-validation)",
        }


def gcv_factor(params: float, rows: np.ndarray) -> np.ndarray:
    """1 / (1 - p/N)² per joint: an in-sample SSE spending ``params`` on ``rows`` (n,) rows
    made an estimate of the error on new noise along the same inputs (infinite when p ≥ N)."""
    n_rows = np.maximum(np.asarray(rows, dtype=float), 1.0)
    share = params / n_rows
    with np.errstate(divide="ignore"):
        return np.where(share < 1.0, 1.0 / np.maximum(1.0 - share, 0.0) ** 2, np.inf)


def interleaved_folds(n_rows: int, k: int, block_rows: int) -> list[np.ndarray]:
    """``k`` folds of row indices: blocks of ``block_rows`` rows, block b in fold b mod k."""
    block = np.arange(n_rows) // max(1, block_rows)
    return [np.flatnonzero(block % k == f) for f in range(k)]


def _features(x: np.ndarray, centre: np.ndarray, spread: np.ndarray) -> np.ndarray:
    keep = spread > _MIN_SPREAD
    return (x[:, keep] - centre[keep]) / spread[keep]


def _query(rows: np.ndarray) -> np.ndarray:
    step = max(1, math.ceil(rows.size / MAX_QUERY_ROWS))
    return rows[::step]


def _distances(points: np.ndarray, seen: np.ndarray, unseen: np.ndarray, k: int = 1) -> np.ndarray:
    """Distance of each (thinned) ``unseen`` row to its k-th nearest ``seen`` row."""
    if not seen.size or not unseen.size:
        return np.full(max(1, unseen.size), math.inf)
    d, _ = cKDTree(points[seen]).query(points[_query(unseen)], k=k, workers=-1)
    return np.maximum(d if k == 1 else d[:, -1], _TINY)


def plan_folds(
    q_train: np.ndarray,
    dq_train: np.ndarray,
    rate_hz: float,
    q_test: np.ndarray,
    dq_test: np.ndarray,
    k: int,
) -> FoldPlan:
    """The guard's fold schemes for training rows ``q_train``, ``dq_train`` (T, n) sampled at
    ``rate_hz``, against the test rows (module docstring)."""
    n_rows = q_train.shape[0]
    x = np.column_stack([q_train, dq_train])
    centre, spread = x.mean(axis=0), x.std(axis=0)
    points = np.vstack(
        [
            _features(x, centre, spread),
            _features(np.column_stack([q_test, dq_test]), centre, spread),
        ]
    )
    train = np.arange(n_rows)
    d_test = _distances(points, train, np.arange(n_rows, points.shape[0]))

    raw: list[tuple[str, float | None, list[Fold]]] = [
        (CONTIGUOUS, None, contiguous_folds(n_rows, k))
    ]
    block = n_rows // (2 * k)
    min_rows = max(1, math.ceil(MIN_BLOCK_S * rate_hz))
    while block >= min_rows:
        raw.append((INTERLEAVED, block / rate_hz, interleaved_folds(n_rows, k, block)))
        block //= 2
    raw.append((IN_SAMPLE, None, [slice(0, n_rows)]))
    fold_of = np.empty(n_rows, dtype=int)
    medians = []
    for name, _, folds in raw:
        if name == IN_SAMPLE:  # the nearest other row: the second nearest, itself first
            medians.append(float(np.median(_distances(points, train, train, k=2))))
            continue
        for f, idx in enumerate(folds):
            fold_of[idx] = f
        held = [
            np.median(_distances(points, train[fold_of != f], train[fold_of == f]))
            for f in range(len(folds))
        ]
        medians.append(float(np.median(held)))
    log_m = np.log(np.maximum(medians, _TINY))
    nearest = np.argmin(np.abs(np.log(d_test)[:, None] - log_m[None, :]), axis=1)
    counts = np.bincount(nearest, minlength=len(raw)).astype(float)
    kept = counts / counts.sum() >= MIN_SHARE
    if not kept.any():
        kept[int(np.argmax(counts))] = True
    # rows of a dropped scheme go to the kept scheme nearest them
    nearest = np.flatnonzero(kept)[
        np.argmin(np.abs(np.log(d_test)[:, None] - log_m[None, kept]), axis=1)
    ]
    shares = np.bincount(nearest, minlength=len(raw)) / nearest.size
    candidates = [
        Scheme(name, folds, block_s, m, float(sh))
        for (name, block_s, folds), m, sh in zip(raw, medians, shares, strict=True)
    ]
    return FoldPlan(
        [c for c in candidates if c.share > 0],
        candidates,
        float(np.median(d_test)),
        float(np.mean(d_test > max(medians))),
    )
