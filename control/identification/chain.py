"""The torque channel's measurement chain: per-joint gain and offset, estimated with the arm.

A drive reports its torque from the motor current through a datasheet torque constant and a
current sensor, so what the file holds is, per joint j::

    τ_meas,j = k_j τ_j + b_j,       τ_j = Y_b,j β + F_j φ_j

with a gain k_j a few % off (the torque constant) and an offset b_j (the sensor's zero). The
rigid-body parameters β are shared by all joints: with a per-joint gain no single β fits every
joint, and what is left over looks like effects that are not there. An offset is not in the
eq. (14)/(15) families at all.

Estimation (:func:`settle`, :func:`estimate`), inside the fit: with the rigid body, the
friction and the effects found all along (case A of :mod:`.effects`), before the effects
between training and test (case B) and before the guard, so that everything after it works on
the physical torque. Estimated *before* case A, the chain took part of real effects: on the
bench (tests/unit/test_ident_effects.py) the offset took the constant of a 400 N·m/rad spring
(k came out 303, q0 0.04 instead of 0.2), gains and offsets took part of a 20 ms delay (found
16.5 ms) and the gain of a wrist joint took a wrist coupling (family seed 1 with the chain).
Case A's rule (ii) already needs an effect to beat noise on held-out folds, so with gain
errors left in it may still take a false one: that is the price of this order.

- *offset*: a constant column per joint is added to every friction family while the chain
  is estimated (``simple`` has its own and gets no second); its coefficient is c_j = b_j /
  k_j. The asymmetric part of Coulomb friction shows the same way: the data cannot tell the
  two apart, and the model keeps the sum as the offset.
- *gain*: ``τ_meas,j = k_j p_j`` with ``p_j = Y_b,j β + F_j φ_j + c_j`` is bilinear. It is
  solved in measured units by Gauss-Newton: at fixed k the fit is linear in the scaled
  targets ``τ_meas,j / k_j`` (rows weighted by k_j so that residuals stay in measured N·m);
  the step adds per joint the column p_j (the fit's own, noise-free prediction) with
  coefficient ε_j, and k_j ← k_j (1 + ε_j), until ε is below :data:`STEP_TOLERANCE`. Two
  things that were tried first and failed: alternating the linear fit with the per-joint
  ``k_j = <τ_j, p_j> / <p_j, p_j>`` crawls along the weakly determined directions (not
  converged after 30 rounds on a 7-joint draw), and the one-shot linear form ``τ_meas,j =
  A_j θ - δ_j τ_meas,j`` uses the noisy torque as a column: it pulls 1/k down by about
  (σ_j / RMS τ_j)², which on a wrist joint whose torque is near its noise gave k = 1.4-1.8.
- *gauge and which joints*: scaling every k by s and β, φ, c by 1/s fits the data exactly as
  well (only the weak URDF prior on β notices; in the linear form δ = -1, β = 0 even fits
  exactly), so only gains *relative* to a reference are determined, and k_j only through the
  part of joint j's rigid-body row that other joints share: where that is small, k_j is not
  determined and must stay 1. Forward selection: all joints start as the reference (k = 1);
  at least one joint stays in the reference, whose gain 1 sets the common scale (the
  remaining joints' measured torque is then modelled on that scale). Each round a joint's
  gain is freed only on evidence of its own channel that holds out of sample:

  (a) *its own joint's held-out error drops beyond noise*: with the gain column added, the
      blocked K-fold held-out sum of squares of joint j (:meth:`.lsq.BlockLS.cv_sse`, the
      pipeline's cross-validation) falls by drop_j with drop_j / noise_dof_j ≥ the χ²_1
      quantile at level ``alpha / (joints tried)`` (test (ii) of :mod:`.effect_rules` on that
      joint alone, as the offsets below);
  (b) *it holds forward in time*, rule (iv) of :mod:`.effect_rules` with its machinery
      (:func:`.effect_rules.forward_sse`): everything fitted on the first half of the training
      rows with and without joint j's gain column (the first half's own prediction, so that
      nothing of the second half is in it), joint j's sum of squares on the second half
      falls by the same χ²_1 quantile × noise_dof_j. Otherwise the gain stays 1.

  Among the joints that pass (a), the largest drop is tried first; the first that passes (b)
  is freed. The rule before summed the drops over all joints; on the virtual cell's nominal
  plant (plant seed 0: torque constants as the datasheet's, so no gain error, but stiction,
  cylinders and other structure the declared model lacks) it freed J2 at 1.001 and J4 at
  0.986 in one commissioning (0.9999, 0.9996 and 0.9911 on J2-J4 re-analysing another
  recording of it), and J4's own held-out RMS went 0.12098 → 0.12099 N·m: its gain was freed
  only because a free gain on J4 let the shared rigid parameters follow structure on the
  other joints. A gain is a property of one joint's torque channel; a drop elsewhere is a
  model mismatch moving through β (test_ident_chain.py: a joint that alone sets a parameter
  is not freed when another joint's row wants a different value of it). And K-fold
  interpolation between neighbouring blocks lets a gain column split the difference of
  anything that scales with the joint's torque in part of the run; a datasheet constant's
  error holds all run long, so a gain fitted on the start of a recording must predict its
  rest (of *each* recording, :func:`leading_halves`: the training files are each joint's
  friction sweeps and then multi-sines, and a model fitted on the first half of the rows has
  seen no multi-sine). The virtual cell's other plant seeds draw each drive's torque constant
  within ±7 % (``sim_bridge/truth.py``), which the product reads through the datasheet's: a
  real gain per joint, found there on the joints whose rigid row ties them (the J1 at 1.016
  of the other commissioning matches plant seed 1's J1, 1 / 0.9839).
- *which offsets*: within a training range of a radian or so the constant is nearly a
  combination of the joint's gravity columns (``cos q`` barely changes), so a fitted offset
  can trade with the link's mass moments there and the two then extrapolate apart outside it
  (a false spring or Stribeck term on the test run). The constant column a family did not
  have (eq. 14/15) is kept on a joint only when removing it raises the joint's held-out sum
  of squares by more than the same χ²_1 noise test; ``simple`` keeps its own.

Afterwards the analysis works on the physical torque ``(τ_meas - b) / k`` (:meth:`Chain.
to_physical`) and every model it builds carries the chain (:class:`.model.IdentifiedModel`'s
``torque_gain`` and ``torque_offset_nm``), so what it predicts for a torque channel is again
``k τ + b``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from control.identification.effect_rules import NoiseFloor, chi2_threshold, forward_sse
from control.identification.friction_law import FRICTION_PARAM_NAMES
from control.identification.lsq import BlockLS, Evaluation


@dataclass(frozen=True)
class Chain:
    """Per joint ``gain`` k (n,) and ``offset_nm`` b (n,) [N·m] of ``τ_meas = k τ + b``;
    ``free`` (n,) whether the joint's gain was estimated (else held at 1), ``cv_rms_fixed`` (n,)
    the held-out RMS [N·m] with every gain 1, ``cv_rms_free`` (n,) the joint's held-out RMS
    once its gain was freed (NaN: never freed)."""

    gain: np.ndarray
    offset_nm: np.ndarray
    free: np.ndarray
    cv_rms_fixed: np.ndarray
    cv_rms_free: np.ndarray

    @classmethod
    def identity(cls, n: int) -> Chain:
        one, zero = np.ones(n), np.zeros(n)
        return cls(one, zero, np.zeros(n, dtype=bool), zero, zero)

    def to_physical(self, tau_nm: np.ndarray) -> np.ndarray:
        """The torque behind readings ``tau_nm`` (T, n): ``(τ_meas - b) / k``."""
        return (np.asarray(tau_nm, dtype=float) - self.offset_nm) / self.gain

    def to_measured(self, tau_nm: np.ndarray) -> np.ndarray:
        """What the channel reads for torques ``tau_nm`` (T, n): ``k τ + b``."""
        return np.asarray(tau_nm, dtype=float) * self.gain + self.offset_nm

    def to_json(self) -> dict[str, Any]:
        return {
            "model": "tau_measured = gain * tau + offset_nm, per joint",
            "gain": [float(v) for v in self.gain],
            "offset_nm": [float(v) for v in self.offset_nm],
            "gain_estimated": [bool(v) for v in self.free],
            "heldout_rms_train_gain_1": [float(v) for v in self.cv_rms_fixed],
            "heldout_rms_train_gain_free": [float(v) for v in self.cv_rms_free],
        }


#: Largest offset the chain takes for a sensor's zero, as a share of the largest torque the
#: joint's channel read on the training files. A drive's current sensor is specified to ~1 %
#: of its full scale (Hall sensors: 0.5-1 %), and a test motion reaches a good part of that
#: scale; a constant column that takes more is trading with the model's own columns (within a
#: training range, gravity's ``cos q`` is nearly a constant, and the URDF prior holds the mass
#: moments back) and extrapolates apart from them outside it.
MAX_OFFSET_SHARE = 0.05
#: Gauss-Newton steps at most, and the relative gain change at which they stop.
MAX_STEPS = 20
STEP_TOLERANCE = 1e-7


def _gain_key(j: int) -> str:
    """Group of joint j's gain column while the chain is estimated."""
    return f"chain-gain:{j}"


