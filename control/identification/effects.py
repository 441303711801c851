"""Closing the loop: find structure in the residual, name the physical effect, add it, refit.

Candidates come from the effect vocabulary of :mod:`.terms`. Effects with a scanned setting
are pre-screened on the current residual, cheaply, and only the best settings are refitted:

- ``position_ripple``: periodogram of joint j's residual against q_j: for every c in
  :data:`RIPPLE_CYCLES` the drop in residual sum of squares by a LS fit of
  ``sin(c q_j)``, ``cos(c q_j)``; the :data:`RIPPLE_PEAKS` highest local peaks go on;
- ``time_delay``: the refit error over shifts δ in ±:data:`DELAY_MAX_S`, step
  :data:`DELAY_STEP_S`, refined by a bounded scalar search around the best
  (:data:`DELAY_TOLERANCE_S`).

Greedy forward selection, one effect per round, until a round accepts nothing (or
:data:`MAX_EFFECTS`). Every candidate is judged on **held-out** data, trajectory-wise:
contiguous blocks, never random samples (samples 5 ms apart are anything but independent):

(A) *All along* (the effect is in the training data): refit rigid + friction + accepted +
    candidate on the training files; the criterion is K-fold cross-validation over contiguous
    blocks of the training data. Accepted effects are then judged on the test files by the
    caller (``rms_after`` there is a plain held-out number).
(B) *Between training and test* (e.g. a spray gun mounted after the identification run): the
    training model is kept fixed and the candidate's parameters are fitted to the test
    residual of the *first part* of the test run only (``fit_rows``; the search itself
    cross-validates over contiguous blocks of that part); the caller scores the result on the
    rest of the test run, which neither the choice nor the fit has seen. Runs after (A).

A candidate is accepted only if

(i) *effect size*: the held-out RMS of its joint (for the all-joint ``payload`` and
    ``time_delay``: of some joint) falls by at least ``margin`` (default :data:`MARGIN` =
    10 %, ``--margin``);
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
    says the model lacks something on that joint; a significant effect that accounts for the
    difference is a better repair than the guard's fallback to a fit without physics.

(vii) *its parameters are physical*: a payload has a positive mass; a Stribeck rise and
    load-dependent friction add friction (positive amplitude, positive coefficient); a
    spring's rest angle lies within the training range of its joint widened by that range on
    each side. Otherwise the term is fitting something else the declared model lacks (a
    spring whose rest angle is tens of radians away is a constant offset, such as the
    direction-dependent part of a Coulomb friction, with a small slope), and naming it would
    be false.

Rules (iv) and (v) are checked on the acceptable candidates in order of their score; the
first that holds is taken.

Among the acceptable ones the largest drop of the weighted held-out error wins.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from operator import methodcaller
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import chdtri

from control.identification.lsq import BlockLS, Evaluation, Solution, contiguous_folds
from control.identification.parallel import map_forked
from control.identification.preprocess import Prepared
from control.identification.terms import Context, EffectTerm, Envelope, shift_signal

MARGIN = 0.10
#: Family-wise probability, per search round, of accepting a candidate that only fits noise.
ALPHA = 0.01
WORSEN_TOLERANCE = 0.05
#: What rule (vi) measures the model against.
RIVAL = "plain least squares"
#: Rule (vii): the narrowest joint range [rad] a spring's rest angle is judged against.
SPRING_MIN_RANGE_RAD = 0.2
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
RIPPLE_PEAKS = 2
DELAY_MAX_S = 0.1
DELAY_STEP_S = 0.005
#: The delay is refined to this [s] (a tenth of a sample at 1 kHz).
DELAY_TOLERANCE_S = 1e-5
#: Joints that may couple (0-based offsets from the end): the last three.
WRIST_JOINTS = 3
ALL_ALONG = "all_along"
BETWEEN = "between_train_and_test"

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Options:
    """Search settings (see the module docstring)."""

    margin: float = MARGIN
    alpha: float = ALPHA
    max_effects: int = MAX_EFFECTS
    folds: int = DEFAULT_FOLDS
    ripple_cycles: tuple[int, int] = RIPPLE_CYCLES
    delay_max_s: float = DELAY_MAX_S
    delay_step_s: float = DELAY_STEP_S


@dataclass
class Accepted:
    """An accepted effect: its term, fitted coefficients, case, and the held-out RMS per joint
    before and after it was added (training CV for case A, test CV for case B) [N·m]."""

    term: EffectTerm
    coef: np.ndarray
    appeared: str
    improved_joints: tuple[int, ...]
    rms_before: np.ndarray
    rms_after: np.ndarray
    estimated_on: str = "train"


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


@dataclass
class SearchState:
    """Where the greedy search stands on one data set."""

    names: list[str]
    effects: list[EffectTerm] = field(default_factory=list)
    delay_s: float = 0.0
    accepted: list[Accepted] = field(default_factory=list)
    evaluation: Evaluation | None = None
    #: candidates that passed rules (i)-(iii) but were refused, with why (:func:`refusal`)
    refused: list[dict[str, Any]] = field(default_factory=list)


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
    else:
        improved = tuple(int(j) for j in np.flatnonzero(big))
    no_worse = bool(np.all(rel >= -WORSEN_TOLERANCE))
    coef = new.solution.coef.get(term.key)
    why = "" if coef is None else implausible(term, coef, envelope)
    ok = bool(improved) and no_worse and stat >= threshold and not why
    score = float(np.sum(weights**2 * drop))
    return Verdict(term, new, ok, score, rel, improved, stat, threshold, implausible=why)


def implausible(term: EffectTerm, coef: np.ndarray, envelope: Envelope | None) -> str:
    """Why rule (vii) refuses ``term`` with fitted coefficients ``coef`` ("" if it does not)."""
    p = term.parameters(coef)
    if term.name == "payload" and p["mass_kg"] <= 0.0:
        return f"a payload of {p['mass_kg']:.3g} kg"
    if term.name == "stribeck" and p["amplitude_nm"] <= 0.0:
        return f"a Stribeck rise of {p['amplitude_nm']:.3g} N·m (friction falling at low speed)"
    if term.name == "load_dependent_friction" and p["coefficient"] <= 0.0:
        return f"load-dependent friction {p['coefficient']:.3g} (friction falling under load)"
    if term.name == "spring" and envelope is not None:
        (j,) = term.joints
        lo, hi = float(envelope.q_min[j]), float(envelope.q_max[j])
        width = max(hi - lo, SPRING_MIN_RANGE_RAD)
        if not lo - width <= p["q0_rad"] <= hi + width:
            return (
                f"a spring at rest at {p['q0_rad']:.3g} rad, far outside the joint's range "
                f"[{lo:.3g}, {hi:.3g}] rad (a constant offset with a slope)"
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

    The rival *beats* a joint when its held-out sum of squares is lower by more than noise
    gives: by at least the ``1 - alpha`` quantile of ``noise_dof_nm2 · χ²₁`` (rule (ii)'s test
    for one column). Two fits of the same data differ in held-out error by noise-sized amounts
    however good both are; a lead that small says nothing is missing, and a candidate that
    closed it was taken for a sub-per-cent gain (a 0.4 ms delay at 100 Hz, named on a draw
    with no effect at all)."""
    gap = (np.asarray(current.cv_sse) - rival_sse) / noise.dof_nm2
    beaten = gap > chi2_threshold(1, 1, alpha)
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


