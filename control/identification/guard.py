"""The guard of ``leadthrough analyze`` (stage 6 of :mod:`.analyze`): per joint, the model
against the simplest predictors of that joint's torque.

Per joint, plain least squares (by the margin where the test extrapolates), the URDF's nominal
rigid body with Coulomb/viscous friction, or zero replaces the model where its held-out error
on the training files is lower, measured on fold schemes mixed as the test run's inputs lie
relative to the training rows (:mod:`.folds`; :func:`guard_joints`); then a second look on the
leading rows of the test run, those case (B) of :mod:`.effects` searched
(:func:`guard_on_test`). A joint replaced is a :class:`.model.PlainJoint`;
:func:`plain_least_squares` fits the first fallback for every joint. The whole models these
choices make, and the second look's candidates, are assembled in :mod:`.assembly`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from control.identification.folds import Scheme, gcv_factor
from control.identification.lsq import BlockLS, Evaluation
from control.identification.model import (
    MODEL,
    NOMINAL,
    PLAIN_LS,
    ZERO,
    PlainJoint,
    plain_columns,
    plain_friction_columns,
    plain_key,
)
from control.identification.rigid import RobotRegressor
from control.identification.stages import AnalyzeOptions
from control.identification.terms import Context

#: The second look's name for the training guard's choice (beside PLAIN_LS and ZERO)
CHOSEN = "chosen"


#: Where Coulomb and viscous sit among :func:`.model.plain_columns` (the offset last).
_COULOMB, _VISCOUS = -3, -2


def plain_least_squares(
    ctx: Context, y: np.ndarray, folds: Sequence[slice], mask: np.ndarray | None = None
) -> Any:
    """Plain LS of every joint alone (:func:`.model.plain_columns`) on targets ``y`` (T, n):
    the :class:`.lsq.Evaluation` (held-out SSE per joint over ``folds``) and its groups.

    Friction dissipates: a joint's Coulomb level and viscous coefficient are at least 0 (rule
    (vii) of :mod:`.effect_rules` asks the same of every effect). A negative one is the fit
    trading friction against its rigid row's error on the training motion, and the error
    grows with speed wherever the operator goes faster (the real Panda's J2 took -0.95
    N·m·s/rad with a 2.9 N·m offset when friction's velocity was read at the torque's
    bandwidth, and its error on the raw test torque doubled). Such a column is held at 0, the
    joint refitted without it (the active set of the bound) until none is negative."""
    n = y.shape[1]
    cols = {j: plain_columns(ctx, j)[j] for j in range(n)}
    held: dict[int, set[int]] = {j: set() for j in range(n)}
    while True:
        ls = BlockLS(y, folds, mask)
        free = {j: [c for c in range(-cols[j].shape[1], 0) if c not in held[j]] for j in range(n)}
        for j in range(n):  # a joint with every column free is added as it is (no copy)
            ls.add(plain_key(j), {j: cols[j][:, free[j]] if held[j] else cols[j]})
        ev = ls.evaluate([plain_key(j) for j in range(n)], np.ones(n))
        negative = False
        for j in range(n):
            full = np.zeros(cols[j].shape[1])
            full[free[j]] = ev.solution.coef[plain_key(j)]
            ev.solution.coef[plain_key(j)] = full
            below = {c for c in (_COULOMB, _VISCOUS) if full[c] < 0.0}
            held[j] |= below
            negative = negative or bool(below)
        if not negative:
            return ev


def _plain_prediction(ctx: Context, sol_coef: dict[str, np.ndarray]) -> np.ndarray:
    out = np.zeros_like(ctx.q)
    for j in range(ctx.q.shape[1]):
        out[:, j] = plain_columns(ctx, j)[j] @ sol_coef[plain_key(j)]
    return out


@dataclass(frozen=True)
class Guard:
    """One joint's guard verdict: held-out RMS [N·m] of the model and each fallback on the
    training files, and the fallback that replaces the model (None: the model stays)."""

    joint: int
    cv_rms: dict[str, float]
    fallback: PlainJoint | None
    reason: str

    def to_json(self) -> dict[str, Any]:
        return {
            "joint": self.joint + 1,
            "kept": MODEL if self.fallback is None else self.fallback.kind,
            "heldout_rms_train": self.cv_rms,
            "reason": self.reason,
        }


def _evaluate_on(
    ls: BlockLS,
    names: Sequence[str],
    weights: np.ndarray,
    folds: Sequence[Any],
    mask: np.ndarray | None,
) -> Any:
    """The model of groups ``names`` in ``ls`` evaluated on other ``folds``."""
    other = BlockLS(ls.y, folds, mask)
    other.priors = dict(ls.priors)
    for name in names:
        other.add(name, ls.cols[name])
    return other.evaluate(names, weights)


@dataclass(frozen=True)
class GuardFolds:
    """One fold scheme of the guard (:class:`.folds.Scheme`: its folds, the share of the test
    it stands for, whether it is the in-sample fit) and the model judged on those folds."""

    scheme: Scheme
    model_eval: Evaluation


def guard_joints(
    reg: RobotRegressor,
    ctx: Context,
    y: np.ndarray,
    mask: np.ndarray | None,
    schemes: Sequence[GuardFolds],
    options: AnalyzeOptions,
    plain_margin: float | None = None,
) -> dict[int, Guard]:
    """Per joint, the model against its fallbacks on held-out training rows (targets ``y``):

    - ``plain_ls``: the joint's own base-regressor row, Coulomb and viscous (:func:`.model.
      plain_columns`); it must win by ``plain_margin`` (default the effect margin; the caller
      passes 0 unless the test lies mostly farther from the training rows than any fold from
      its fit, :attr:`.folds.FoldPlan.extrapolates`), since its coefficients have no shared
      physics to extrapolate with (on the bench's synthetic arm a joint it won by 8 % on the
      training folds was 70 % worse on a test run mostly outside the training envelope);
    - ``nominal``: the URDF's own inertials (base parameters of :meth:`.rigid.RobotRegressor.
      parameters`, no armature) with Coulomb/viscous friction fitted on the rest;
    - ``zero``: predicting no torque at all.
    The error of each is the mix of its held-out SSE over ``schemes`` in their shares; an
    in-sample scheme's SSE is multiplied by :func:`.folds.gcv_factor` of the parameters each
    predictor spends per joint (the model's shared ones spread over the joints). The one with
    the lowest error replaces the model where it beats it.
    """
    n = y.shape[1]
    beta_nominal = reg.base.base_values(reg.parameters())
    assert ctx.y_base is not None
    rigid_nominal = np.einsum("jtb,b->tj", ctx.y_base, beta_nominal)
    n_rows = np.maximum(schemes[0].model_eval.n_rows, 1.0)
    mixed = {kind: np.zeros(n) for kind in (MODEL, PLAIN_LS, NOMINAL, ZERO)}
    for guard_folds in schemes:
        scheme = guard_folds.scheme
        plain_eval = plain_least_squares(ctx, y, scheme.folds, mask)
        nominal = BlockLS(y - rigid_nominal, scheme.folds, mask)
        names = []
        for j in range(n):
            nominal.add(f"nominal:{j}", {j: plain_friction_columns(ctx, j)})
            names.append(f"nominal:{j}")
        nominal_eval = nominal.evaluate(names, np.ones(n))
        zero_sse = BlockLS(y, scheme.folds, mask).evaluate([], np.ones(n)).cv_sse
        for kind, ev in (
            (MODEL, guard_folds.model_eval),
            (PLAIN_LS, plain_eval),
            (NOMINAL, nominal_eval),
        ):
            factor = gcv_factor(ev.rank / n if scheme.in_sample else 0.0, n_rows)
            mixed[kind] += scheme.share * ev.cv_sse * factor
        mixed[ZERO] += scheme.share * zero_sse
    out = {}
    keep = (1.0 - (options.search.margin if plain_margin is None else plain_margin)) ** 2
    for j in range(n):
        sse = {kind: float(v[j]) for kind, v in mixed.items()}
        rms_j = {k: float(np.sqrt(v / n_rows[j])) for k, v in sse.items()}
        beats = {k: v for k, v in sse.items() if k != MODEL and v < sse[MODEL]}
        if PLAIN_LS in beats and sse[PLAIN_LS] >= keep * sse[MODEL]:
            del beats[PLAIN_LS]
        if not beats:
            out[j] = Guard(j, rms_j, None, "the model has the lowest held-out error")
            continue
        kind = min(beats, key=beats.__getitem__)
        if kind == PLAIN_LS:
            fallback = PlainJoint.from_coef(j, plain_eval.solution.coef[plain_key(j)])
        elif kind == NOMINAL:
            c = nominal_eval.solution.coef[f"nominal:{j}"]
            fallback = PlainJoint(j, beta_nominal.copy(), *map(float, c[:2]), NOMINAL, float(c[2]))
        else:
            fallback = PlainJoint(j, np.zeros_like(beta_nominal), 0.0, 0.0, ZERO)
        reason = (
            f"the model's held-out error on the training files ({rms_j[MODEL]:.4g} N·m) is "
            f"worse than {kind.replace('_', ' ')}'s ({rms_j[kind]:.4g} N·m): {kind} kept"
        )
        out[j] = Guard(j, rms_j, fallback, reason)
    return out


#: Fewest raw rows of the test run's leading part on which the guard's second look decides.
TEST_GUARD_MIN_ROWS = 200


@dataclass(frozen=True)
class LeadGuard:
    """The guard's second look, on the leading rows of the test run (those case (B) searched):
    per joint the held-out RMS [N·m] there of what the training guard kept, of plain least
    squares and of zero, and what is kept."""

    rows: tuple[int, int]
    rms: list[dict[str, float]]
    kept: list[str]

    def to_json(self) -> dict[str, Any]:
        return {
            "rows": list(self.rows),
            "joints": [
                {"joint": j + 1, "heldout_rms_test_lead": r, "kept": k}
                for j, (r, k) in enumerate(zip(self.rms, self.kept, strict=True))
            ],
        }


def guard_on_test(
    errors: dict[str, np.ndarray], rows: tuple[int, int], chosen_kinds: Sequence[str]
) -> LeadGuard | None:
    """Per joint, what the training guard kept (of kind ``chosen_kinds[j]``) against plain
    least squares and zero on the test run's leading part (analysis rows ``rows``), judged as
    every figure of the analysis is: ``errors`` maps :data:`CHOSEN`, :data:`PLAIN_LS` and
    :data:`ZERO` to the raw measured torque minus each whole model's prediction on the raw
    rows of that part (R, n), NaN where it declines (:func:`.heldout.residuals`), every row
    counted, stops and reversals too. Each model carries the effects that appeared between the
    runs (fitted on those rows: a tool mounted weighs on every joint whatever predicts the
    rest of its torque). The training folds cannot show how a model extrapolates to where the
    test run goes (outside the training envelope, a shared rigid-body fit can lose to a
    joint's own least squares, and an effect nobody declared can grow there); the leading
    test rows can, and no fit has seen them. The lowest error there is kept (the training
    guard's choice on a tie). None when fewer than :data:`TEST_GUARD_MIN_ROWS` rows are
    answered by all three."""
    answered = np.logical_and.reduce([np.isfinite(e).all(axis=1) for e in errors.values()])
    count = int(answered.sum())
    if count < TEST_GUARD_MIN_ROWS:
        return None
    sse = {k: np.sum(e[answered] ** 2, axis=0) for k, e in errors.items()}
    n = next(iter(errors.values())).shape[1]
    rms_rows, kept = [], []
    for j in range(n):
        own = {k: float(v[j]) for k, v in sse.items()}
        best = min(own, key=lambda k: (own[k], k != CHOSEN))
        named = {(chosen_kinds[j] if k == CHOSEN else k): v for k, v in own.items()}
        rms_rows.append({k: float(np.sqrt(v / count)) for k, v in named.items()})
        kept.append(chosen_kinds[j] if best == CHOSEN else best)
    return LeadGuard(rows, rms_rows, kept)
