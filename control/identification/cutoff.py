"""The position/velocity low-pass of an analysis, chosen from the data by held-out validation.

Acceleration is the derivative of a measured, noisy velocity (or the second derivative of a
quantised position). The low-pass that the analysis applies to positions and velocities
before differentiating (:mod:`.preprocess`) trades two errors:

- too high a cutoff lets velocity noise through, which differentiation amplifies (∝ f³ in
  power) into the acceleration; on a heavy arm that turns into N·m of torque "noise" in the
  inertia columns, and noisy columns also bias the fit (errors in variables);
- too low a cutoff smooths away torque the model could have explained (fast motion, the
  sharp friction reversal as seen through the velocity).

No fixed value suits every measurement chain, so each candidate of :data:`CANDIDATES_HZ`
(up to :data:`NYQUIST_SHARE` of the analysis rate) is tried: the files are prepared at that
cutoff, rigid body + Coulomb/viscous friction are fitted on contiguous K-fold training blocks
and each held-out block is predicted. All candidates are scored on **one reference target**,
the torque low-passed at the highest candidate, on the same rows (the same edges are trimmed
for all): the reference's own noise is common to every candidate, so the comparison sees only
what each candidate's model gets right. Joints are weighed as in
:func:`.families.choose_family` (each joint's held-out MSE relative to its best candidate).
Candidates within :data:`TIE_TOLERANCE` of the best are a tie, won by the highest cutoff
among them: it keeps the most of the measured signal for the effect search.

The torque, the pressures and every regressor column keep the reference low-pass (the
highest candidate): it is the anti-alias filter of the decimation. A lower one would take
noise out of the target, and with it the margin by which the effect search's relative
criterion tells an effect from the model's own mismatch outside its training envelope (on
the synthetic GR630ST of :mod:`.bench` a 16 Hz target let four false effects through).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from control.identification.fit import make_context
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.parallel import map_forked
from control.identification.preprocess import Prepared, sliding_mask
from control.identification.rigid import RobotRegressor
from control.identification.terms import FrictionTerm, RigidTerm

#: Cutoffs tried [Hz], a roughly geometric grid (√2 steps) from slow to fast motion.
CANDIDATES_HZ = (2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 40.0)
#: Highest cutoff tried, as a share of the analysis (and sample) rate.
NYQUIST_SHARE = 0.4
#: Relative total held-out error within which candidates tie.
TIE_TOLERANCE = 0.01
#: q_e of the Coulomb column of the selection model [rad/s] (a sharp sign).
_Q_E_RAD_S = 0.005

#: ``prepare(cutoff_hz, edge_cutoff_hz, torque_cutoff_hz)`` → the training files as one
#: :class:`.preprocess.Prepared` (cylinder torque already taken out).
Preparer = Callable[[float, float, float], Prepared]


@dataclass(frozen=True)
class CutoffChoice:
    """The chosen cutoff [Hz] and every candidate's relative held-out error per joint."""

    cutoff_hz: float
    candidates_hz: tuple[float, ...]
    relative_mse: np.ndarray  #: (C, n) held-out MSE / the joint's best
    reference_hz: float

    def to_json(self) -> dict[str, Any]:
        return {
            "cutoff_hz": self.cutoff_hz,
            "chosen_by": "held-out (contiguous K-fold) error of rigid body + Coulomb/viscous "
            "friction on the training files, every candidate scored on the torque low-passed "
            f"at {self.reference_hz:g} Hz over the same rows",
            "candidates_hz": list(self.candidates_hz),
            "relative_heldout_mse": self.relative_mse.round(4).tolist(),
            "score": self.relative_mse.sum(axis=1).round(4).tolist(),
        }


def candidates(rate_hz: float, sample_hz: float) -> tuple[float, ...]:
    """The cutoffs of :data:`CANDIDATES_HZ` that the rates allow (at least the lowest)."""
    top = NYQUIST_SHARE * min(rate_hz, sample_hz)
    out = tuple(c for c in CANDIDATES_HZ if c <= top + 1e-9)
    return out or (min(CANDIDATES_HZ[0], top),)


def _heldout(reg: RobotRegressor, data: Prepared, mask: np.ndarray, folds: int) -> np.ndarray:
    """Held-out MSE per joint of rigid + Coulomb/viscous on ``data``."""
    ctx = make_context(reg, data, payload=False)
    ls = BlockLS(data.tau, contiguous_folds(data.n_samples, folds), mask)
    ls.add("rigid", RigidTerm().columns(ctx))
    names = ["rigid"]
    for j in range(data.n_joints):
        term = FrictionTerm(j, "simple", _Q_E_RAD_S, 1.0)
        ls.add(term.key, term.columns(ctx))
        names.append(term.key)
    scale = np.sqrt(np.mean(data.tau**2, axis=0))
    weights = 1.0 / np.maximum(scale, 1e-9)
    predicted = ls.cv_predict(names, weights)
    err = (data.tau - predicted) ** 2 * mask
    return err.sum(axis=0) / np.maximum(mask.sum(axis=0), 1.0)


def choose_cutoff(
    reg: RobotRegressor,
    prepare: Preparer,
    rate_hz: float,
    sample_hz: float,
    stick_velocity_rad_s: float,
    folds: int,
    progress: Callable[[str], None],
    grid: Sequence[float] | None = None,
) -> CutoffChoice:
    """Choose the analysis cutoff (module docstring) for training files at ``sample_hz``."""
    cands = tuple(sorted(grid)) if grid is not None else candidates(rate_hz, sample_hz)
    low, high = cands[0], cands[-1]
    # stuck rows from the smoothest velocity, one mask for every candidate
    mask = sliding_mask(prepare(low, low, high), stick_velocity_rad_s, 1.0 / low)

    def heldout(cutoff_hz: float) -> np.ndarray:
        return _heldout(reg, prepare(cutoff_hz, low, high), mask, folds)

    # independent candidates, side by side in worker processes (:mod:`.parallel`)
    table = np.array(map_forked(heldout, cands))
    best = np.min(table, axis=0)
    rel = table / np.where(best > 0, best, 1.0)
    score = rel.sum(axis=1)
    top = float(np.min(score))
    chosen = max(c for c, s in zip(cands, score, strict=True) if s <= top * (1 + TIE_TOLERANCE))
    n = rel.shape[1]
    scores = ", ".join(f"{c:g} Hz {s / n:.3f}" for c, s in zip(cands, score, strict=True))
    progress(f"cutoff {chosen:g} Hz: lowest held-out error on the training files ({scores})")
    return CutoffChoice(chosen, cands, rel, high)