def scanned_settings(terms: Sequence[EffectTerm], options: Options, delay: bool) -> int:
    """Candidate settings tried in a round, for the Bonferroni count of rule (ii): each ripple
    peak was picked among the scanned cycle counts, the delay among the scanned shifts."""
    lo, hi = options.ripple_cycles
    count = 0
    for t in terms:
        count += hi - lo + 1 if t.name == "position_ripple" else 1
    return count + (_delays(options).size if delay else 0)


# --------------------------------------------------------------------------------------------
# Pre-screens on the residual


def ripple_scores(q: np.ndarray, r: np.ndarray, c_max: int) -> np.ndarray:
    """Residual-SSE drop of a LS fit of sin(c q), cos(c q) to ``r``, for c = 0..c_max (0 → 0)."""
    z = np.exp(1j * np.asarray(q, dtype=float))
    e = np.ones_like(z)
    out = np.zeros(c_max + 1)
    for c in range(1, c_max + 1):
        e = e * z
        if c % 32 == 0:
            e = e / np.abs(e)
        s, co = e.imag, e.real
        g11, g12, g22 = s @ s, s @ co, co @ co
        b1, b2 = s @ r, co @ r
        det = g11 * g22 - g12 * g12
        if det <= 1e-12 * max(g11 * g22, 1e-300):
            continue
        out[c] = (g22 * b1 * b1 - 2 * g12 * b1 * b2 + g11 * b2 * b2) / det
    return out


