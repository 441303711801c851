"""The candidates of the effect search (:mod:`.effects`) and the scan of their settings.

Candidates come from the effect vocabulary of :mod:`.terms`. Effects with a scanned setting
are pre-screened on the current residual, cheaply, and only the best settings are refitted:

- ``position_ripple``: periodogram of joint j's residual against q_j: for every c in
  :data:`.effect_rules.RIPPLE_CYCLES` the drop in residual sum of squares by a LS fit of
  ``sin(c q_j)``, ``cos(c q_j)``; the :data:`RIPPLE_PEAKS` highest local peaks go on;
- ``time_delay``: the refit error over shifts δ in ±:data:`.effect_rules.DELAY_MAX_S`, step
  :data:`.effect_rules.DELAY_STEP_S`, refined by a bounded scalar search around the best
  (:data:`DELAY_TOLERANCE_S`).

A ripple the rules accept is then walked to the adjacent cycle count the refit scores higher
(:func:`best_ripple_neighbour`); :func:`scanned_settings` counts the settings scanned, for the
Bonferroni count of rule (ii) (:mod:`.effect_rules`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from control.identification.effect_rules import (
    DELAY_STEP_S,
    NoiseFloor,
    Options,
    Verdict,
    judge,
)
from control.identification.lsq import BlockLS, Evaluation
from control.identification.preprocess import Prepared
from control.identification.signal_shift import shift_signal
from control.identification.terms import Context, EffectTerm

RIPPLE_PEAKS = 2
#: The delay is refined to this [s] (a tenth of a sample at 1 kHz).
DELAY_TOLERANCE_S = 1e-5
#: Joints of the wrist, which may couple: those after the arm's first three at most three.
WRIST_JOINTS = 3


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
    ctx: Context,
    residual: np.ndarray,
    done: Sequence[EffectTerm],
    options: Options,
    session: str | None = None,
) -> list[EffectTerm]:
    """Linear candidate effects on this data (module docstring), minus those already taken.

    ``session`` (case B: "test") makes a thermal drift that session's own (its setting): a
    drift is not the robot's but the session's, and one the training files took (fitted over
    their time, e.g. a viscous friction warming up) says nothing of how the test run drifts, so
    it does not stand in for a drift there. Every other effect taken is the robot's."""
    n = residual.shape[1]
    taken = {_taken_key(t) for t in done if t.name != "position_ripple"}
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
            drift = {} if session is None else {"session": session}
            out.append(EffectTerm("thermal_drift", (j,), drift))
    if ctx.y_payload is not None:
        out.append(EffectTerm("payload", tuple(range(n))))
    if ctx.rigid is not None and ctx.friction is not None and n >= 2:
        wrist = range(wrist_start(n), n)
        for j in wrist:
            for k in wrist:
                if k != j:
                    for source in ("torque", "friction"):
                        out.append(
                            EffectTerm("wrist_coupling", (j,), {"from_joint": k, "source": source})
                        )
    return [t for t in out if _taken_key(t) not in taken or t.name == "position_ripple"]


def wrist_start(n: int) -> int:
    """The first joint (0-based) of an ``n``-joint arm's wrist: after the first three joints,
    which place the wrist (base, shoulder, elbow: each on its own motor and gear train), at most
    the last :data:`WRIST_JOINTS`; at least the last two of a shorter arm."""
    return max(n - WRIST_JOINTS, min(3, n - 2), 0)


def _taken_key(t: EffectTerm) -> tuple[str, tuple[int, ...], Any]:
    """What makes two candidates the same effect: name and joints, and a drift's session."""
    return t.name, t.joints, t.setting.get("session") if t.name == "thermal_drift" else None


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


# --------------------------------------------------------------------------------------------
# The delay: the refit error over the scanned shifts, refined


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
