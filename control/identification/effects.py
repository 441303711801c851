"""Closing the loop: find structure in the residual, name the physical effect, add it, refit.

Candidates come from the effect vocabulary of :mod:`.terms`; those with a scanned setting are
pre-screened on the current residual (:mod:`.effect_candidates`).

Greedy forward selection, one effect per round, until a round accepts nothing (or
:data:`.effect_rules.MAX_EFFECTS`). Every candidate is judged on **held-out** data,
trajectory-wise: contiguous blocks, never random samples (samples 5 ms apart are anything but
independent):

(A) *All along* (the effect is in the training data): refit rigid + friction + accepted +
    candidate on the training files; the criterion is K-fold cross-validation over contiguous
    blocks of the training data. Accepted effects are then judged on the test files by the
    caller (``rms_after`` there is a plain held-out number).
(B) *Between training and test* (e.g. a spray gun mounted after the identification run): the
    training model is kept fixed and the candidate's parameters are fitted to the test
    residual of the *first part* of the test run only (``fit_rows``; the search itself
    cross-validates over contiguous blocks of that part); the caller scores the result on the
    rest of the test run, which neither the choice nor the fit has seen. Runs after (A).

A candidate is accepted only by the rules (i)-(vii) of :mod:`.effect_rules`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from operator import methodcaller
from typing import Any

import numpy as np

from control.identification.effect_candidates import (
    _delay_again,
    _delay_verdict,
    best_ripple_neighbour,
    candidates,
    scanned_settings,
)
from control.identification.effect_rules import (
    EXPLAINED_FACTOR,
    FAILURE_FACTOR,
    MIN_INSIDE_SHARE,
    RIVAL,
    WORSEN_TOLERANCE,
    NoiseFloor,
    Options,
    Progress,
    Verdict,
    _describe,
    _log_round,
    _note_implausible,
    _quiet,
    forward_gain,
    judge,
    refusal,
    rescuing,
)
from control.identification.envelope import Envelope
from control.identification.lsq import BlockLS, Evaluation, Solution, contiguous_folds
from control.identification.parallel import map_forked
from control.identification.preprocess import Prepared
from control.identification.signal_shift import shift_signal
from control.identification.terms import Context, EffectTerm

ALL_ALONG = "all_along"
BETWEEN = "between_train_and_test"


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
class SearchState:
    """Where the greedy search stands on one data set."""

    names: list[str]
    effects: list[EffectTerm] = field(default_factory=list)
    delay_s: float = 0.0
    accepted: list[Accepted] = field(default_factory=list)
    evaluation: Evaluation | None = None
    #: candidates that passed rules (i)-(iii) but were refused, with why (:func:`refusal`)
    refused: list[dict[str, Any]] = field(default_factory=list)


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
    moved_mean: bool = False,
) -> list[Verdict]:
    """The verdict on each candidate of a round (``columns(term)`` added to the fit of
    ``names`` on ``ls``), then the delay's (``delay(fork of ls)``) if asked: each on a fork
    of ``ls`` (left as it was), side by side in worker processes (:mod:`.parallel`), the
    delay's scan first (it costs a dozen fits). ``moved_mean`` (case B): a candidate is also
    judged against a moved mean torque on its joints (:func:`_only_a_moved_mean`)."""

    def one(i: int) -> Verdict:
        own = ls.fork()
        if i < 0:
            assert delay is not None
            return delay(own)
        term = terms[i]
        cols = columns(term)
        own.add(term.key, cols)
        new = own.evaluate([*names, term.key], weights)
        verdict = judge(term, current, new, weights, noise, tried, options, 0, envelope)
        if moved_mean and verdict.accepted:
            why = _only_a_moved_mean(own, term, cols, names, weights, noise, tried, options)
            if why:
                verdict = replace(verdict, accepted=False, implausible=why)
        return verdict

    order = ([-1] if delay is not None else []) + list(range(len(terms)))
    done = dict(zip(order, map_forked(one, order), strict=True))
    return [done[i] for i in sorted(order, key=lambda i: (i < 0, i))]


def _only_a_moved_mean(
    ls: BlockLS,
    term: EffectTerm,
    cols: dict[int, np.ndarray],
    names: Sequence[str],
    weights: np.ndarray,
    noise: NoiseFloor,
    tried: int,
    options: Options,
) -> str:
    """Why a candidate of case B is refused as a change of its joints' mean torque ("" if it
    is not): fitted where the model is fixed, its columns may take any change of a joint's
    mean torque between the runs (the model's extrapolation where the test run leaves the
    training envelope, a sensor's zero), so it must pass rules (i) and (ii) against a constant
    per joint it acts on, with that constant beside it. A spring's own constant is that
    constant, and what is judged is its slope: a moved mean torque gave "springs" of a few
    thousandths of the joint's noise per radian, and "couplings" of a few thousandths.
    ``ls`` holds the candidate's columns under ``term.key``."""
    key = f"{term.key}:mean"
    ls.add(key, {j: np.ones((c.shape[0], 1)) for j, c in cols.items()})
    mean = ls.evaluate([*names, key], weights)
    both = ls.evaluate([*names, key, term.key], weights)
    beyond = judge(term, mean, both, weights, noise, tried, options)
    if beyond.accepted:
        return ""
    js = list(term.joints) if len(term.joints) == 1 else list(cols)
    return (
        "it is not told from a moved mean torque (held-out RMS "
        f"{np.array2string(-beyond.rel[js], precision=3)} against a constant alone, held-out "
        f"drop {beyond.chi2:.3g} noise dof, threshold {beyond.chi2_threshold:.3g})"
    )


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
    rechoose: Callable[[Sequence[int], list[str]], list[int]] | None = None,
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
    still take one below the margin (rule (vi) of :mod:`.effect_rules`).

    ``sliding(names)``: the groups ``names`` with every friction that has memory
    (:class:`.terms.FrictionTerm`) replaced by the same law without it, added to ``ls``. The
    delay is judged against those: a friction with memory turns round late at a reversal, as
    a torque measured late does, and fitted first it takes the friction's share of a delay and
    leaves the rest below the margin (a 7 ms delay found at +56 % without memory, refused at
    +31 % with it). Once a delay is accepted, ``refit_friction`` chooses the friction, memory
    included, again on the shifted torque.

    ``rechoose(joints, names)``: the friction options (memory, Gaussian Stribeck rise) of
    ``joints`` chosen again on ``ls`` with the groups ``names``
    (:func:`.fit.rechoose_options`); it returns the joints whose options changed. It is
    called on the joints an accepted effect improved: the options were chosen on a residual
    that still held that effect.
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
            if rechoose is not None:
                changed = rechoose(best.improved, state.names)
                if changed:
                    progress(
                        f"friction options of joints {[j + 1 for j in changed]} chosen again "
                        f"with {term.name} in the model"
                    )
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


def prune(
    ls: BlockLS,
    state: SearchState,
    current: Evaluation,
    weights: np.ndarray,
    noise: NoiseFloor,
    options: Options,
    envelope: Envelope | None,
    rival_sse: Callable[[np.ndarray], np.ndarray] | None,
    progress: Progress = _quiet,
) -> tuple[Evaluation, list[dict[str, Any]]]:
    """Rule (viii), the backward look on the final fit (``ls`` with ``state.names``, whose
    evaluation is ``current``): each accepted effect is judged again by rules (i)-(iii), (vi)
    and (vii) against the final model without it, as if it were the last candidate (one setting
    tried: the test is no stricter than the one it passed). The weakest that fails is dropped
    from ``ls`` and ``state``, and the rest judged again, until all pass. The delay is not
    judged again (the friction was chosen again on the shifted torque). Returns the evaluation
    of what stays and the refusals of what was dropped.

    Why: an effect is accepted against the model of its round, and the final model is not that
    one. The measurement chain's offsets are estimated after the search (estimated before it,
    they took part of a spring or a delay), and until then any term with a near-constant
    column can stand in for a joint's offset: a gear ripple of 5 cycles per revolution took
    11 % of a joint's held-out RMS when accepted and 0.001 N·m once the chain had the offset.
    Named, it would be false; so would one that a later effect made redundant."""
    dropped: list[dict[str, Any]] = []
    # the target does not change here, nor does the rival's error on it
    rival = None if rival_sse is None else rival_sse(ls.y)
    while True:
        weakest = None
        for acc in state.accepted:
            term = acc.term
            if not term.is_linear:  # the delay: no columns to take out
                continue
            without = ls.evaluate([n for n in state.names if n != term.key], weights)
            v = judge(term, without, current, weights, noise, 1, options, 0, envelope)
            if v.accepted:
                continue
            if rival is not None and rescuing([v], without, rival, noise, options.alpha):
                continue
            strength = v.chi2 / max(v.chi2_threshold, 1e-300)
            if weakest is None or strength < weakest[0]:
                weakest = (strength, acc, v, without)
        if weakest is None:
            return current, dropped
        _, acc, v, without = weakest
        ls.remove(acc.term.key)
        state.names.remove(acc.term.key)
        state.effects = [e for e in state.effects if e is not acc.term]
        state.accepted = [a for a in state.accepted if a is not acc]
        dropped.append(refusal(v, ALL_ALONG, "redundant in the final model (rule viii)"))
        progress(f"dropped on the final fit {_describe(v)}")
        current = without


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
    ``fit_rows`` are held out. ``effects_torque`` (T, n) [N·m] is the accepted linear effects'
    torque alone: what a joint carries whatever predicts the rest of its torque (a tool
    mounted between the runs weighs on a joint kept on plain least squares too)."""

    accepted: list[Accepted]
    delay_s: float
    prediction: np.ndarray
    fit_rows: slice
    effects_torque: np.ndarray
    refused: list[dict[str, Any]] = field(default_factory=list)


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
        terms = candidates(screen, residual, [*done, *effects], options, session="test")
        with_delay = allow_delay and delay == 0.0
        tried = scanned_settings(terms, options, with_delay)
        verdicts = _judge_all(
            ls, terms, lambda term: _rows(term.columns(ctx), fit_rows), names, weights, current,
            noise, tried, options, ctx.envelope,
            partial(_delay_verdict, target=lambda d: (tau - shifted(d))[fit_rows], names=names,
                    weights=weights, current=current, noise=noise, tried=tried, options=options)
            if with_delay else None,
            moved_mean=True,
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
    effects_torque = np.zeros_like(model_prediction)
    for acc in accepted:
        acc.coef = current.solution.coef.get(acc.term.key, np.zeros(0))
        if acc.term.is_linear:
            for j, cols in acc.term.columns(ctx).items():
                effects_torque[:, j] += cols @ acc.coef
    prediction = shifted(delay) + effects_torque
    return TestSearch(accepted, delay, prediction, fit_rows, effects_torque, refused)