def _peaks(scores: np.ndarray, lo: int, k: int) -> list[int]:
    s = scores.copy()
    s[:lo] = 0.0
    left = np.r_[-np.inf, s[:-1]]
    right = np.r_[s[1:], -np.inf]
    idx = np.flatnonzero((s >= left) & (s >= right) & (s > 0))
    return [int(i) for i in idx[np.argsort(s[idx])[::-1][:k]]]


def candidates(
    ctx: Context, residual: np.ndarray, done: Sequence[EffectTerm], options: Options
) -> list[EffectTerm]:
    """Linear candidate effects on this data (module docstring), minus those already taken."""
    n = residual.shape[1]
    taken = {(t.name, t.joints) for t in done if t.name != "position_ripple"}
    ripples = {
        (t.joints, t.setting.get("cycles_per_rev")) for t in done if t.name == "position_ripple"
    }
    out: list[EffectTerm] = []
    lo, hi = options.ripple_cycles
    for j in range(n):
        r = residual[:, j]
        # A ripple is only told apart from a spring (or gravity) when the motion spans at
        # least one of its periods: over a shorter range sin(c q) is nearly linear in q.
        span = float(np.ptp(ctx.q[:, j])) if ctx.q.shape[0] else 0.0
        lo_j = max(lo, int(np.ceil(2 * np.pi / span)) if span > 0 else hi + 1)
        for c in _peaks(ripple_scores(ctx.q[:, j], r, hi), lo_j, RIPPLE_PEAKS):
            if ((j,), c) not in ripples:
                out.append(EffectTerm("position_ripple", (j,), {"cycles_per_rev": c}))
        out.append(EffectTerm("spring", (j,)))
        # no ``stribeck``: a Stribeck curve of another shape is the friction's own
        # (:attr:`.terms.FrictionTerm.stribeck_rad_s`, chosen with the friction)
        if ctx.rigid is not None:
            out.append(EffectTerm("load_dependent_friction", (j,)))
        if ctx.t is not None:
            out.append(EffectTerm("thermal_drift", (j,)))
    if ctx.y_payload is not None:
        out.append(EffectTerm("payload", tuple(range(n))))
    if ctx.rigid is not None and ctx.friction is not None and n >= 2:
        wrist = range(max(0, n - WRIST_JOINTS), n)
        for j in wrist:
            for k in wrist:
                if k != j:
                    for source in ("torque", "friction"):
                        out.append(
                            EffectTerm("wrist_coupling", (j,), {"from_joint": k, "source": source})
                        )
    return [t for t in out if (t.name, t.joints) not in taken or t.name == "position_ripple"]


#: how far :func:`best_ripple_neighbour` walks from the periodogram's peak [cycles per rev]
RIPPLE_NEIGHBOURS = 3