class _Fit:
    """The linear fit of ``names`` at fixed gains ``k`` on ``ls``, in measured units: targets
    ``τ_meas / k`` with row weights ``w k`` (a scaled row's residual is the measured one / k)."""

    def __init__(
        self, ls: BlockLS, y_meas: np.ndarray, names: list[str], w: np.ndarray, k: np.ndarray
    ) -> None:
        self.ls, self.y_meas, self.names, self.w, self.k = ls, y_meas, names, w, k
        ls.set_y(y_meas / k)
        self.solution = ls.solve(names, w * k)
        #: the model's torque (T, n), physical: the Gauss-Newton column of each gain
        self.pred = ls.predict(self.solution)

    def cv_sse(self, gains: Sequence[int] = ()) -> np.ndarray:
        """Held-out SSE per joint [N²·m² measured] with the gains of joints ``gains`` fitted
        too (linearised about ``k``)."""
        for j in gains:
            self.ls.add(_gain_key(j), {j: self.pred[:, j : j + 1]})
        try:
            names = [*self.names, *map(_gain_key, gains)]
            return self.ls.cv_sse(names, self.w * self.k) * self.k**2
        finally:
            for j in gains:
                self.ls.remove(_gain_key(j))

    def forward_drop(self, j: int, first: np.ndarray | None) -> float:
        """Joint j's drop [N²·m² measured] of the sum of squares on the rows not in ``first``
        (T,) when its gain is fitted too, everything fitted on the rows in ``first`` (None:
        the first half of the rows); rule (iv) of :mod:`.effect_rules`, with its
        :func:`.effect_rules.forward_sse`. The gain's column is the prediction of that fit, so
        nothing of the rows scored is in it."""
        sse = forward_sse(
            self.ls, self.names, self.w * self.k, _gain_key(j),
            lambda fitted: {j: fitted[:, j : j + 1]}, first=first,
        )  # fmt: skip
        return float(sse.before[j] - sse.after[j]) * float(self.k[j]) ** 2

    def step(self, free: Sequence[int]) -> np.ndarray:
        """One Gauss-Newton step of the gains of joints ``free``: the new k (n,).
        ``τ_meas,j = k_j (1 + ε_j) p_j`` linearised: ``τ_meas,j / k_j = A_j θ + ε_j p_j``."""
        for j in free:
            self.ls.add(_gain_key(j), {j: self.pred[:, j : j + 1]})
        try:
            sol = self.ls.solve([*self.names, *map(_gain_key, free)], self.w * self.k)
        finally:
            for j in free:
                self.ls.remove(_gain_key(j))
        k = self.k.copy()
        for j in free:
            k[j] *= 1.0 + float(sol.coef[_gain_key(j)][0])
        return k


