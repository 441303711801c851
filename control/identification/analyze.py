"""``leadthrough analyze``: identify, validate on held-out files, close the loop, report.

Stages (each timed in ``summary.json``'s ``timing_s``; their settings and what they hand each
other: :mod:`.stages`):

1. read the ``--train`` and ``--test`` CSVs (:mod:`.datafile`);
2. preprocess each file (:mod:`.preprocess`: filtering, the position/velocity low-pass chosen
   on the training files by :mod:`.cutoff`, and the measured noise floor); take
   assist-cylinder torque out (:mod:`.fit`);
3. base regressor of the URDF on every sample (:mod:`.rigid`), filtered like the torque
   (stages 1-3: :mod:`.load`);
4. fit rigid body + friction on the training files; the eq. (14), eq. (15) and simple friction
   families are fitted and, with ``--friction auto`` (the default), the one with the lowest
   held-out (contiguous K-fold) error on the *training* files is kept — never chosen on the
   test files (:mod:`.families`);
5. effects: case (A) on the training files, then case (B) on the first part of the test run
   (:mod:`.effects`);
6. the guard (:mod:`.guard`): per joint, plain least squares (by the margin where the
   test extrapolates), the URDF's nominal rigid body with Coulomb/viscous friction, or zero
   replaces the model where its held-out error on the training files is lower, measured on
   fold schemes mixed as the test run's inputs lie relative to the training rows
   (:mod:`.folds`);
7. validate on the test files and plot (:mod:`.validate`);
8. write ``model.json``, ``summary.json`` and ``report.md`` (:mod:`.report`).

Every figure is held out. The fit, the guard and the effect search work on an analysis
target: the measured torque low-passed and decimated, every model's torque passed through the
same filter; ``rms_before``/``rms_after``/``rms_plain_ls`` are on it, per joint over the rows
where it slides. ``summary["raw"]`` has the same three figures on the raw measured torque of the
test files minus each model's prediction for every row (:mod:`.heldout`, the arithmetic of
``leadthrough predict``), against the raw noise: stuck rows and reversals included. With no
effect accepted in case (B) both cover the whole test run; with one, the rest of the test run
after the part case (B) used (:data:`TEST_FIT_FRACTION`), and ``summary["figures"]`` says so.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from control.identification import cylinders as cyl
from control.identification import effects as fx
from control.identification.assembly import Assembly
from control.identification.chain import settle as settle_chain
from control.identification.effect_rules import NoiseFloor
from control.identification.envelope import Envelope
from control.identification.families import (
    RIGID_PRIOR_RIDGE,
    _excitation_report,
    _fit_families,
    _keep_family,
    _predict,
    _settle_cylinders,
)
from control.identification.fit import FrictionFit, rechoose_options
from control.identification.folds import CONTIGUOUS, plan_folds
from control.identification.friction_law import FRICTION_MODELS
from control.identification.guard import (
    GuardFolds,
    _evaluate_on,
    _plain_prediction,
    guard_joints,
    guard_on_test,
    plain_least_squares,
)
from control.identification.heldout import per_file_rms, residuals, rms_answered, scored_rows
from control.identification.load import _load
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.model import MODEL, PLAIN_LS, PlainJoint, plain_key
from control.identification.parallel import map_forked
from control.identification.preprocess import FILTER_ORDER, sliding_mask
from control.identification.report import write_report
from control.identification.signal_shift import shift_signal
from control.identification.speed_regimes import (
    friction_coverage,
    raw_by_speed,
    scored_velocity,
)
from control.identification.stages import AUTO, AnalyzeOptions, Progress, _Clock, _Run
from control.identification.terms import Context
from control.identification.validate import (
    import_plotting,
    masked_rms,
    plot_friction,
    plot_torques,
    relative_error,
    rms,
)
from gateway.progress import ProgressBar

#: Leading share of the test run on which case (B) chooses and fits effects; the rest scores.
#: Half: the search needs enough data to see an effect, the score enough to be a figure.
TEST_FIT_FRACTION = 0.5


def _rigid(ctx: Context, beta: np.ndarray) -> np.ndarray:
    assert ctx.y_base is not None
    return np.einsum("jtb,b->tj", ctx.y_base, beta)


def _outside_share(env: Envelope, data: Any) -> dict[str, Any]:
    out = env.outside(data.q, data.dq)
    return {
        "any_joint": float(np.mean(out.any(axis=1))) if out.size else 0.0,
        "per_joint": np.mean(out, axis=0).tolist() if out.size else [],
    }


def _floats(x: np.ndarray | None) -> list[float] | None:
    return None if x is None else [float(v) for v in x]


def analyze(
    urdf_path: str | Path,
    train_paths: Sequence[str | Path],
    test_paths: Sequence[str | Path],
    out_dir: str | Path,
    options: AnalyzeOptions | None = None,
    progress: Progress | None = None,
    bar: ProgressBar | None = None,
) -> dict[str, Any]:
    """Run the whole analysis (module docstring); returns the summary written to
    ``out_dir/summary.json``. Bad files raise DataFileError, bad settings ConfigError.

    ``progress`` receives one line per step (default: print, above ``bar`` when it is drawn).
    ``bar`` (:func:`stage_bar`) advances one step at the end of each of :data:`STAGES`; it is
    updated in this process only, never in the forked workers.
    """
    # One BLAS thread: the analysis does many small dense solves (~100 columns) and products
    # over 1e4-1e5 samples; threaded, on a busy machine a thread waiting for a core turned a
    # 3 ms eigen-solve into 70 ms (the whole analysis 20x slower). One is as fast here.
    with threadpool_limits(limits=1, user_api="blas"):
        return _analyze(urdf_path, train_paths, test_paths, out_dir, options, progress, bar)


def _analyze(
    urdf_path: str | Path,
    train_paths: Sequence[str | Path],
    test_paths: Sequence[str | Path],
    out_dir: str | Path,
    options: AnalyzeOptions | None,
    progress: Progress | None,
    bar: ProgressBar | None = None,
) -> dict[str, Any]:
    options = options or AnalyzeOptions()
    say = progress or (bar.write if bar is not None else (lambda s: print(s, flush=True)))
    clock = _Clock(say, bar)
    out = Path(out_dir)
    skipped: list[str] = []
    run, ratios, options = _load(urdf_path, train_paths, test_paths, options, clock, skipped)
    assert options.torque_cutoff_hz is not None
    reg, train, test, meta = run.reg, run.train, run.test, run.meta
    ctx_train, ctx_test, urdf = run.ctx_train, run.ctx_test, str(run.urdf)

    folds = contiguous_folds(train.n_samples, options.search.folds)
    window_s = 1.0 / options.torque_cutoff_hz
    sliding_train = sliding_mask(train, options.stick_velocity_rad_s, window_s)
    sliding_test = sliding_mask(test, options.stick_velocity_rad_s, window_s)
    ls = BlockLS(train.tau, folds, sliding_train)
    beta_nominal = reg.base.base_values(reg.parameters())
    ls.set_prior("rigid", beta_nominal, RIGID_PRIOR_RIDGE)
    auto = options.friction == AUTO
    kinds = list(FRICTION_MODELS) if (auto or options.compare_friction) else [options.friction]
    # matplotlib takes half a second to import: done while the families are fitted
    prefetch = import_plotting if options.plots else None
    if run.cyl_train is not None:
        ls.add(cyl.GROUP, run.cyl_train)
    fits, comparison = _fit_families(ls, run, kinds, ratios, while_waiting=prefetch)
    kind = _keep_family(ls, fits, options.friction, clock)
    base_fit = fits[kind]
    calibration = None
    if run.cyl_train is not None:
        base_fit, calibration = _settle_cylinders(ls, run, base_fit)
        fits[kind] = base_fit
        train, test = run.train, run.test
    clock.lap("fit")

    accepted_a: list[fx.Accepted] = []
    refused: list[dict[str, Any]] = []
    delay_a = 0.0
    train_eval = base_fit.evaluation
    names = base_fit.names
    if options.find_effects:
        refit: list[FrictionFit] = []

        def refit_friction() -> list[str]:
            for term in base_fit.terms:
                ls.remove(term.key)
            clock.say("delay accepted: friction family and q_e chosen again on the shifted torque")
            again, _ = _fit_families(ls, run, kinds, ratios)
            refit.append(again[_keep_family(ls, again, options.friction, clock)])
            return [t.key for t in refit[-1].terms]

        def plain_sse(y: np.ndarray) -> np.ndarray:
            return plain_least_squares(ctx_train, y, folds, sliding_train).cv_sse

        def without_memory(names: list[str]) -> list[str]:
            """``names`` with each friction that has memory as the same law without it."""
            swap = {}
            for term in (refit[-1] if refit else base_fit).terms:
                if term.presliding_rad is not None and term.key in names:
                    plain = replace(term, presliding_rad=None)
                    swap[term.key] = f"{term.key}/sliding"
                    ls.add(swap[term.key], plain.columns(ctx_train))
            return [swap.get(k, k) for k in names]

        def rechoose(joints: Sequence[int], names: list[str]) -> list[int]:
            now = refit[-1] if refit else base_fit
            terms = list(now.terms)
            for j in joints:
                terms[j] = rechoose_options(ls, ctx_train, names, now.weights, terms[j])
            changed = [j for j in joints if terms[j] != now.terms[j]]
            if changed:
                refit.append(replace(now, terms=terms))
            return changed

        state = fx.search_all_along(
            ls, ctx_train, train, base_fit.names, base_fit.weights, options.search, clock.say,
            refit_friction, plain_sse, without_memory, rechoose,
        )  # fmt: skip
        base_fit = refit[-1] if refit else base_fit
        kind = base_fit.kind
        refused += state.refused
        assert state.evaluation is not None
        train_eval, accepted_a, delay_a, names = (
            state.evaluation, state.accepted, state.delay_s, state.names
        )  # fmt: skip
    # the measurement chain, with the effects found all along (estimated before them, it took
    # part of a spring or a delay); from here on the analysis is on the physical torque
    base_fit, chain, train_eval = settle_chain(
        ls, run, base_fit, names, options.search.alpha, clock.say
    )
    fits[kind] = base_fit
    if options.find_effects and accepted_a:
        # rule (viii): every accepted effect judged again on this final fit
        train_eval, dropped = fx.prune(
            ls, state, train_eval, base_fit.weights, NoiseFloor.of(run.train), options.search,
            ctx_train.envelope, plain_sse, clock.say,
        )  # fmt: skip
        accepted_a, names = state.accepted, state.names
        refused += dropped
    if calibration is not None:
        # the cylinders' torque in physical units too: the gain reads it as well
        calibration = calibration.over_gain(chain.gain)
        run.meta["cylinders"] = calibration.to_json()
    train, test = run.train, run.test
    accepted_a = [
        replace(a, coef=train_eval.solution.coef[a.term.key])
        if a.term.key in train_eval.solution.coef
        else a
        for a in accepted_a
    ]
    model_before, pred_before = _predict(reg, ctx_test, base_fit, urdf, meta)
    model_before = replace(
        model_before, envelope=run.envelope, torque_gain=chain.gain,
        torque_offset_nm=chain.offset_nm,
    )  # fmt: skip
    clock.lap("effects")

    # The guard: never worse than plain least squares, the URDF's nominal rigid body with
    # Coulomb/viscous friction, or zero, judged on the training files' held-out folds on the
    # same target as the model (the delay of case A included).
    plan = plan_folds(train.q, train.dq, train.rate_hz, test.q, test.dq, options.search.folds)
    schemes = [
        GuardFolds(
            sch,
            train_eval
            if sch.name == CONTIGUOUS
            else _evaluate_on(ls, names, base_fit.weights, sch.folds, sliding_train),
        )
        for sch in plan.schemes
    ]
    clock.say(f"guard folds: {plan.describe()}")
    plain_margin = options.search.margin if plan.extrapolates else 0.0
    guard = guard_joints(reg, ctx_train, ls.y, sliding_train, schemes, options, plain_margin)
    plain = {j: g.fallback for j, g in guard.items() if g.fallback is not None}
    for j, g in guard.items():
        if g.fallback is not None:
            clock.say(f"joint {j + 1}: {g.reason}")
    plain_ref = plain_least_squares(ctx_train, train.tau, folds, sliding_train)
    parts = Assembly(
        reg, base_fit, train_eval.solution, urdf, meta, run.envelope, chain,
        plain_ref.solution.coef, accepted_a,
    )  # fmt: skip
    pred_a = parts.model(plain, between=False).torque_from_context(ctx_test)
    if delay_a:
        pred_a = shift_signal(test.t, test.segment, pred_a, -delay_a)
    pred_plain = _plain_prediction(ctx_test, plain_ref.solution.coef)

    split = round(TEST_FIT_FRACTION * test.n_samples)
    fit_rows = slice(0, split)
    accepted_b: list[fx.Accepted] = []
    pred_after = pred_a
    # what the effects that appeared between the runs add to every joint they act on, whatever
    # predicts the rest of its torque: they were fitted on the residual of ``pred_a``, plain
    # joints' own prediction included, and a tool mounted weighs on those joints too
    between_torque = np.zeros_like(pred_a)
    if options.find_effects:
        gain = fx.training_gain_fn(ls, ctx_train, train, names, base_fit.weights, delay_a)
        done = [a.term for a in accepted_a]
        between = fx.search_between(
            ctx_test, test, pred_a, base_fit.weights, done, options.search, fit_rows,
            clock.say, gain, sliding_test, train_eval.cv_rms,
        )  # fmt: skip
        accepted_b = between.accepted
        pred_after = between.prediction
        between_torque = between.effects_torque
        refused += between.refused
    accepted = [*accepted_a, *accepted_b]
    # The guard's second look: on the leading test rows, what extrapolates worse than plain
    # least squares or zero is replaced there too (the figures are then those of the rest).
    # Judged on the raw torque of every row there, as every figure is (.heldout): three whole
    # models, each with the effects that appeared between the runs.
    kinds_now = [MODEL if j not in plain else plain[j].kind for j in range(reg.n)]
    parts = replace(parts, between=accepted_b)
    lead = [~r for r in scored_rows(run.test_files, test.t, split)]
    candidates = parts.second_look(plain)
    names_lead = list(candidates)
    lead_errors = map_forked(
        lambda i: residuals(candidates[names_lead[i]], run.test_files, lead, run.desc),
        range(len(names_lead)),
    )
    second = guard_on_test(dict(zip(names_lead, lead_errors, strict=True)), (0, split), kinds_now)
    switched = []
    if second is not None:
        pred_after = pred_after.copy()
        for j, (was, now) in enumerate(zip(kinds_now, second.kept, strict=True)):
            if now == was:
                continue
            switched.append(j)
            plain[j] = parts.fallback(j, now)
            base = pred_plain[:, j] if now == PLAIN_LS else 0.0
            pred_after[:, j] = base + between_torque[:, j]
            r = second.rms[j]
            clock.say(
                f"joint {j + 1}: on the raw rows of the first {split} test samples "
                f"{was.replace('_', ' ')} ({r[was]:.4g} N·m) predicts worse than "
                f"{now.replace('_', ' ')} ({r[now]:.4g} N·m): {now} kept"
            )
    # case (B)'s effects stay on a plain joint, added to its own prediction (.assembly)
    model = parts.model(plain)
    scored = slice(split, test.n_samples) if accepted_b or switched else slice(0, test.n_samples)
    on = sliding_test[scored]
    # figures in the torque channel's units: a physical residual r reads k r (.chain)
    k = chain.gain
    rms_before = masked_rms(k * (test.tau - pred_before)[scored], on)
    rms_after = masked_rms(k * (test.tau - pred_after)[scored], on)
    rms_plain = masked_rms(k * (test.tau - pred_plain)[scored], on)
    rms_after_all = rms(k * (test.tau - pred_after)[scored])
    # the same on the raw measured torque: each model's prediction for every row (.heldout)
    plain_model = replace(
        model_before,
        plain_joints={
            j: PlainJoint.from_coef(j, plain_ref.solution.coef[plain_key(j)], PLAIN_LS)
            for j in range(reg.n)
        },
    )
    rows = scored_rows(run.test_files, test.t, scored.start)
    # three independent predictions of every raw test row, side by side (.parallel)
    three = (model_before, model, plain_model)
    errors = map_forked(lambda i: residuals(three[i], run.test_files, rows, run.desc), range(3))
    (raw_before, raw_after, raw_plain), answered = rms_answered(errors)
    named = dict(zip(("rms_before", "rms_after", "rms_plain_ls"), errors, strict=True))
    by_speed = raw_by_speed(
        named,
        scored_velocity([f.measurements for f in run.test_files], rows),
        answered,
        options.stick_velocity_rad_s,
    )
    by_file = per_file_rms(run.test_files, rows, named, answered)
    if options.find_effects and not accepted:
        clock.say("no further effect found")
    clock.say(f"held-out RMS before effects: {np.array2string(rms_before, precision=3)} N·m")
    clock.say(f"held-out RMS after effects:  {np.array2string(rms_after, precision=3)} N·m")
    clock.say(f"held-out RMS plain LS:       {np.array2string(rms_plain, precision=3)} N·m")
    clock.say(
        f"on the raw torque, every row: before {np.array2string(raw_before, precision=3)}, "
        f"after {np.array2string(raw_after, precision=3)}, plain LS "
        f"{np.array2string(raw_plain, precision=3)} N·m (raw noise "
        f"{np.array2string(np.asarray(test.raw_noise_nm), precision=3)})"
    )
    clock.lap("effects")

    out.mkdir(parents=True, exist_ok=True)
    plots = _plots(out, options, run, fits, base_fit, pred_before, pred_after, bool(accepted))
    clock.lap("validate")

    # What the control's rest hold (control/rt/src/law/rest_hold.rs) sizes its band by: the
    # held-out error where the joint slides, or over every row where it never did.
    model.metadata["heldout_rms_nm"] = [
        float(a if np.isfinite(a) else b) for a, b in zip(rms_after, rms_after_all, strict=True)
    ]
    model.save(out / "model.json")
    where = (
        f"test rows {scored.start}..{scored.stop - 1} of {test.n_samples}: the rest of the test "
        f"run after the first {split} rows used by case (B) and the guard"
        if scored.start
        else f"all {test.n_samples} test rows"
    )
    raw_where = (
        f"raw rows of the test files from t = {test.t[scored.start]:.6g} s of the file case (B) "
        "used the start of"
        if scored.start
        else "every raw row of the test files"
    ) + f" that the models answer ({int(answered.sum())} of {answered.size})"
    if options.stick_velocity_rad_s > 0:
        where += (
            f", per joint those where it slides (faster than {options.stick_velocity_rad_s} "
            f"rad/s, and {window_s:.3g} s from being stuck: share in sliding_share_scored); "
            "rms_after_all_samples has every row"
        )
    summary: dict[str, Any] = {
        "joints": list(reg.joint_names),
        "friction_model": kind,
        "friction_chosen_by": (
            "held-out (contiguous K-fold) error on the training files" if auto else "--friction"
        ),
        "rms_before": rms_before.tolist(),
        "rms_after": rms_after.tolist(),
        "cutoff_hz": {
            "position": options.position_cutoff_hz,
            "torque": options.torque_cutoff_hz,
            "choice": meta["cutoff_choice"],
        },
        "rms_after_all_samples": rms_after_all.tolist(),
        "raw": {
            "rms_before": raw_before.tolist(),
            "rms_after": raw_after.tolist(),
            "rms_plain_ls": raw_plain.tolist(),
            "noise_std_nm": _floats(test.raw_noise_nm),
            "rows_scored": int(answered.sum()),
            "rows_declined": int(answered.size - answered.sum()),
            "by_speed": by_speed,
            "per_file": by_file,
            "scored": f"{raw_where}: raw measured torque minus each model's prediction "
            "(heldout.py, the arithmetic of `leadthrough predict`), no filter, stuck rows and "
            "reversals included",
        },
        "sliding_share_scored": on.mean(axis=0).tolist(),
        "friction_measured_over": friction_coverage(
            train.dq, sliding_train, options.stick_velocity_rad_s
        ),
        "stick_velocity_rad_s": options.stick_velocity_rad_s,
        "rms_plain_ls": rms_plain.tolist(),
        "after_le_plain_ls": (rms_after <= rms_plain * (1 + 1e-9)).tolist(),
        "plain_ls_joints": sorted(j + 1 for j, pj in plain.items() if pj.kind == PLAIN_LS),
        "fallback_joints": {str(j + 1): pj.kind for j, pj in sorted(plain.items())},
        "guard": {
            "rule": "per joint, the model is replaced where its held-out error on the training "
            "files (folds: see 'folds') is worse than plain least squares (by the margin where "
            "the test lies farther from the training rows than the folds from their fits: it "
            "extrapolates without shared physics), the URDF's nominal rigid body + "
            "Coulomb/viscous friction, or zero; the lowest of those is kept",
            "folds": plan.to_json(),
            "heldout_rms_train_means": "sqrt of the schemes' held-out mean squared errors "
            "mixed in their shares (in-sample ones × the GCV factor)",
            "plain_margin": plain_margin,
            "joints": [guard[j].to_json() for j in range(reg.n)],
            "test_lead": None if second is None else second.to_json(),
            "test_lead_rule": "then, on the first test rows (those case (B) searched), each "
            "joint keeps the lowest held-out error of what the training guard kept, plain "
            "least squares and zero; where that changes a joint, the figures are scored on "
            "the rest of the test run",
        },
        "relative_before": relative_error(test.tau[scored], pred_before[scored]).tolist(),
        "relative_after": relative_error(test.tau[scored], pred_after[scored]).tolist(),
        "rms_train": (k * train_eval.fit_rms).tolist(),
        "rms_train_cv": (k * train_eval.cv_rms).tolist(),
        "rms_train_cv_plain_ls": [guard[j].cv_rms[PLAIN_LS] for j in range(reg.n)],
        "rms_train_before": (k * base_fit.evaluation.fit_rms).tolist(),
        "rms_measured_test": rms(chain.to_measured(test.tau[scored])).tolist(),
        "noise_floor_nm": {"train": _floats(train.noise_nm), "test": _floats(test.noise_nm)},
        "raw_noise_std_nm": {
            "train": _floats(train.raw_noise_nm),
            "test": _floats(test.raw_noise_nm),
        },
        "figures": {
            "rms_before": f"{where}; rigid body + friction family fitted on the training files",
            "rms_after": f"{where}; the final model (effects, plain joints)",
            "rms_plain_ls": f"{where}; plain least squares per joint fitted on the training "
            "files (model.plain_columns)",
            "raw": "the same three on the raw measured torque, every row (raw.scored)",
            "rms_train_cv": "training files, held out by contiguous K-fold cross-validation",
            "rms_train": "training files, in-sample (for reference only)",
            "noise_floor_nm": "std of the measured noise left in the filtered torque",
            "target": "measured torque low-passed at the torque cutoff; every model's torque "
            "through the same filter and the measurement chain (gain * tau + offset, "
            "measurement_chain)",
            "effects": "case (A) fitted on the training files; case (B) chosen and fitted on "
            f"the first {split} test rows",
        },
        "test_rows_scored": [scored.start, scored.stop],
        "test_time_scored_s": [float(test.t[scored.start]), float(test.t[scored.stop - 1])],
        "target_filter": {
            "kind": "Butterworth, zero-phase (forward and backward)",
            "order": FILTER_ORDER,
            "cutoff_hz": sorted({float(v) for v in np.unique(np.asarray(test.filter_hz))}),
        },
        "training_envelope": run.envelope.to_json(),
        "test_outside_envelope": _outside_share(run.envelope, test),
        "effects": [
            {
                "name": a.term.name,
                "joints": [j + 1 for j in a.term.joints],
                "parameters": a.term.parameters(a.coef),
                "appeared": a.appeared,
                "estimated_on": a.estimated_on,
                "improved_joints": [j + 1 for j in a.improved_joints],
                "heldout_rms_before": a.rms_before.tolist(),
                "heldout_rms_after": a.rms_after.tolist(),
            }
            for a in accepted
        ],
        "refused_effects": refused,
        "friction_comparison": comparison,
        "base_parameters": reg.base.n_base,
        "base_parameter_excitation": _excitation_report(reg, ls, base_fit, train_eval),
        "n_samples": {"train": train.n_samples, "test": test.n_samples},
        "rate_hz": train.rate_hz,
        "cylinders_removed": meta["cylinders_removed"],
        "measurement_chain": chain.to_json(),
        "cylinders": None if calibration is None else calibration.to_json(),
        "files": {
            "urdf": urdf,
            "train": [str(p) for p in train_paths],
            "test": [str(p) for p in test_paths],
        },
        "plots": plots,
        "model_file": "model.json",
        "effects_searched": options.find_effects,
        "files_left_out": skipped,
        "margin": options.search.margin,
        "alpha": options.search.alpha,
    }
    clock.lap("report")
    summary["timing_s"] = dict(clock.timing, total=round(time.perf_counter() - clock.start, 3))
    write_report(out, summary)
    clock.say(f"wrote {out / 'model.json'}, {out / 'summary.json'}, {out / 'report.md'}")
    return summary


def _plots(
    out: Path,
    options: AnalyzeOptions,
    run: _Run,
    fits: dict[str, FrictionFit],
    base_fit: FrictionFit,
    pred_before: np.ndarray,
    pred_after: np.ndarray,
    any_effect: bool,
) -> list[str]:
    if not options.plots:
        return []
    test, train, ctx_train = run.test, run.train, run.ctx_train
    curves = {"model before effects": pred_before}
    if any_effect:
        curves["model after effects"] = pred_after
    plots = [
        plot_torques(
            out / "torque_test.png",
            test.tau,
            curves,
            run.reg.joint_names,
            test.rate_hz,
            "Held-out test files: measured vs model torque",
        ).name
    ]
    # Each family's fit has its own β; plot each as what it predicts for τ - τ_rigid of the
    # kept model, so measured and model points share one reference.
    rigid_ref = _rigid(ctx_train, base_fit.evaluation.solution.coef["rigid"])
    friction_curves = {}
    for kind, fit in fits.items():
        sol = fit.evaluation.solution
        fr = _rigid(ctx_train, sol.coef["rigid"]) - rigid_ref
        for term in fit.terms:
            fr[:, term.joint] += term.columns(ctx_train)[term.joint] @ sol.coef[term.key]
        friction_curves[kind] = fr
    plots.append(
        plot_friction(
            out / "friction_train.png",
            train.dq,
            train.tau - rigid_ref,
            friction_curves,
            run.reg.joint_names,
        ).name
    )
    return plots