def best_ripple_neighbour(
    best: Verdict,
    verdicts: Sequence[Verdict],
    done: Sequence[EffectTerm],
    options: Options,
    judge_terms: Callable[[list[EffectTerm]], list[Verdict]],
) -> Verdict:
    """The accepted ripple ``best``, or an adjacent cycle count the refit scores higher.

    The periodogram's peak is as wide as 2π over the joint's span (about six cycles per rev
    over a 1 rad motion): what else is left in the residual moves it by one or two, and a
    ripple fitted one cycle off drifts out of phase across the span (27 found as 26 kept
    J4 at 0.3-0.6 of its error). The refit, the criterion itself, tells them apart: the
    walk goes to c ± 1 while the score rises, at most :data:`RIPPLE_NEIGHBOURS` steps.
    Every cycle count was already counted in the round's Bonferroni ``tried``."""
    (j,) = best.term.joints
    lo, hi = options.ripple_cycles
    have = {
        t.setting.get("cycles_per_rev")
        for t in done
        if t.name == "position_ripple" and t.joints == (j,)
    }
    judged = {
        int(v.term.setting["cycles_per_rev"]): v
        for v in verdicts
        if v.term.name == "position_ripple" and v.term.joints == (j,)
    }

    def verdict(c: int) -> Verdict | None:
        if not lo <= c <= hi or c in have:
            return None
        if c not in judged:
            term = EffectTerm("position_ripple", (j,), {"cycles_per_rev": c})
            judged[c] = judge_terms([term])[0]
        v = judged[c]
        return v if v.accepted else None

    c0 = int(best.term.setting["cycles_per_rev"])
    for step in (-1, 1):
        c, walked = c0, best
        for _ in range(RIPPLE_NEIGHBOURS):
            v = verdict(c + step)
            if v is None or v.score <= walked.score:
                break
            c, walked = c + step, v
        if walked.score > best.score:
            best = walked
    return best


def _delays(options: Options) -> np.ndarray:
    k = round(options.delay_max_s / options.delay_step_s)
    return options.delay_step_s * np.arange(-k, k + 1)


def _refine(
    deltas: np.ndarray, errors: np.ndarray, error_of: Callable[[float], float] | None = None
) -> float:
    """The delay of least error: the best of the scan ``deltas``, then (with ``error_of``) a
    bounded scalar search within one scan step on either side to :data:`DELAY_TOLERANCE_S`.
    (A parabola through the best three scan points is biased: near its optimum the error of a
    torque with friction steps grows like |δ - δ₀|, not (δ - δ₀)²; it missed a 12.1 ms delay
    by 0.3 ms, which left a heavy joint at 4x its noise floor.)"""
    i = int(np.argmin(errors))
    if error_of is None or deltas.size < 2:
        return float(deltas[i])
    lo, hi = float(deltas[max(i - 1, 0)]), float(deltas[min(i + 1, deltas.size - 1)])
    return _search_delay(error_of, lo, hi, float(deltas[i]), float(errors[i]))


def _search_delay(
    error_of: Callable[[float], float], lo: float, hi: float, best: float, best_error: float
) -> float:
    """Bounded scalar search of ``error_of`` on [lo, hi] to :data:`DELAY_TOLERANCE_S`; ``best``
    (error ``best_error``) unless the search found lower."""
    res = minimize_scalar(
        error_of, bounds=(lo, hi), method="bounded", options={"xatol": DELAY_TOLERANCE_S}
    )
    return float(res.x) if res.fun < best_error else best


def _fit_error_fn(
    ls: BlockLS, names: Sequence[str], weights: np.ndarray, y_of: Callable[[float], np.ndarray]
) -> Callable[[float], float]:
    """``delay → weighted in-sample SSE`` of the groups ``names`` refitted on targets
    ``y_of(delay)`` (left in ``ls``)."""

    def error_of(d: float) -> float:
        ls.set_y(y_of(float(d)))
        return float(np.sum(weights**2 * ls.fold_sse(ls.solve(names, weights)).sum(axis=0)))

    return error_of


def _judge_all(
    ls: BlockLS,
    terms: Sequence[EffectTerm],
    columns: Callable[[EffectTerm], dict[int, np.ndarray]],
    names: Sequence[str],
    weights: np.ndarray,
    current: Evaluation,
    noise: NoiseFloor,
    tried: int,
    options: Options,
    envelope: Envelope | None,
    delay: Callable[[BlockLS], Verdict] | None = None,
) -> list[Verdict]:
    """The verdict on each candidate of a round (``columns(term)`` added to the fit of
    ``names`` on ``ls``), then the delay's (``delay(fork of ls)``) if asked: each on a fork
    of ``ls`` (left as it was), side by side in worker processes (:mod:`.parallel`), the
    delay's scan first (it costs a dozen fits)."""

    def one(i: int) -> Verdict:
        own = ls.fork()
        if i < 0:
            assert delay is not None
            return delay(own)
        term = terms[i]
        own.add(term.key, columns(term))
        new = own.evaluate([*names, term.key], weights)
        return judge(term, current, new, weights, noise, tried, options, 0, envelope)

    order = ([-1] if delay is not None else []) + list(range(len(terms)))
    done = dict(zip(order, map_forked(one, order), strict=True))
    return [done[i] for i in sorted(order, key=lambda i: (i < 0, i))]


