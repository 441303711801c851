"""The acceptance rules of the effect search, the verdicts they give, and its hold-outs.

A candidate of the search (:mod:`.effects`, where cases (A) *all along* and (B) *between
training and test* are described) is accepted only if

(i) *effect size*: the held-out RMS of its joint (for the all-joint ``payload``: of some
    joint) falls by at least ``margin`` (default :data:`MARGIN` =
    10 %, ``--margin``); for ``time_delay``, the held-out RMS of all joints together
    (:func:`pooled_gain`, each joint weighted by its inverse noise). A delay is one shift of
    the whole measurement chain (one clock stamps every joint): it lowers the error of every
    joint whose torque changes within the delay, in proportion to how fast it changes. A
    shift that helps one joint alone is that joint's own lag: a presliding friction (LuGre,
    Dahl) turning round behind its velocity's reversal (hard world draw 203: a 3.6 ms
    "delay" taking 10 % off the LuGre joint J2, 3x its floor, and nothing off the others);
(ii) *significance against the measured noise floor*: the drop of the held-out sum of squares
    exceeds what fitting the candidate's ``p`` columns to noise alone could give, at
    family-wise level :data:`ALPHA` over the candidates tried in the round (Bonferroni).
    With the noise floor measured by :mod:`.preprocess` (``noise_dof_nm2``, the noise one
    column takes out on average), a column fitted to pure noise lowers the *in-sample* sum of
    squares by ``noise_dof_nm2 · χ²_p`` and raises the held-out one; requiring the held-out
    drop to beat the ``1 - ALPHA/m`` quantile of ``noise_dof_nm2 · χ²_p`` is therefore a
    conservative test. It replaces BIC on the residual's own MSE, which grew the penalty with
    the model's mismatch instead of with the noise;
(iii) no joint's held-out RMS grows by more than :data:`WORSEN_TOLERANCE`;
(iv) case (B) only, *it holds forward in time* (:func:`forward_gain`): fitted on the first
    half of its part of the test run, the candidate lowers the RMS of the second half on its
    improved joints by at least half the margin, and no joint's by less than
    -:data:`WORSEN_TOLERANCE`;
(v) case (B) only, *it holds where the training run went*: the same forward gain, scored only
    on the test rows inside the training envelope (every joint's q and dq within the training
    run's range), reaches half the margin on the improved joints. Outside the envelope the
    fixed model extrapolates, and any term fitted on the test run there learns the
    extrapolation error (a spurious Stribeck or drift term for a friction shape the declared
    model lacks); an effect that really appeared shows where the model is known to hold. With
    fewer than :data:`MIN_INSIDE_SHARE` of those rows inside, a candidate is taken only if it
    *repairs a failure*: fitted on the first half, it takes the second half of its improved
    joints from at least :data:`FAILURE_FACTOR` × the model's known error (per joint the larger
    of the noise floor and its held-out RMS on the training files; root mean square of the
    ratios over the joints) to at most :data:`EXPLAINED_FACTOR` × it. An extrapolation error
    has the shape of whatever the model's parameters got wrong; a term of a few parameters that
    takes all of a large one, forward in time, is the effect itself (a payload fixed between
    the runs, on a test run that goes elsewhere).

(vi) case (A) only, *below the margin where plain least squares wins*: when no candidate
    passes (i), one that passes (ii) and (iii) is still taken if it brings a joint on which
    the guard's plain least squares (per-joint coefficients, no shared physics) has the lower
    held-out error to at least that error. Plain least squares beating the shared model there
    by more than the model's own parameter error on that joint can account for
    (:func:`rescuing`) says the model lacks something on that joint; a significant effect that
    accounts for the difference is a better repair than the guard's fallback to a fit without
    physics.

(vii) *its parameters are physical*: a payload has a positive mass; a Stribeck rise and
    load-dependent friction add friction (positive amplitude, positive coefficient); a spring
    pulls towards its rest angle (k > 0: a hose, a cable or a balancer is a passive elastic
    element), and its rest angle lies within the training range of its joint widened by that
    range on each side, and its torque over that training range stays within
    :data:`SPRING_TORQUE_FACTOR` times the joint's torque room (:attr:`.envelope.Envelope.
    torque_room_nm`: the largest torque the joint's channel read plus the largest the URDF's
    rigid body asks of it). The motor holds the arm against gravity and the spring together,
    so a spring far stronger than both needs an opposite torque as large that neither the
    measurement nor the URDF shows: a steep line fitted through a periodic torque over a short
    range (a gear ripple of 52 N·m at 10 cycles per revolution on a 0.9 rad motion came out a
    spring of 4e5 N·m/rad, over 100× the joint's largest torque; refused, the ripple is named).
    Otherwise the term is fitting something else the declared model lacks
    (a spring whose rest angle is tens of radians away is a constant offset, such as the
    direction-dependent part of a Coulomb friction, with a small slope; a negative one the
    gravity of a mass the model lacks, or its extrapolation), and naming it would be false.
    In case (B), where the model is fixed, a candidate must also pass (i) and (ii) against a
    constant on each joint it acts on, with that constant beside it
    (:func:`.effects._only_a_moved_mean`): a joint whose mean torque moved between the runs
    is not a spring (whose own constant that is: its slope is judged) nor a coupling.

(viii) case (A), *the backward look*: on the final fit (the measurement chain settled, every
    effect in), each accepted effect is judged again by (i)-(iii), (vi) and (vii) against
    the final model without it; the weakest that fails is dropped and the rest judged again
    (:func:`.effects.prune`). An effect taken against the model of its round can be
    redundant in the final one (a joint's offset, taken by the chain after the search; a
    later effect), and naming it would be false.

Rules (iv) and (v) are checked on the acceptable candidates in order of their score; the
first that holds is taken.

Among the acceptable ones the largest drop of the weighted held-out error wins.

Here too: the search's settings (:class:`Options`), the measured noise floor the
significance test (ii) uses (:class:`NoiseFloor`), the hold-out forward in time of rules
(iv)/(v) (:func:`forward_sse`, also used by the measurement chain's gains, :mod:`.chain`),
and what a round says (:func:`_describe`, :func:`_log_round`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np
from scipy.special import chdtri

from control.identification.envelope import Envelope
from control.identification.lsq import BlockLS, Evaluation, Solution, contiguous_folds
from control.identification.preprocess import Prepared
from control.identification.terms import EffectTerm

MARGIN = 0.10
#: Family-wise probability, per search round, of accepting a candidate that only fits noise.
ALPHA = 0.01
WORSEN_TOLERANCE = 0.05
#: What rule (vi) measures the model against.
RIVAL = "plain least squares"
#: Rule (vii): the narrowest joint range [rad] a spring's rest angle is judged against.
SPRING_MIN_RANGE_RAD = 0.2
#: Rule (vii): a spring's largest torque over its joint's training range, at most this many
#: times the joint's torque room. A balancer carries at most the arm's weight, and the URDF's
#: weight is off by its masses' and centres' errors (tens of per cent, not a factor of two);
#: a twofold room leaves a spring that cancels the whole gravity the URDF gives, and more.
SPRING_TORQUE_FACTOR = 2.0
#: Rule (v): least share of the scored test rows inside the training envelope.
MIN_INSIDE_SHARE = 0.1
#: Rule (v) with fewer rows inside: a candidate takes the test error of its improved joints
#: from at least FAILURE_FACTOR × the model's known error (noise floor or training held-out
#: RMS, joint by joint; root mean square over the joints) to at most EXPLAINED_FACTOR × it.
FAILURE_FACTOR = 5.0
EXPLAINED_FACTOR = 2.0
MAX_EFFECTS = 6
DEFAULT_FOLDS = 5
RIPPLE_CYCLES = (1, 200)
DELAY_MAX_S = 0.1
DELAY_STEP_S = 0.005

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Options:
    """Search settings (see the module docstrings of :mod:`.effects`, :mod:`.effect_candidates`
    and this one)."""

    margin: float = MARGIN
    alpha: float = ALPHA
    max_effects: int = MAX_EFFECTS
    folds: int = DEFAULT_FOLDS
    ripple_cycles: tuple[int, int] = RIPPLE_CYCLES
    delay_max_s: float = DELAY_MAX_S
    delay_step_s: float = DELAY_STEP_S


@dataclass
class Verdict:
    term: EffectTerm
    evaluation: Evaluation
    accepted: bool
    score: float
    rel: np.ndarray
    improved: tuple[int, ...]
    chi2: float
    chi2_threshold: float
    delay_s: float = 0.0
    #: why rule (vii) refuses its parameters ("" when they are physical)
    implausible: str = ""


def refusal(v: Verdict, case: str, reason: str) -> dict[str, Any]:
    """A refused candidate as the summary lists it."""
    coef = v.evaluation.solution.coef.get(v.term.key)
    return {
        "name": v.term.name,
        "joints": [j + 1 for j in (v.improved or v.term.joints)],
        "case": case,
        "heldout_gain": round(float(np.max(v.rel[list(v.improved or v.term.joints)])), 4),
        "parameters": v.term.parameters(coef) if coef is not None else dict(v.term.setting),
        "reason": reason,
    }


def _note_implausible(
    verdicts: Sequence[Verdict], case: str, out: list[dict[str, Any]], progress: Progress
) -> None:
    """Record (and say) the candidates rule (vii) alone turned down."""
    for v in verdicts:
        no_worse = bool(np.all(v.rel >= -WORSEN_TOLERANCE))
        seen = any(r["name"] == v.term.name and r["case"] == case and
                   r["joints"] == [j + 1 for j in v.improved] for r in out)  # fmt: skip
        if v.implausible and v.improved and v.chi2 >= v.chi2_threshold and no_worse and not seen:
            out.append(refusal(v, case, f"implausible: {v.implausible}"))
            progress(f"refused {_describe(v)}: implausible, {v.implausible}")


def _quiet(_: str) -> None:
    pass


@dataclass(frozen=True)
class NoiseFloor:
    """Measured noise of one data set (see :class:`.preprocess.Prepared`): ``std_nm`` (n,)
    the noise std left in the filtered torque [N·m], ``dof_nm2`` (n,) the sum of squares one
    fitted column takes out of pure noise on average [N²·m²]."""

    std_nm: np.ndarray
    dof_nm2: np.ndarray

    @classmethod
    def of(cls, data: Prepared) -> NoiseFloor:
        """From ``data``; where the data cannot tell (no estimate), a tiny floor, so that the
        significance test (ii) is left to the other two."""
        n = data.n_joints
        std = data.noise_nm if data.noise_nm is not None else np.zeros(n)
        dof = data.noise_dof_nm2 if data.noise_dof_nm2 is not None else np.zeros(n)
        std = np.where(np.isfinite(std), std, 0.0)
        dof = np.where(np.isfinite(dof), dof, 0.0)
        return cls(std, np.maximum(dof, 1e-300))


def chi2_threshold(p: int, tried: int, alpha: float) -> float:
    """``1 - alpha/tried`` quantile of χ² with ``p`` degrees of freedom (Bonferroni)."""
    return float(chdtri(max(p, 1), alpha / max(tried, 1)))  # chi2.isf(alpha, p)


def judge(
    term: EffectTerm,
    current: Evaluation,
    new: Evaluation,
    weights: np.ndarray,
    noise: NoiseFloor,
    tried: int,
    options: Options,
    extra_params: int = 0,
    envelope: Envelope | None = None,
) -> Verdict:
    """Accept/reject ``term`` (rules (i)-(iii) and (vii) of the module docstring); ``tried``
    is the number of candidate settings of the round, ``extra_params`` counts non-linear
    settings, ``envelope`` is the training envelope (rule (vii)'s joint ranges)."""
    cur = np.maximum(current.cv_sse, 1e-300)
    rel = 1.0 - np.sqrt(np.maximum(new.cv_sse, 0.0) / cur)
    drop = current.cv_sse - new.cv_sse
    joints = list(term.joints)
    p = max(new.rank - current.rank, 0) + extra_params
    stat = float(np.sum(drop[joints] / noise.dof_nm2[joints]))
    threshold = chi2_threshold(p, tried, options.alpha)
    big = rel >= options.margin
    if len(term.joints) == 1:
        improved = tuple(j for j in term.joints if big[j])
    elif term.name == "time_delay" and pooled_gain(current, new, weights) < options.margin:
        improved = ()
    else:
        improved = tuple(int(j) for j in np.flatnonzero(big))
    no_worse = bool(np.all(rel >= -WORSEN_TOLERANCE))
    coef = new.solution.coef.get(term.key)
    why = "" if coef is None else implausible(term, coef, envelope)
    ok = bool(improved) and no_worse and stat >= threshold and not why
    score = float(np.sum(weights**2 * drop))
    return Verdict(term, new, ok, score, rel, improved, stat, threshold, implausible=why)


def pooled_gain(current: Evaluation, new: Evaluation, weights: np.ndarray) -> float:
    """The relative fall of the held-out RMS over all joints together, each joint's sum of
    squares weighted as the fit weighs it (by its inverse noise squared): the effect size of
    one shift of the whole measurement chain (rule (i) for ``time_delay``)."""
    w2 = np.asarray(weights, dtype=float) ** 2
    cur = float(np.sum(w2 * np.asarray(current.cv_sse)))
    new_sse = float(np.sum(w2 * np.maximum(np.asarray(new.cv_sse), 0.0)))
    return 1.0 - float(np.sqrt(new_sse / cur)) if cur > 0.0 else 0.0


def implausible(term: EffectTerm, coef: np.ndarray, envelope: Envelope | None) -> str:
    """Why rule (vii) refuses ``term`` with fitted coefficients ``coef`` ("" if it does not)."""
    p = term.parameters(coef)
    if term.name == "payload" and p["mass_kg"] <= 0.0:
        return f"a payload of {p['mass_kg']:.3g} kg"
    if term.name == "stribeck" and p["amplitude_nm"] <= 0.0:
        return f"a Stribeck rise of {p['amplitude_nm']:.3g} N·m (friction falling at low speed)"
    if term.name == "load_dependent_friction" and p["coefficient"] <= 0.0:
        return f"load-dependent friction {p['coefficient']:.3g} (friction falling under load)"
    if term.name == "spring" and p["k_nm_per_rad"] <= 0.0:
        return (
            f"a spring of {p['k_nm_per_rad']:.3g} N·m/rad (pushing away from its rest angle: "
            "a mass's gravity the model lacks, or its extrapolation)"
        )
    if term.name == "spring" and envelope is not None:
        (j,) = term.joints
        lo, hi = float(envelope.q_min[j]), float(envelope.q_max[j])
        width = max(hi - lo, SPRING_MIN_RANGE_RAD)
        if not lo - width <= p["q0_rad"] <= hi + width:
            return (
                f"a spring at rest at {p['q0_rad']:.3g} rad, far outside the joint's range "
                f"[{lo:.3g}, {hi:.3g}] rad (a constant offset with a slope)"
            )
        room = envelope.torque_room_nm
        if room is not None:
            peak = abs(p["k_nm_per_rad"]) * max(abs(lo - p["q0_rad"]), abs(hi - p["q0_rad"]))
            if peak > SPRING_TORQUE_FACTOR * float(room[j]):
                return (
                    f"a spring of {p['k_nm_per_rad']:.3g} N·m/rad whose torque reaches "
                    f"{peak:.3g} N·m over the joint's range, more than {SPRING_TORQUE_FACTOR:g}× "
                    f"the {float(room[j]):.3g} N·m the joint's torque and the URDF's rigid body "
                    "span there (a steep line through a periodic or rigid-body torque)"
                )
    return ""


def rescuing(
    verdicts: Sequence[Verdict],
    current: Evaluation,
    rival_sse: np.ndarray,
    noise: NoiseFloor,
    alpha: float = ALPHA,
) -> list[Verdict]:
    """Rule (vi): the candidates that pass rules (ii) and (iii) and take some joint the rival
    (plain least squares) beats on the held-out folds to at least the rival's error; their
    ``improved`` joints are those. Empty when the rival beats no joint.

    The rival *beats* a joint when its held-out sum of squares is lower by more than the
    model's own estimation error there can make it. Two fits of the same data differ in
    held-out error by noise-sized amounts however good both are (the same held-out noise
    cancels in the difference; what is left is each fit's parameter error): a lead that small
    says nothing is missing, and a candidate that closed it was taken for a sub-per-cent gain
    (a 0.4 ms delay at 100 Hz named on a draw with no effect at all; hard world draw 229, a
    0.004 N·m/rad "spring" for a 0.13 % lead on a joint at its noise floor). The model's
    parameter error on joint j is ``noise_dof_nm2 · χ²`` with as many degrees of freedom as
    the parameters that act there, shared or its own, which its held-out and in-sample errors
    measure: a fit of ``d`` effective parameters takes ``d`` noise columns out in sample and
    adds as many held out, ``d_j = (cv_sse - fit_sse) / (2 noise_dof_nm2)`` (at least 1). The
    lead must pass the ``1 - alpha / n`` quantile of ``noise_dof_nm2 · χ²_{d_j}``, each of the
    ``n`` joints tested (Bonferroni, as rule (ii) over its candidates)."""
    cv = np.asarray(current.cv_sse, dtype=float)
    own = np.nan_to_num((cv - np.asarray(current.fit_sse, dtype=float)) / (2.0 * noise.dof_nm2))
    gap = (cv - rival_sse) / noise.dof_nm2
    limit = [chi2_threshold(max(round(float(d)), 1), gap.size, alpha) for d in own]
    beaten = gap > np.asarray(limit)
    if not np.any(beaten):
        return []
    out = []
    for v in verdicts:
        lifted = beaten & (np.asarray(v.evaluation.cv_sse) <= rival_sse)
        lifted[[j for j in range(lifted.size) if j not in v.term.joints]] = False
        no_worse = bool(np.all(v.rel >= -WORSEN_TOLERANCE))
        if np.any(lifted) and no_worse and v.chi2 >= v.chi2_threshold and not v.implausible:
            out.append(
                replace(v, accepted=True, improved=tuple(int(j) for j in np.flatnonzero(lifted)))
            )
    return out


class ForwardSSE(NamedTuple):
    """Per joint (n,) on the scored rows of the second half (:func:`forward_sse`): the sum of
    squares ``before`` (without the candidate) and ``after`` (with it) [N²·m²], and ``rows``
    the rows scored."""

    before: np.ndarray
    after: np.ndarray
    rows: np.ndarray


#: A candidate's columns, or what builds them from the prediction (T, n) of the groups fitted
#: on the first half (a Gauss-Newton column: built from that fit, it carries nothing of the
#: second half).
Columns = dict[int, np.ndarray] | Callable[[np.ndarray], dict[int, np.ndarray]]


def forward_sse(
    ls: BlockLS,
    names: Sequence[str],
    weights: np.ndarray,
    key: str,
    cols: Columns | None,
    y_after: np.ndarray | None = None,
    scored: np.ndarray | None = None,
    first: np.ndarray | None = None,
) -> ForwardSSE:
    """The hold-out of rules (iv)/(v): the groups ``names`` of ``ls`` (their priors too) fitted
    on the first half of its rows without and with the candidate, each scored on the second
    half (on those of its rows where ``scored`` (T,) is true, when given). ``first`` (T,),
    when given, are the rows fitted on instead, the others the rows scored (the first half of
    every recording, when the rows are several recordings of different motions in turn).

    The candidate is a group ``key`` with columns ``cols``, or (a delay) targets ``y_after``.
    What is fitted on the start of a run and then used on what follows has to predict forward
    in time, which K-fold interpolation between neighbouring blocks does not test (a slow
    drift there fits any smooth mismatch of a model). Used by case (B) (:func:`forward_gain`)
    and by the measurement chain's gains (:mod:`.chain`)."""
    if first is None:
        folds: list[Any] = contiguous_folds(ls.n_rows, 2)
    else:
        folds = [np.flatnonzero(first), np.flatnonzero(~np.asarray(first, dtype=bool))]
    halves = BlockLS(ls.y, folds, ls.mask)
    second = halves.folds[1]
    keep = np.ones((ls.n_rows, ls.n)) if ls.mask is None else ls.mask
    if scored is not None:
        keep = keep * np.asarray(scored, dtype=float)[:, None]
    keep = keep[second]

    def second_sse(sol: Solution) -> np.ndarray:
        r = halves.y[second] - halves.predict(sol)[second]
        return np.sum(r * r * keep, axis=0)

    for name in names:
        halves.add(name, ls.cols[name])
        if name in ls.priors:
            halves.priors[name] = ls.priors[name]
    first_fit = halves.solve(list(names), weights, exclude_fold=1)
    before = second_sse(first_fit)
    after_names = list(names)
    if y_after is not None:
        halves.set_y(y_after)
    if cols is not None:
        halves.add(key, cols(halves.predict(first_fit)) if callable(cols) else cols)
        after_names.append(key)
    after = second_sse(halves.solve(after_names, weights, exclude_fold=1))
    return ForwardSSE(before, after, keep.sum(axis=0))


def forward_gain(
    ls: BlockLS,
    names: Sequence[str],
    weights: np.ndarray,
    key: str,
    cols: Columns | None,
    y_after: np.ndarray | None = None,
    scored: np.ndarray | None = None,
    rms_after: np.ndarray | None = None,
) -> np.ndarray:
    """Rules (iv)/(v) of case (B): the relative RMS gain per joint (n,) on the second half of
    ``ls``'s rows (those of them where ``scored`` (T,) is true, when given) when the groups
    ``names`` plus the candidate are fitted on the first half (:func:`forward_sse`);
    ``rms_after`` (n,), when given, receives the RMS left there with the candidate.

    An effect that appeared between training and test is fitted on the start of the test run
    and then used on what follows: it has to predict forward in time (a slow drift fits any
    smooth mismatch of the training model on the test trajectory between K-fold blocks)."""
    sse = forward_sse(ls, names, weights, key, cols, y_after, scored)
    after = np.maximum(sse.after, 0.0)
    if rms_after is not None:
        rms_after[:] = np.sqrt(after / np.maximum(sse.rows, 1.0))
    return 1.0 - np.sqrt(after / np.maximum(sse.before, 1e-300))


# --------------------------------------------------------------------------------------------


def _describe(v: Verdict) -> str:
    t = v.term
    setting = f" {t.setting}" if t.setting else ""
    joints = [j + 1 for j in (v.improved or t.joints)]
    return (
        f"{t.name} joints {joints}{setting}: held-out RMS -"
        f"{100 * float(np.max(v.rel[list(v.improved or t.joints)])):.0f} %, held-out drop "
        f"{v.chi2:.0f} noise dof (threshold {v.chi2_threshold:.0f})"
    )


def _log_round(progress: Progress, where: str, verdicts: Sequence[Verdict]) -> None:
    if not verdicts:
        return
    top = sorted(verdicts, key=lambda v: float(np.max(v.rel)), reverse=True)[:3]
    text = "; ".join(
        f"{v.term.name}{[j + 1 for j in v.term.joints] if len(v.term.joints) == 1 else ''}"
        f"{' ' + str(v.term.setting) if v.term.setting else ''} "
        f"{100 * float(np.max(v.rel)):+.1f} %"
        f"{' ok' if v.accepted else ' implausible' if v.implausible else ''}"
        for v in top
    )
    progress(f"effects ({where}): {len(verdicts)} candidates, best held-out gains: {text}")
