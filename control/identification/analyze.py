"""``leadthrough analyze``: identify, validate on held-out files, close the loop, report.

Stages (each timed in ``summary.json``'s ``timing_s``):

1. read the ``--train`` and ``--test`` CSVs (:mod:`.datafile`);
2. preprocess each file (:mod:`.preprocess`); take assist-cylinder torque out (:mod:`.fit`);
3. base regressor of the URDF on every sample (:mod:`.rigid`);
4. fit rigid body + friction on the training files; the eq. (14), eq. (15) and simple friction
   families are all fitted so the report can compare them (Fig. 7 of the paper), the one of
   ``--friction`` is kept;
5. effects: case (A) on the training files, then case (B) on the test residual
   (:mod:`.effects`);
6. validate on the test files and plot (:mod:`.validate`);
7. write ``model.json``, ``summary.json`` and ``report.md`` (:mod:`.report`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from control.identification import effects as fx
from control.identification._blas import single_threaded_blas
from control.identification.datafile import Measurements, read_measurements
from control.identification.fit import (
    FrictionFit,
    IdentifiedModel,
    fit_rigid_friction,
    make_context,
    model_from_solution,
    remove_cylinders,
)
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.preprocess import (
    DEFAULT_POSITION_CUTOFF_HZ,
    DEFAULT_RATE_HZ,
    DEFAULT_TORQUE_CUTOFF_HZ,
    Prepared,
    TooShortError,
    concatenate,
    prepare,
)
from control.identification.report import write_report
from control.identification.rigid import DEFAULT_GRAVITY_M_S2, RobotRegressor
from control.identification.terms import FRICTION_MODELS, Context, shift_signal
from control.identification.validate import plot_friction, plot_torques, relative_error, rms
from control.robot.description import RobotDescription, load_description
from gateway.errors import ConfigError, DataFileError

Progress = Callable[[str], None]


@dataclass(frozen=True)
class AnalyzeOptions:
    """Settings of one analysis; every field has its command-line option in :mod:`.cli`."""

    friction: str = "eq15"
    rate_hz: float = DEFAULT_RATE_HZ
    position_cutoff_hz: float = DEFAULT_POSITION_CUTOFF_HZ
    torque_cutoff_hz: float = DEFAULT_TORQUE_CUTOFF_HZ
    drive_gains: tuple[float, ...] | None = None
    gear_ratios: tuple[float, ...] | None = None
    description_path: Path | None = None
    gravity_m_s2: tuple[float, float, float] = DEFAULT_GRAVITY_M_S2
    find_effects: bool = True
    #: leave out (and report) a file with no stretch long enough to filter instead of failing;
    #: `identify` sets it: cycles disturbed by holds can chop a short segment to pieces
    skip_short_files: bool = False
    compare_friction: bool = True
    plots: bool = True
    search: fx.Options = field(default_factory=fx.Options)

    def __post_init__(self) -> None:
        if self.friction not in FRICTION_MODELS:
            raise ConfigError(
                f"--friction: {self.friction!r} is not one of {list(FRICTION_MODELS)}"
            )
        if not 0 < self.search.margin < 1:
            raise ConfigError(f"--margin: {self.search.margin!r} must be in (0, 1)")
        if self.search.folds < 2:
            raise ConfigError(f"--folds: {self.search.folds!r} must be >= 2")


class _Clock:
    def __init__(self, progress: Progress) -> None:
        self.start = time.perf_counter()
        self.last = self.start
        self.timing: dict[str, float] = {}
        self.progress = progress

    def say(self, message: str) -> None:
        self.progress(f"[{time.perf_counter() - self.start:7.1f} s] {message}")

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.timing[stage] = round(self.timing.get(stage, 0.0) + now - self.last, 3)
        self.last = now


def _read(
    paths: Sequence[Path], options: AnalyzeOptions, n: int, urdf: Path, clock: _Clock
) -> list[Measurements]:
    out = []
    for path in paths:
        m = read_measurements(path, options.drive_gains)
        if m.n_joints != n:
            raise DataFileError(
                f"{path}:1: has {m.n_joints} joints (q1..q{m.n_joints}), URDF {urdf} has {n}"
            )
        clock.say(f"read {path}: {m.n_samples} samples, {m.t[-1] - m.t[0]:.1f} s")
        out.append(m)
    return out


def _description(options: AnalyzeOptions, needed: bool) -> RobotDescription | None:
    if options.description_path is not None:
        return load_description(options.description_path)
    try:
        return load_description()
    except ConfigError:
        if needed:
            raise
        return None


def _gear_ratios(
    options: AnalyzeOptions, reg: RobotRegressor, desc: RobotDescription | None, clock: _Clock
) -> np.ndarray:
    if options.gear_ratios is not None:
        ratios = np.asarray(options.gear_ratios, dtype=float)
        if ratios.shape != (reg.n,) or not np.all(ratios > 0):
            raise ConfigError(
                f"--gear-ratios: need {reg.n} values > 0, got {list(options.gear_ratios)}"
            )
        return ratios
    if desc is not None and desc.joint_names == reg.joint_names:
        return desc.gear_ratios
    if options.friction == "eq15":
        clock.say(
            "no gear ratios known (--gear-ratios): eq. (15) uses R = 1 (its q/R terms then "
            "repeat sin q, cos q and drop out)"
        )
    return np.ones(reg.n)


def _prepare(
    ms: Sequence[Measurements], options: AnalyzeOptions, clock: _Clock, skipped: list[str]
) -> Prepared:
    parts = []
    for m in ms:
        try:
            parts.append(
                prepare(m, options.rate_hz, options.position_cutoff_hz, options.torque_cutoff_hz)
            )
        except TooShortError as exc:
            if not options.skip_short_files:
                raise
            clock.say(f"left out: {exc}")
            skipped.append(str(exc))
    if not parts:
        raise DataFileError(f"no usable file among {[m.source for m in ms]}: {skipped[-1]}")
    return concatenate(parts)


def _rigid(ctx: Context, beta: np.ndarray) -> np.ndarray:
    assert ctx.y_base is not None
    return np.einsum("jtb,b->tj", ctx.y_base, beta)


def _predict(
    reg: RobotRegressor, ctx: Context, fit: FrictionFit, urdf: str, meta: dict[str, Any]
) -> tuple[IdentifiedModel, np.ndarray]:
    model = model_from_solution(reg, fit, fit.evaluation.solution, [], urdf, meta)
    return model, model.torque_from_context(ctx)


def analyze(
    urdf_path: str | Path,
    train_paths: Sequence[str | Path],
    test_paths: Sequence[str | Path],
    out_dir: str | Path,
    options: AnalyzeOptions | None = None,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Run the whole analysis (module docstring); returns the summary written to
    ``out_dir/summary.json``. Bad files raise DataFileError, bad settings ConfigError.

    ``progress`` receives one line per step (default: print).
    """
    with single_threaded_blas():
        return _analyze(urdf_path, train_paths, test_paths, out_dir, options, progress)