# --------------------------------------------------------------------------------------------
# Case A: all along, on the training data


def _refresh_model_columns(
    ctx: Context, ls: BlockLS, sol: Solution, friction_keys: Sequence[str]
) -> None:
    """Current model's rigid and friction torques on the context (for model-based columns)."""
    assert ctx.y_base is not None
    ctx.rigid = np.einsum("jtb,b->tj", ctx.y_base, sol.coef["rigid"])
    fr = np.zeros_like(ctx.q)
    for key in friction_keys:
        for j, c in ls.cols[key].items():
            fr[:, j] += c @ sol.coef[key]
    ctx.friction = fr


def search_all_along(
    ls: BlockLS,
    ctx: Context,
    data: Prepared,
    names: list[str],
    weights: np.ndarray,
    options: Options,
    progress: Progress | None = None,
    refit_friction: Callable[[], list[str]] | None = None,
    rival_sse: Callable[[np.ndarray], np.ndarray] | None = None,
    sliding: Callable[[list[str]], list[str]] | None = None,
) -> SearchState:
    """Case (A) greedy search on the training data in ``ls`` (groups ``names`` fitted there).

    ``ls`` must use contiguous folds; accepted effects stay in ``ls`` (and a delay in its y).
    ``refit_friction()`` re-chooses the friction family and its nonlinear settings (q_e) on
    ``ls``, replaces the friction groups there and returns their names: it is called once a
    delay is accepted, since the friction chosen on the unshifted torque stood in for part of
    the delay (a late sign change looks like a slow one), and left alone would hand the rest
    of the mismatch to spurious Stribeck terms.

    ``rival_sse(y)`` is the held-out sum of squares per joint of the guard's plain least
    squares on targets ``y`` (same folds): when no candidate passes, :func:`rescuing` may
    still take one below the margin (rule (vi) of the module docstring).

    ``sliding(names)``: the groups ``names`` with every friction that has memory
    (:class:`.terms.FrictionTerm`) replaced by the same law without it, added to ``ls``. The
    delay is judged against those: a friction with memory turns round late at a reversal, as
    a torque measured late does, and fitted first it takes the friction's share of a delay and
    leaves the rest below the margin (a 7 ms delay found at +56 % without memory, refused at
    +31 % with it). Once a delay is accepted, ``refit_friction`` chooses the friction, memory
    included, again on the shifted torque.
    """
    progress = progress or _quiet
    noise = NoiseFloor.of(data)
    state = SearchState(names=list(names))
    friction_keys = [k for k in names if k.startswith("friction")]
    y0 = ls.y.copy()
    current = ls.evaluate(state.names, weights)
    while len(state.accepted) < options.max_effects:
        sol = current.solution
        residual = ls.y - ls.predict(sol)
        _refresh_model_columns(ctx, ls, sol, friction_keys)
        terms = candidates(ctx, residual, state.effects, options)
        tried = scanned_settings(terms, options, state.delay_s == 0.0)
        names = list(state.names)
        d_names, d_current = names, current
        if sliding is not None and state.delay_s == 0.0:
            d_names = sliding(names)
            if d_names != names:
                d_current = ls.evaluate(d_names, weights)
        verdicts = _judge_all(
            ls, terms, lambda term: term.columns(ctx), names, weights, current, noise, tried,
            options, ctx.envelope,
            partial(_delay_verdict, target=partial(shift_signal, data.t, data.segment, y0),
                    names=d_names, weights=weights, current=d_current, noise=noise,
                    tried=tried, options=options)
            if state.delay_s == 0.0 else None,
        )  # fmt: skip
        for key in set(d_names) - set(names):
            ls.remove(key)
        ok = [v for v in verdicts if v.accepted]
        _log_round(progress, "train", verdicts)
        _note_implausible(verdicts, ALL_ALONG, state.refused, progress)
        if not ok and rival_sse is not None:
            ok = rescuing(verdicts, current, rival_sse(ls.y), noise, options.alpha)
            for v in ok:
                lifted = [j + 1 for j in v.improved]
                progress(f"below the margin, but it lifts joints {lifted} past {RIVAL}")
        if not ok:
            break
        best = max(ok, key=lambda v: v.score)
        if best.term.name == "position_ripple":
            best = best_ripple_neighbour(
                best, verdicts, state.effects, options,
                partial(_judge_all, ls, columns=methodcaller("columns", ctx), names=names,
                        weights=weights, current=current, noise=noise, tried=tried,
                        options=options, envelope=ctx.envelope),
            )  # fmt: skip
        term = best.term
        if term.name == "time_delay":
            state.delay_s = best.delay_s
            ls.set_y(shift_signal(data.t, data.segment, y0, state.delay_s))
            if refit_friction is not None:
                keys = refit_friction()
                state.names = [k for k in state.names if k not in friction_keys] + keys
                friction_keys = keys
                # and the delay again with that friction (it was measured against the
                # friction chosen on the unshifted torque, and biased by it)
                state.delay_s = _delay_again(ls, y0, data, state.names, weights, state.delay_s)
                best.term = term = EffectTerm(
                    "time_delay", term.joints, {"delay_s": round(state.delay_s, 6)}
                )
                ls.set_y(shift_signal(data.t, data.segment, y0, state.delay_s))
        else:
            ls.add(term.key, term.columns(ctx))
            state.names.append(term.key)
        state.effects.append(term)
        new = ls.evaluate(state.names, weights)
        state.accepted.append(
            Accepted(term, np.zeros(0), ALL_ALONG, best.improved, current.cv_rms, new.cv_rms)
        )
        progress(f"accepted (all along) {_describe(best)}")
        current = new
    # Final coefficients of the accepted linear effects from the last all-fold fit.
    sol = current.solution
    for acc in state.accepted:
        acc.coef = sol.coef.get(acc.term.key, np.zeros(0))
    state.evaluation = current
    return state


