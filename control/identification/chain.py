"""The torque channel's measurement chain: per-joint gain and offset, estimated with the arm.

A drive reports its torque from the motor current through a datasheet torque constant and a
current sensor, so what the file holds is, per joint j::

    τ_meas,j = k_j τ_j + b_j,       τ_j = Y_b,j β + F_j φ_j

with a gain k_j a few % off (the torque constant) and an offset b_j (the sensor's zero). The
rigid-body parameters β are shared by all joints: with a per-joint gain no single β fits every
joint, and what is left over looks like effects that are not there. An offset is not in the
eq. (14)/(15) families at all.

Estimation (:func:`estimate`), inside the fit, before the effect search and the guard:

- *offset*: every friction family carries a constant column per joint while the chain is
  estimated (:attr:`.terms.FrictionTerm.offset`; ``simple`` has its own and gets no second);
  its coefficient is c_j = b_j / k_j. The asymmetric part of Coulomb friction shows the same
  way: the data cannot tell the two apart, and the model keeps the sum as the offset.
- *gain*: with g_j = 1/k_j the model is linear in the scaled target,
  ``g_j τ_meas,j = Y_b,j β + F_j φ_j + c_j``. Alternating least squares: the joint linear fit
  at fixed g (:class:`.lsq.BlockLS` on the scaled targets), then per joint
  k_j = <τ_meas,j, p_j> / <p_j, p_j> (p_j the fit's prediction, rows where the joint slides),
  until g moves less than :data:`TOLERANCE` (at most :data:`MAX_ITERATIONS`).
- *gauge*: scaling every k by s and β, φ, c by 1/s fits the data exactly as well (only the
  URDF prior on β notices), so while every joint's gain is free their geometric mean is held
  at 1; a joint held at k = 1 fixes the scale instead.
- *which joints*: k_j is determined only through the part of the joint's rigid-body row that
  other joints share; where that is small it is not determined and must stay 1. Per joint, the
  gain is kept only if the blocked K-fold held-out sum of squares of the joint (measured
  units, the pipeline's cross-validation :meth:`.lsq.BlockLS.cv_sse`) with its gain free is
  lower than with k_j = 1 by more than one column fitted to noise could give: the test (ii)
  of :mod:`.effects`, ``drop / noise_dof ≥ χ²_1`` quantile at level ``alpha / n`` (Bonferroni
  over the joints). The joints refused are held at 1 and the rest estimated again.

Afterwards the analysis works on the physical torque ``(τ_meas - b) / k`` (:meth:`Chain.
to_physical`) and every model it builds carries the chain (:class:`.fit.IdentifiedModel`'s
``torque_gain`` and ``torque_offset_nm``), so what it predicts for a torque channel is again
``k τ + b``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from control.identification.effects import NoiseFloor, chi2_threshold
from control.identification.lsq import BlockLS, Solution

#: Largest change of any 1/k_j between two iterations at which the alternation stops.
TOLERANCE = 1e-6
MAX_ITERATIONS = 30


@dataclass(frozen=True)
class Chain:
    """Per joint ``gain`` k (n,) and ``offset_nm`` b (n,) [N·m] of ``τ_meas = k τ + b``;
    ``free`` (n,) whether the joint's gain was estimated (else held at 1), ``cv_rms_fixed`` /
    ``cv_rms_free`` (n,) the joint's held-out RMS [N·m] with its gain held at 1 / free,
    ``iterations`` of the last alternation."""

    gain: np.ndarray
    offset_nm: np.ndarray
    free: np.ndarray
    cv_rms_fixed: np.ndarray
    cv_rms_free: np.ndarray
    iterations: int

    @classmethod
    def identity(cls, n: int) -> Chain:
        one, zero = np.ones(n), np.zeros(n)
        return cls(one, zero, np.zeros(n, dtype=bool), zero, zero, 0)

    def to_physical(self, tau_nm: np.ndarray) -> np.ndarray:
        """The torque behind readings ``tau_nm`` (T, n): ``(τ_meas - b) / k``."""
        return (np.asarray(tau_nm, dtype=float) - self.offset_nm) / self.gain

    def to_json(self) -> dict[str, Any]:
        return {
            "model": "tau_measured = gain * tau + offset_nm, per joint",
            "gain": [float(v) for v in self.gain],
            "offset_nm": [float(v) for v in self.offset_nm],
            "gain_estimated": [bool(v) for v in self.free],
            "heldout_rms_train_gain_1": [float(v) for v in self.cv_rms_fixed],
            "heldout_rms_train_gain_free": [float(v) for v in self.cv_rms_free],
            "iterations": self.iterations,
        }


def _masked_dot(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    return np.einsum("tj,tj->j", a if mask is None else a * mask, b)


def _alternate(
    ls: BlockLS,
    y_meas: np.ndarray,
    names: Sequence[str],
    weights: np.ndarray,
    free: np.ndarray,
) -> tuple[np.ndarray, Solution, int]:
    """Alternating LS for 1/k (module docstring): (g (n,), the fit at g, iterations). ``ls``
    is left with the targets ``g τ_meas``."""
    g = np.ones(y_meas.shape[1])
    it = 0
    while True:
        it += 1
        ls.set_y(y_meas * g)
        # the weights are per measured N·m: a scaled row's residual is g times the measured one
        sol = ls.solve(names, weights / g)
        if not free.any() or it > MAX_ITERATIONS:
            return g, sol, it
        pred = ls.predict(sol)
        pp = _masked_dot(pred, pred, ls.mask)
        k = np.where(
            free & (pp > 0), _masked_dot(y_meas, pred, ls.mask) / np.maximum(pp, 1e-300), 1.0
        )
        k = np.where(np.isfinite(k) & (k > 0), k, 1.0)
        if free.all():
            k = k / np.exp(np.mean(np.log(k)))
        g_new = 1.0 / k
        if np.max(np.abs(g_new - g)) < TOLERANCE:
            ls.set_y(y_meas * g_new)
            return g_new, ls.solve(names, weights / g_new), it
        g = g_new


def _cv_measured(ls: BlockLS, y_meas: np.ndarray, g: np.ndarray, names, weights) -> np.ndarray:
    """Per joint held-out SSE [N²·m²] in measured units of the fit on targets ``g τ_meas``."""
    ls.set_y(y_meas * g)
    return ls.cv_sse(names, weights / g) / g**2


def estimate(
    ls: BlockLS,
    names: Sequence[str],
    weights: np.ndarray,
    offsets: dict[int, tuple[str, int]],
    noise: NoiseFloor,
    alpha: float,
) -> Chain:
    """The measurement chain of the targets of ``ls`` (module docstring), fitting groups
    ``names`` with row ``weights`` (per measured N·m); ``offsets`` maps a joint to the group
    and column index of its constant column (a joint without one gets offset 0). ``noise``
    (of the training data) and ``alpha`` set the test that keeps a joint's gain. ``ls`` gets
    its measured targets back."""
    names = list(names)
    y_meas = ls.y.copy()
    n = y_meas.shape[1]
    try:
        free = np.ones(n, dtype=bool)
        g, _, _ = _alternate(ls, y_meas, names, weights, free)
        cv_free = _cv_measured(ls, y_meas, g, names, weights)
        cv_fixed = np.zeros(n)
        for j in range(n):
            gj = g.copy()
            gj[j] = 1.0
            cv_fixed[j] = _cv_measured(ls, y_meas, gj, names, weights)[j]
        threshold = chi2_threshold(1, n, alpha)
        free = (cv_fixed - cv_free) / noise.dof_nm2 >= threshold
        g, sol, iterations = _alternate(ls, y_meas, names, weights, free)
        gain = 1.0 / g
        offset = np.zeros(n)
        for j, (group, col) in offsets.items():
            offset[j] = gain[j] * float(sol.coef[group][col])
        counts = np.maximum(ls.counts, 1.0)
        return Chain(
            gain, offset, free, np.sqrt(cv_fixed / counts), np.sqrt(cv_free / counts), iterations
        )
    finally:
        ls.set_y(y_meas)


def settle(ls: BlockLS, run: Any, fit: Any, alpha: float, say: Any) -> tuple[Any, Chain]:
    """The chain of ``fit`` (a :class:`.fit.FrictionFit` whose friction terms carry the
    constant column) estimated on ``ls``; then the analysis goes physical: ``run.train`` and
    ``run.test`` (and ``ls``) get the torque ``(τ_meas - b) / k``, the friction terms lose
    their extra column (the offset is the chain's now), and ``fit`` comes back solved again on
    that target, its row weights per physical N·m."""
    offsets = {t.joint: (t.key, t.offset_column) for t in fit.terms if t.offset_column >= 0}
    chain = estimate(ls, fit.names, fit.weights, offsets, NoiseFloor.of(run.train), alpha)
    run.train = run.train.with_tau(chain.to_physical(run.train.tau))
    run.test = run.test.with_tau(chain.to_physical(run.test.tau))
    ls.set_y(run.train.tau)
    terms = [replace(t, offset=False) for t in fit.terms]
    for t in terms:
        ls.add(t.key, t.columns(run.ctx_train))
    weights = fit.weights * chain.gain
    fit = replace(fit, terms=terms, weights=weights, evaluation=ls.evaluate(fit.names, weights))
    say(
        f"measurement chain: gain {np.array2string(chain.gain, precision=4)} (estimated on "
        f"joints {[j + 1 for j in np.flatnonzero(chain.free)]}), offset "
        f"{np.array2string(chain.offset_nm, precision=3)} N·m"
    )
    return fit, chain