def _analyze(
    urdf_path: str | Path,
    train_paths: Sequence[str | Path],
    test_paths: Sequence[str | Path],
    out_dir: str | Path,
    options: AnalyzeOptions | None,
    progress: Progress | None,
) -> dict[str, Any]:
    options = options or AnalyzeOptions()
    clock = _Clock(progress or (lambda s: print(s, flush=True)))
    urdf = Path(urdf_path)
    out = Path(out_dir)
    if not train_paths or not test_paths:
        raise ConfigError("need at least one --train and one --test file")
    try:
        urdf_xml = urdf.read_text()
    except OSError as exc:
        raise ConfigError(f"--urdf {urdf}: cannot read: {exc.strerror or exc}") from None
    reg = RobotRegressor(urdf_xml, options.gravity_m_s2)
    clock.say(
        f"URDF {urdf}: {reg.n} joints {list(reg.joint_names)}, {reg.base.n_base} base parameters"
    )
    train_m = _read([Path(p) for p in train_paths], options, reg.n, urdf, clock)
    test_m = _read([Path(p) for p in test_paths], options, reg.n, urdf, clock)
    clock.lap("read")

    has_p = any(m.p is not None for m in [*train_m, *test_m])
    desc = _description(options, has_p)
    ratios = _gear_ratios(options, reg, desc, clock)
    skipped: list[str] = []
    train = remove_cylinders(_prepare(train_m, options, clock, skipped), reg, desc)
    test = remove_cylinders(_prepare(test_m, options, clock, skipped), reg, desc)
    if test.p_joints != train.p_joints:
        raise DataFileError(
            f"{test.sources[0]}: pressure columns {list(test.p_joints)} differ from the training "
            f"files' {list(train.p_joints)}"
        )
    clock.say(
        f"preprocessed: {train.n_samples} training and {test.n_samples} test samples at "
        f"{train.rate_hz:.0f} Hz{'; cylinder torque taken out' if has_p else ''}"
    )
    clock.lap("preprocess")

    ctx_train = make_context(reg, train, clock.say)
    ctx_test = make_context(reg, test, clock.say)
    clock.say("regressor done")
    clock.lap("regressor")

    meta = {
        "rate_hz": train.rate_hz,
        "position_cutoff_hz": options.position_cutoff_hz,
        "torque_cutoff_hz": options.torque_cutoff_hz,
        "train_files": [str(p) for p in train_paths],
        "test_files": [str(p) for p in test_paths],
        "urdf_xml": urdf_xml,
        "cylinders_removed": has_p,
    }
    ls = BlockLS(train.tau, contiguous_folds(train.n_samples, options.search.folds))
    kinds = list(FRICTION_MODELS) if options.compare_friction else [options.friction]
    kinds.sort(key=lambda k: k != options.friction)
    fits: dict[str, FrictionFit] = {}
    comparison: dict[str, Any] = {}
    for kind in kinds:
        fit = fit_rigid_friction(ls, ctx_train, kind, ratios, progress=clock.say)
        fits[kind] = fit
        _, pred = _predict(reg, ctx_test, fit, str(urdf), meta)
        comparison[kind] = {
            "rms_train": fit.evaluation.fit_rms.tolist(),
            "rms_train_cv": fit.evaluation.cv_rms.tolist(),
            "rms_test": rms(test.tau - pred).tolist(),
            "q_e_rad_s": [t.q_e_rad_s for t in fit.terms],
        }
    for kind in kinds[1:]:
        for term in fits[kind].terms:
            ls.remove(term.key)
    base_fit = fits[options.friction]
    baseline, pred_before = _predict(reg, ctx_test, base_fit, str(urdf), meta)
    rms_before = rms(test.tau - pred_before)
    clock.say(f"held-out RMS before effects: {np.array2string(rms_before, precision=3)} N·m")
    clock.lap("fit")

    model = baseline
    pred_after = pred_before
    accepted: list[fx.Accepted] = []
    train_eval = base_fit.evaluation
    if options.find_effects:
        state = fx.search_all_along(
            ls, ctx_train, train, base_fit.names, base_fit.weights, options.search, clock.say
        )
        assert state.evaluation is not None
        train_eval = state.evaluation
        a_effects = [(a.term, a.coef, a.appeared) for a in state.accepted]
        model_a = model_from_solution(
            reg, base_fit, state.evaluation.solution, a_effects, str(urdf), meta
        )
        pred_a = model_a.torque_from_context(ctx_test)
        if state.delay_s:
            pred_a = shift_signal(test.t, test.segment, pred_a, -state.delay_s)
        gain = fx.training_gain_fn(
            ls, ctx_train, train, state.names, base_fit.weights, state.delay_s
        )
        between = fx.search_between(
            ctx_test, test, pred_a, base_fit.weights, state.effects, options.search, clock.say, gain
        )
        accepted = [*state.accepted, *between.accepted]
        if accepted:
            model = model_from_solution(
                reg,
                base_fit,
                state.evaluation.solution,
                [*a_effects, *((a.term, a.coef, a.appeared) for a in between.accepted)],
                str(urdf),
                meta,
            )
            pred_after = between.model_prediction + between.cv_prediction
        if not accepted:
            clock.say("no further effect found")
    rms_after = rms(test.tau - pred_after)
    clock.say(f"held-out RMS after effects:  {np.array2string(rms_after, precision=3)} N·m")
    clock.lap("effects")

    out.mkdir(parents=True, exist_ok=True)
    plots: list[str] = []
    if options.plots:
        curves = {"model before effects": pred_before}
        if accepted:
            curves["model after effects"] = pred_after
        plots.append(
            plot_torques(
                out / "torque_test.png",
                test.tau,
                curves,
                reg.joint_names,
                test.rate_hz,
                "Held-out test files: measured vs model torque",
            ).name
        )
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
                reg.joint_names,
            ).name
        )
    clock.lap("validate")

    model.save(out / "model.json")
    summary: dict[str, Any] = {
        "joints": list(reg.joint_names),
        "friction_model": options.friction,
        "rms_before": rms_before.tolist(),
        "rms_after": rms_after.tolist(),
        "relative_before": relative_error(test.tau, pred_before).tolist(),
        "relative_after": relative_error(test.tau, pred_after).tolist(),
        "rms_train": train_eval.fit_rms.tolist(),
        "rms_train_before": base_fit.evaluation.fit_rms.tolist(),
        "rms_measured_test": rms(test.tau).tolist(),
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
        "friction_comparison": comparison,
        "base_parameters": reg.base.n_base,
        "n_samples": {"train": train.n_samples, "test": test.n_samples},
        "rate_hz": train.rate_hz,
        "cylinders_removed": has_p,
        "files": {
            "urdf": str(urdf),
            "train": [str(p) for p in train_paths],
            "test": [str(p) for p in test_paths],
        },
        "plots": plots,
        "model_file": "model.json",
        "effects_searched": options.find_effects,
        "files_left_out": skipped,
        "margin": options.search.margin,
    }
    clock.lap("report")
    summary["timing_s"] = dict(clock.timing, total=round(time.perf_counter() - clock.start, 3))
    write_report(out, summary)
    clock.say(f"wrote {out / 'model.json'}, {out / 'summary.json'}, {out / 'report.md'}")
    return summary