def _converge(
    ls: BlockLS, y_meas: np.ndarray, names: list[str], w: np.ndarray, k: np.ndarray, free
) -> _Fit:
    fit = _Fit(ls, y_meas, names, w, k)
    for _ in range(MAX_STEPS if free else 0):
        k_new = fit.step(free)
        if not np.all(np.isfinite(k_new) & (k_new > 0)):
            break
        done = np.max(np.abs(k_new / fit.k - 1.0)) < STEP_TOLERANCE
        fit = _Fit(ls, y_meas, names, w, k_new)
        if done:
            break
    return fit


def _quiet(_: str) -> None:
    pass


def estimate(
    ls: BlockLS,
    names: Sequence[str],
    weights: np.ndarray,
    offsets: dict[int, tuple[str, int]],
    noise: NoiseFloor,
    alpha: float,
    dropped_offset: Any = None,
    say: Callable[[str], None] = _quiet,
    first: np.ndarray | None = None,
) -> Chain:
    """The measurement chain of the targets of ``ls`` (module docstring), fitting groups
    ``names`` with row ``weights``; ``offsets`` maps a joint to the group and column index of
    its constant column (a joint without one gets offset 0). ``noise`` (of the training data)
    and ``alpha`` set the test that frees a joint's gain, and the one that keeps the offset of
    each joint ``j`` where ``dropped_offset(j)`` (None: none tested; a tested offset is a group
    of its own, one column, left out when refused). ``say`` hears why a gain that beat noise
    on the held-out folds was kept at 1. ``first`` (T,) the rows a gain is fitted on to be
    scored on the others (:func:`leading_halves`; None: the first half of the rows). ``ls``
    gets its measured targets back."""
    names = list(names)
    offsets = dict(offsets)
    y_meas = ls.y.copy()
    n = y_meas.shape[1]
    try:
        free: list[int] = []
        fit = _Fit(ls, y_meas, names, weights, np.ones(n))
        current = fit.cv_sse()
        cv_fixed = current.copy()
        cv_free = np.full(n, np.nan)
        # forward: the joint whose free gain lowers its own held-out error most beyond noise,
        # if that holds forward in time; one joint at least stays the reference (k = 1)
        while len(free) < n - 1:
            tried = [j for j in range(n) if j not in free]
            threshold = chi2_threshold(1, len(tried), alpha)
            own = {j: (current[j] - fit.cv_sse([j])[j]) / noise.dof_nm2[j] for j in tried}
            best = None
            for j in sorted((j for j in tried if own[j] >= threshold), key=lambda j: -own[j]):
                ahead = fit.forward_drop(j, first) / noise.dof_nm2[j]
                held = ahead >= threshold
                say(
                    f"measurement chain: gain of joint {j + 1} "
                    f"{'freed' if held else 'kept at 1'}: its held-out drop {own[j]:.1f} noise "
                    f"dof (threshold {threshold:.1f}) {'holds' if held else 'does not hold'} "
                    f"forward (fitted on the first half of each recording, {ahead:.3g} on the "
                    "second)"
                )
                if held:
                    best = j
                    break
            if best is None:
                break
            free.append(best)
            fit = _converge(ls, y_meas, names, weights, fit.k, free)
            current = fit.cv_sse()
            cv_free[best] = current[best]
        if dropped_offset is not None:
            threshold = chi2_threshold(1, n, alpha)
            reach = np.max(np.abs(y_meas), axis=0)
            for j, (group, col) in list(offsets.items()):
                if not dropped_offset(j):
                    continue
                value = float(fit.k[j] * fit.solution.coef[group][col])
                if abs(value) > MAX_OFFSET_SHARE * reach[j]:
                    say(
                        f"measurement chain: offset of joint {j + 1} left out: {value:.4g} N·m "
                        f"is {abs(value) / reach[j]:.0%} of the largest torque its channel "
                        f"read ({reach[j]:.4g} N·m), no sensor's zero (at most "
                        f"{MAX_OFFSET_SHARE:.0%}): the constant trades with the model's columns"
                    )
                    del offsets[j]
                    names.remove(group)
                    continue
                without = _Fit(ls, y_meas, [g for g in fit.names if g != group], weights, fit.k)
                if (without.cv_sse()[j] - current[j]) / noise.dof_nm2[j] < threshold:
                    del offsets[j]
                    names.remove(group)
            fit = _converge(ls, y_meas, names, weights, fit.k, free)
        gain = fit.k
        offset = np.zeros(n)
        for j, (group, col) in offsets.items():
            offset[j] = gain[j] * float(fit.solution.coef[group][col])
        counts = np.maximum(ls.counts, 1.0)
        is_free = np.isin(np.arange(n), free)
        return Chain(gain, offset, is_free, np.sqrt(cv_fixed / counts), np.sqrt(cv_free / counts))
    finally:
        ls.set_y(y_meas)