def _delay_again(
    ls: BlockLS, y0: np.ndarray, data: Prepared, names: list[str], weights: np.ndarray, near: float
) -> float:
    """The delay of least in-sample error within one scan step of ``near`` [s]."""
    error_of = _fit_error_fn(
        ls, names, weights, lambda d: shift_signal(data.t, data.segment, y0, d)
    )
    best = _search_delay(error_of, near - DELAY_STEP_S, near + DELAY_STEP_S, near, error_of(near))
    return round(best, 6) if best != near else near


def _delay_verdict(
    ls: BlockLS,
    target: Callable[[float], np.ndarray],
    names: list[str],
    weights: np.ndarray,
    current: Evaluation,
    noise: NoiseFloor,
    tried: int,
    options: Options,
) -> Verdict:
    """The delay candidate of a round: the scan and refinement of the groups ``names`` fitted
    on the targets ``target(delay)`` on ``ls`` (its targets are changed), judged as one more
    candidate at the delay it reports (rounded to 1 µs)."""
    deltas = _delays(options)
    error_of = _fit_error_fn(ls, names, weights, target)
    d_best = round(_refine(deltas, np.array([error_of(float(d)) for d in deltas]), error_of), 6)
    ls.set_y(target(d_best))
    term = EffectTerm("time_delay", tuple(range(ls.n)), {"delay_s": d_best})
    v = judge(term, current, ls.evaluate(names, weights), weights, noise, tried, options, 1)
    v.delay_s = d_best
    return v


def training_gain_fn(
    ls: BlockLS, ctx: Context, data: Prepared, names: list[str], weights: np.ndarray, delay_s: float
) -> Callable[[EffectTerm], np.ndarray]:
    """``term → relative held-out gain per joint`` of adding ``term`` to the training fit."""
    y_now = ls.y.copy()
    base = ls.evaluate(names, weights)
    y0 = shift_signal(data.t, data.segment, y_now, -delay_s) if delay_s else y_now

    def gain(term: EffectTerm) -> np.ndarray:
        if term.name == "time_delay":
            ls.set_y(shift_signal(data.t, data.segment, y0, float(term.setting["delay_s"])))
            ev = ls.evaluate(names, weights)
            ls.set_y(y_now)
        else:
            ls.add(term.key, term.columns(ctx))
            ev = ls.evaluate([*names, term.key], weights)
            ls.remove(term.key)
        return 1.0 - np.sqrt(ev.cv_sse / np.maximum(base.cv_sse, 1e-300))

    return gain