def leading_halves(segment: np.ndarray) -> np.ndarray:
    """(T,) true on the first half of every segment (recording) of ids ``segment`` (T,): what
    a gain is fitted on before it is scored on the rest. Training files are different motions
    in turn (each joint's friction sweeps, then multi-sines): fitted on the first half of the
    rows, a model has seen no multi-sine and extrapolates by orders of magnitude."""
    segment = np.asarray(segment)
    first = np.zeros(segment.size, dtype=bool)
    for s in np.unique(segment):
        rows = np.flatnonzero(segment == s)
        first[rows[: rows.size // 2]] = True
    return first


def _offset_key(j: int) -> str:
    """Group of joint j's constant column while the chain is estimated."""
    return f"chain-offset:{j}"


def settle(
    ls: BlockLS, run: Any, fit: Any, names: Sequence[str], alpha: float, say: Any
) -> tuple[Any, Chain, Evaluation]:
    """The chain estimated on ``ls`` with the groups ``names`` (rigid body, the friction of
    ``fit``, a :class:`.fit.FrictionFit`, and the effects accepted so far), then the analysis
    goes physical: ``run.train`` and ``run.test`` (and ``ls``) get the torque
    ``(τ_meas - b) / k``; returns ``fit`` with row weights per physical N·m and solved again,
    the chain, and the evaluation of ``names`` on the new target."""
    names = list(names)
    offsets, added = {}, []
    for t in fit.terms:
        if "offset_nm" in FRICTION_PARAM_NAMES[t.kind]:  # ``simple``: its own, never a second
            offsets[t.joint] = (t.key, FRICTION_PARAM_NAMES[t.kind].index("offset_nm"))
        else:
            ls.add(_offset_key(t.joint), {t.joint: np.ones((ls.n_rows, 1))})
            offsets[t.joint] = (_offset_key(t.joint), 0)
            added.append(_offset_key(t.joint))
    try:
        chain = estimate(
            ls, [*names, *added], fit.weights, offsets, NoiseFloor.of(run.train), alpha,
            lambda j: offsets[j][0] in added, say, leading_halves(run.train.segment),
        )  # fmt: skip
    finally:
        for key in added:
            ls.remove(key)
    run.train = run.train.with_tau(chain.to_physical(run.train.tau))
    run.test = run.test.with_tau(chain.to_physical(run.test.tau))
    # the targets of ``ls`` as they are (shifted by an accepted delay: the chain commutes)
    ls.set_y(chain.to_physical(ls.y))
    weights = fit.weights * chain.gain
    fit = replace(fit, weights=weights, evaluation=ls.evaluate(fit.names, weights))
    say(
        f"measurement chain: gain {np.array2string(chain.gain, precision=4)} (estimated on "
        f"joints {[int(j) + 1 for j in np.flatnonzero(chain.free)]}), offset "
        f"{np.array2string(chain.offset_nm, precision=3)} N·m"
    )
    return fit, chain, ls.evaluate(names, weights)