# --------------------------------------------------------------------------------------------
# Case B: appeared between training and test, on the test residual of the fixed model


@dataclass
class TestSearch:
    """Result of case (B): accepted effects with coefficients fitted on the ``fit_rows`` of
    the test data, the delay, and the prediction of the fixed model shifted by that delay plus
    the accepted effects on *all* test samples, (T, n) [N·m]; only the rows after
    ``fit_rows`` are held out."""

    accepted: list[Accepted]
    delay_s: float
    prediction: np.ndarray
    fit_rows: slice
    refused: list[dict[str, Any]] = field(default_factory=list)


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


def _rows(cols: dict[int, np.ndarray], rows: slice) -> dict[int, np.ndarray]:
    return {j: c[rows] for j, c in cols.items()}


def search_between(
    ctx: Context,
    data: Prepared,
    model_prediction: np.ndarray,
    weights: np.ndarray,
    done: Sequence[EffectTerm],
    options: Options,
    fit_rows: slice,
    progress: Progress | None = None,
    training_gain: Callable[[EffectTerm], np.ndarray] | None = None,
    sliding: np.ndarray | None = None,
    known_rms: np.ndarray | None = None,
) -> TestSearch:
    """Case (B) on the test data: ``model_prediction`` (T, n) is the fixed training model's
    torque on ``data`` (delay of case A included); ``ctx`` carries its rigid/friction parts.
    Candidates are chosen and fitted on ``fit_rows`` (a leading slice of the samples) only.

    ``training_gain(term)`` gives the relative held-out gain per joint the term brings on the
    *training* data; an accepted effect whose joints gain ``margin`` there too was present all
    along (case A turned it down for another reason) and is labelled so, although its
    parameters come from the test residual. ``sliding`` (T, n): the rows that take part
    (:func:`.preprocess.sliding_mask`), all when None. ``known_rms`` (n,): the model's
    held-out RMS on the training files, the error it is known to have (rule (v)).
    """
    progress = progress or _quiet
    refused: list[dict[str, Any]] = []
    part = data.select(np.arange(data.n_samples)[fit_rows])
    noise = NoiseFloor.of(part)
    tau = data.tau
    allow_delay = not any(t.name == "time_delay" for t in done)
    n_fit = part.n_samples
    mask = None if sliding is None else sliding[fit_rows]
    ls = BlockLS((tau - model_prediction)[fit_rows], contiguous_folds(n_fit, options.folds), mask)
    screen = ctx.rows(fit_rows)
    names: list[str] = []
    effects: list[EffectTerm] = []
    accepted: list[Accepted] = []
    delay = 0.0
    current = ls.evaluate(names, weights)
    inside, inside_share = None, 1.0
    if ctx.envelope is not None:
        inside = ~np.any(ctx.envelope.outside(data.q, data.dq), axis=1)[fit_rows]
        inside_share = float(np.mean(inside[contiguous_folds(n_fit, 2)[1]]))

    def shifted(d: float) -> np.ndarray:
        return shift_signal(data.t, data.segment, model_prediction, -d) if d else model_prediction

    while len(accepted) + len(done) < options.max_effects:
        residual = ls.y - ls.predict(current.solution) if names else ls.y
        terms = candidates(screen, residual, [*done, *effects], options)
        with_delay = allow_delay and delay == 0.0
        tried = scanned_settings(terms, options, with_delay)
        verdicts = _judge_all(
            ls, terms, lambda term: _rows(term.columns(ctx), fit_rows), names, weights, current,
            noise, tried, options, ctx.envelope,
            partial(_delay_verdict, target=lambda d: (tau - shifted(d))[fit_rows], names=names,
                    weights=weights, current=current, noise=noise, tried=tried, options=options)
            if with_delay else None,
        )  # fmt: skip
        _log_round(progress, "test", verdicts)
        _note_implausible(verdicts, BETWEEN, refused, progress)
        ok = sorted((v for v in verdicts if v.accepted), key=lambda v: -v.score)
        best = None
        for v in ok:
            y_after = (tau - shifted(v.delay_s))[fit_rows] if v.term.name == "time_delay" else None
            cols = None if y_after is not None else _rows(v.term.columns(ctx), fit_rows)
            left = np.zeros(ls.n)
            gain = forward_gain(ls, names, weights, v.term.key, cols, y_after, None, left)
            if not (
                np.all(gain[list(v.improved)] >= 0.5 * options.margin)
                and np.all(gain >= -WORSEN_TOLERANCE)
            ):
                why = (
                    "fitted on the first half of its rows, it does not hold on the second "
                    f"(held-out RMS gain {np.array2string(gain, precision=3)})"
                )
                progress(f"refused {_describe(v)}: {why}")
                refused.append(refusal(v, BETWEEN, why))
                continue
            if inside is not None:
                if inside_share < MIN_INSIDE_SHARE:
                    improved = list(v.improved)
                    level = (
                        noise.std_nm if known_rms is None else np.maximum(noise.std_nm, known_rms)
                    )
                    before = left / np.maximum(1.0 - gain, 1e-12)
                    # over the improved joints, in units of each joint's known error
                    ratio_before = float(np.sqrt(np.mean((before / level)[improved] ** 2)))
                    ratio_left = float(np.sqrt(np.mean((left / level)[improved] ** 2)))
                    repair = ratio_before >= FAILURE_FACTOR and ratio_left <= EXPLAINED_FACTOR
                    if repair:
                        progress(
                            f"{_describe(v)}: only {inside_share:.0%} of the test rows inside "
                            "the training envelope, but fitted on the first half it takes the "
                            f"second from {np.array2string(before[improved], precision=3)} to "
                            f"{np.array2string(left[improved], precision=3)} N·m, the model's "
                            "own held-out error: the effect itself"
                        )
                        best = v
                        break
                    why = (
                        f"only {inside_share:.0%} of the test rows it would be judged on are "
                        "inside the training envelope, too few to tell an effect that appeared "
                        "from the model's extrapolation (and it does not take a failure of the "
                        f"model, {np.array2string(before[improved], precision=3)} N·m, to the "
                        "model's own held-out error)"
                    )
                    progress(f"refused {_describe(v)}: {why}")
                    refused.append(refusal(v, BETWEEN, why))
                    continue
                gain = forward_gain(ls, names, weights, v.term.key, cols, y_after, inside)
                if not np.all(gain[list(v.improved)] >= 0.5 * options.margin):
                    why = (
                        "it does not hold where the training run went (held-out RMS gain "
                        f"inside the training envelope {np.array2string(gain, precision=3)}): "
                        "the model's extrapolation, not an effect that appeared"
                    )
                    progress(f"refused {_describe(v)}: {why}")
                    refused.append(refusal(v, BETWEEN, why))
                    continue
            best = v
            break
        if best is None:
            break
        term = best.term
        if term.name == "time_delay":
            delay = best.delay_s
            ls.set_y((tau - shifted(delay))[fit_rows])
        else:
            ls.add(term.key, _rows(term.columns(ctx), fit_rows))
            names.append(term.key)
        effects.append(term)
        new = ls.evaluate(names, weights)
        appeared = BETWEEN
        if training_gain is not None and best.improved:
            gain = training_gain(term)
            if np.all(gain[list(best.improved)] >= options.margin):
                appeared = ALL_ALONG
        accepted.append(
            Accepted(term, np.zeros(0), appeared, best.improved, current.cv_rms, new.cv_rms, "test")
        )
        case = appeared.replace("_", " ")
        progress(f"accepted ({case}, fitted on the first part of the test run) {_describe(best)}")
        current = new
    prediction = shifted(delay).copy()
    for acc in accepted:
        acc.coef = current.solution.coef.get(acc.term.key, np.zeros(0))
        if acc.term.is_linear:
            for j, cols in acc.term.columns(ctx).items():
                prediction[:, j] += cols @ acc.coef
    return TestSearch(accepted, delay, prediction, fit_rows, refused)


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
