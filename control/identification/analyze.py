"""``leadthrough analyze``: identify, validate on held-out files, close the loop, report.

Stages (each timed in ``summary.json``'s ``timing_s``):

1. read the ``--train`` and ``--test`` CSVs (:mod:`.datafile`);
2. preprocess each file (:mod:`.preprocess`: filtering, the position/velocity low-pass chosen
   on the training files by :mod:`.cutoff`, and the measured noise floor); take
   assist-cylinder torque out (:mod:`.fit`);
3. base regressor of the URDF on every sample (:mod:`.rigid`), filtered like the torque;
4. fit rigid body + friction on the training files; the eq. (14), eq. (15) and simple friction
   families are fitted and, with ``--friction auto`` (the default), the one with the lowest
   held-out (contiguous K-fold) error on the *training* files is kept — never chosen on the
   test files;
5. effects: case (A) on the training files, then case (B) on the first part of the test run
   (:mod:`.effects`);
6. the guard (:func:`guard_joints`): per joint, plain least squares (by the margin where the
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
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from control.identification import cylinders as cyl
from control.identification import effects as fx
from control.identification.chain import settle as settle_chain
from control.identification.cutoff import CutoffChoice, candidates, choose_cutoff
from control.identification.datafile import Measurements, read_measurements
from control.identification.fit import (
    MODEL,
    NOMINAL,
    PLAIN_LS,
    ZERO,
    FrictionFit,
    IdentifiedModel,
    PlainJoint,
    cylinder_columns,
    fit_rigid_friction,
    make_context,
    model_from_solution,
    plain_columns,
    plain_friction_columns,
    plain_key,
    remove_cylinders,
)
from control.identification.folds import CONTIGUOUS, Scheme, gcv_factor, plan_folds
from control.identification.heldout import TestFile, residuals, rms_answered, scored_rows
from control.identification.lsq import BlockLS, Evaluation, contiguous_folds
from control.identification.parallel import map_forked
from control.identification.preprocess import (
    DEFAULT_POSITION_CUTOFF_HZ,
    DEFAULT_RATE_HZ,
    DEFAULT_STICK_VELOCITY_RAD_S,
    DEFAULT_TORQUE_CUTOFF_HZ,
    FILTER_ORDER,
    Prepared,
    TooShortError,
    concatenate,
    keeps_a_stretch,
    prepare,
    sliding_mask,
)
from control.identification.report import write_report
from control.identification.rigid import DEFAULT_GRAVITY_M_S2, RobotRegressor
from control.identification.terms import (
    FRICTION_MODELS,
    FRICTION_PARAM_NAMES,
    Context,
    EffectTerm,
    Envelope,
    RigidTerm,
    shift_signal,
)
from control.identification.validate import (
    import_plotting,
    masked_rms,
    plot_friction,
    plot_torques,
    relative_error,
    rms,
)
from control.robot.description import RobotDescription, load_description
from gateway.errors import ConfigError, DataFileError
from gateway.progress import ProgressBar, progress_bar

Progress = Callable[[str], None]
#: ``--friction`` value that picks the family by held-out error on the training files.
AUTO = "auto"
#: Leading share of the test run on which case (B) chooses and fits effects; the rest scores.
#: Half: the search needs enough data to see an effect, the score enough to be a figure.
TEST_FIT_FRACTION = 0.5
#: Ridge that pulls the rigid-body base parameters towards the URDF's nominal values, per
#: column of the scaled problem (:meth:`.lsq.BlockLS.set_prior`): directions the training
#: motion excites less than about 1/1000 of the best (sqrt(VIF) above ~10³) keep the URDF's
#: values instead of whatever noise and mismatch make of them, which would then be
#: extrapolated outside the training envelope; well-excited ones are not moved.
RIGID_PRIOR_RIDGE = 1e-6
#: sqrt(VIF) above which a base parameter counts as not identified by the training motion.
NOT_IDENTIFIED_SQRT_VIF = 1e3
#: The stages of one analysis in the order they end: (its ``timing_s`` key, what it does).
#: Each end is one :meth:`_Clock.lap` and one step of the progress bar; the effect search
#: ends twice (training files, then the guard and the test run), ``timing_s`` adds both up.
STAGES: tuple[tuple[str, str], ...] = (
    ("read", "reading the files"),
    ("cutoff", "choosing the cutoff"),
    ("preprocess", "preprocessing"),
    ("regressor", "base regressor"),
    ("fit", "fitting the friction families"),
    ("effects", "effects on the training files"),
    ("effects", "guard, effects on the test run"),
    ("validate", "plots"),
    ("report", "report"),
)


@dataclass(frozen=True)
class AnalyzeOptions:
    """Settings of one analysis; every field has its command-line option in :mod:`.cli`."""

    friction: str = AUTO
    rate_hz: float = DEFAULT_RATE_HZ
    #: None: chosen from the training files (:mod:`.cutoff`)
    position_cutoff_hz: float | None = None
    #: None: the highest cutoff candidate (:func:`.cutoff.candidates`: 0.4 × the analysis
    #: rate, at most 40 Hz), one filter for the torque and every regressor column
    torque_cutoff_hz: float | None = None
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
    #: joints slower than this are stuck: their rows neither fit nor score the model
    #: (:func:`.preprocess.sliding_mask`); 0 keeps every row [rad/s]
    stick_velocity_rad_s: float = DEFAULT_STICK_VELOCITY_RAD_S

    def __post_init__(self) -> None:
        if not (np.isfinite(self.stick_velocity_rad_s) and self.stick_velocity_rad_s >= 0):
            raise ConfigError(
                f"--stick-velocity: {self.stick_velocity_rad_s!r} must be a number >= 0"
            )
        if self.friction not in (AUTO, *FRICTION_MODELS):
            raise ConfigError(
                f"--friction: {self.friction!r} is not one of {[AUTO, *FRICTION_MODELS]}"
            )
        if not 0 < self.search.margin < 1:
            raise ConfigError(f"--margin: {self.search.margin!r} must be in (0, 1)")
        if self.search.folds < 2:
            raise ConfigError(f"--folds: {self.search.folds!r} must be >= 2")


def stage_bar(
    enabled: bool | None = None, before: int = 0, desc: str = "analyze"
) -> AbstractContextManager[ProgressBar]:
    """The progress bar of an analysis: :data:`STAGES` (plus ``before`` steps of the caller's
    own ahead of them), for :func:`analyze`'s ``bar`` (:func:`gateway.progress.progress_bar`:
    ``enabled`` None draws it when stderr is a terminal, False never)."""
    return progress_bar(len(STAGES) + before, desc, "stage", enabled=enabled)


class _Clock:
    def __init__(self, progress: Progress, bar: ProgressBar | None = None) -> None:
        self.start = time.perf_counter()
        self.last = self.start
        self.timing: dict[str, float] = {}
        self.progress = progress
        self.bar = bar
        self.laps = 0
        if bar is not None:
            bar.set_label(STAGES[0][1])

    def say(self, message: str) -> None:
        self.progress(f"[{time.perf_counter() - self.start:7.1f} s] {message}")

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.timing[stage] = round(self.timing.get(stage, 0.0) + now - self.last, 3)
        self.last = now
        self.laps += 1
        if self.bar is not None:
            upcoming = STAGES[self.laps][1] if self.laps < len(STAGES) else "done"
            self.bar.advance(label=upcoming)


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
    ms: Sequence[Measurements],
    options: AnalyzeOptions,
    clock: _Clock,
    skipped: list[str],
    edge_cutoff_hz: float | None = None,
    kept: list[TestFile] | None = None,
) -> Prepared:
    """The files prepared and concatenated; ``kept`` (when given) gets each file used and the
    analysis rows it gave, in order."""
    assert options.position_cutoff_hz is not None and options.torque_cutoff_hz is not None
    parts = []
    for m in ms:
        try:
            parts.append(
                prepare(
                    m,
                    options.rate_hz,
                    options.position_cutoff_hz,
                    options.torque_cutoff_hz,
                    edge_cutoff_hz,
                )
            )
            if kept is not None:
                kept.append(TestFile(m, parts[-1].n_samples))
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
    reg: RobotRegressor,
    ctx: Context,
    fit: FrictionFit,
    urdf: str,
    meta: dict[str, Any],
    cyl_cols: dict[int, np.ndarray] | None = None,
) -> tuple[IdentifiedModel, np.ndarray]:
    """The model of ``fit`` and what it predicts on ``ctx``; a fit with the cylinder columns
    (:mod:`.cylinders`) adds their part, on ``cyl_cols`` (those of ``ctx``'s rows)."""
    model = model_from_solution(reg, fit, fit.evaluation.solution, [], urdf, meta)
    pred = model.torque_from_context(ctx)
    coef = fit.evaluation.solution.coef.get(cyl.GROUP)
    if coef is not None and cyl_cols is not None:
        pred = pred + cyl.contribution(cyl_cols, np.asarray(coef, dtype=float), reg.n)
    return model, pred


def _settle_cylinders(
    ls: BlockLS, run: _Run, fit: FrictionFit
) -> tuple[FrictionFit, cyl.Calibration]:
    """The cylinder columns of ``fit`` judged (:func:`.cylinders.judge`) and taken out of the
    fit: kept, their part is taken out of the training and test targets as measured cylinder
    torque (``run.train``, ``run.test`` and ``ls`` get the corrected torque), refused, the
    targets stay; either way ``fit`` comes back without them, solved again, and
    ``run.meta["cylinders"]`` says what was done (the model file carries it)."""
    assert run.cyl_train is not None and run.cyl_test is not None and run.desc is not None
    names = [name for name in fit.names if name != cyl.GROUP]
    without = ls.evaluate(names, fit.weights)
    coef = np.asarray(fit.evaluation.solution.coef[cyl.GROUP], dtype=float)
    cal = cyl.judge(run.desc, coef, fit.evaluation.cv_rms, without.cv_rms)
    ls.remove(cyl.GROUP)
    evaluation = without
    if cal.any_kept:
        n = run.reg.n
        run.train = run.train.with_tau(run.train.tau - cyl.contribution(run.cyl_train, cal.coef, n))
        run.test = run.test.with_tau(run.test.tau - cyl.contribution(run.cyl_test, cal.coef, n))
        ls.set_y(run.train.tau)
        evaluation = ls.evaluate(names, fit.weights)
    run.meta["cylinders"] = cal.to_json()
    for j, s, why in zip(cal.joints, cal.scale, cal.reasons, strict=True):
        run.clock.say(f"cylinder on J{j + 1}: force scale {s:.4g}, {why}")
    return replace(fit, evaluation=evaluation, extra=()), cal


def _fit_families(
    ls: BlockLS,
    run: _Run,
    kinds: Sequence[str],
    ratios: np.ndarray,
    while_waiting: Callable[[], None] | None = None,
) -> tuple[dict[str, FrictionFit], dict[str, Any]]:
    """Each friction family fitted on ``ls`` (groups left there) and its figures;
    ``while_waiting()`` runs in this process while workers fit them."""
    fits: dict[str, FrictionFit] = {}
    comparison: dict[str, Any] = {}

    if "rigid" not in ls.cols:
        ls.add("rigid", RigidTerm().columns(run.ctx_train))
    extra = [cyl.GROUP] if cyl.GROUP in ls.cols else []

    def fit_one(kind: str) -> tuple[FrictionFit, dict[str, Any], list[str]]:
        lines: list[str] = []
        own = ls.fork()
        fit = fit_rigid_friction(
            own, run.ctx_train, kind, ratios, progress=lines.append, extra=extra
        )
        return fit, own.export([t.key for t in fit.terms]), lines

    # the families are independent searches: side by side on a fork of ``ls`` each, in worker
    # processes (:mod:`.parallel`); the costliest first. This process meanwhile imports what
    # the plots will need.
    order = sorted(kinds, key=lambda k: -len(FRICTION_PARAM_NAMES[k]))
    done = dict(zip(order, map_forked(fit_one, order, while_waiting=while_waiting), strict=True))
    for kind in kinds:
        fit, groups, lines = done[kind]
        for line in lines:
            run.clock.say(line)
        ls.adopt(groups)
        fits[kind] = fit
        _, pred = _predict(run.reg, run.ctx_test, fit, str(run.urdf), run.meta, run.cyl_test)
        comparison[kind] = {
            "rms_train": fit.evaluation.fit_rms.tolist(),
            "rms_train_cv": fit.evaluation.cv_rms.tolist(),
            "rms_test": rms(run.test.tau - pred).tolist(),
            "q_e_rad_s": [t.q_e_rad_s for t in fit.terms],
            "sign_width_rad_s": [t.sign_width_rad_s for t in fit.terms],
        }
    return fits, comparison


def _keep_family(ls: BlockLS, fits: dict[str, FrictionFit], friction: str, clock: _Clock) -> str:
    """The family kept (``--friction``, or :func:`choose_family` for auto); the others' groups
    leave ``ls``."""
    kind = choose_family(fits) if friction == AUTO else friction
    if friction == AUTO:
        clock.say(f"friction family {kind}: lowest held-out error on the training files")
    for other, fit in fits.items():
        if other != kind:
            for term in fit.terms:
                ls.remove(term.key)
    return kind


def choose_family(fits: dict[str, FrictionFit]) -> str:
    """The friction family with the lowest held-out error on the training files.

    Joints carry torques of very different size, so each joint's held-out MSE is divided by
    the best family's on that joint before summing: a family is judged by how much worse than
    the best it does, joint by joint, not by the largest joint alone. A joint without rows
    (it never slid) has no say.
    """
    mse = {k: f.evaluation.cv_rms**2 for k, f in fits.items()}
    judged = np.isfinite(np.array(list(mse.values()))).all(axis=0)
    best = np.min(np.array(list(mse.values()))[:, judged], axis=0)
    scale = np.where(best > 0, best, 1.0)
    return min(mse, key=lambda k: float(np.sum(mse[k][judged] / scale)))


def plain_least_squares(
    ctx: Context, y: np.ndarray, folds: Sequence[slice], mask: np.ndarray | None = None
) -> Any:
    """Plain LS of every joint alone (:func:`.fit.plain_columns`) on targets ``y`` (T, n):
    the :class:`.lsq.Evaluation` (held-out SSE per joint over ``folds``) and its groups."""
    ls = BlockLS(y, folds, mask)
    names = []
    for j in range(y.shape[1]):
        ls.add(plain_key(j), plain_columns(ctx, j))
        names.append(plain_key(j))
    return ls.evaluate(names, np.ones(y.shape[1]))


def _plain_prediction(ctx: Context, sol_coef: dict[str, np.ndarray]) -> np.ndarray:
    out = np.zeros_like(ctx.q)
    for j in range(ctx.q.shape[1]):
        out[:, j] = plain_columns(ctx, j)[j] @ sol_coef[plain_key(j)]
    return out


def _restricted(effects: Sequence[fx.Accepted], plain: set[int]) -> list[tuple[Any, Any, str]]:
    """Training-fitted effects without the joints kept on plain least squares (their columns
    were fitted with the full model's parameters, which those joints no longer use)."""
    out = []
    for a in effects:
        joints = tuple(j for j in a.term.joints if j not in plain)
        if not a.term.is_linear:
            out.append((a.term, a.coef, a.appeared))
        elif joints:
            term = EffectTerm(a.term.name, joints, dict(a.term.setting))
            out.append((term, a.coef, a.appeared))
    return out


def _outside_share(env: Envelope, data: Any) -> dict[str, Any]:
    out = env.outside(data.q, data.dq)
    return {
        "any_joint": float(np.mean(out.any(axis=1))) if out.size else 0.0,
        "per_joint": np.mean(out, axis=0).tolist() if out.size else [],
    }


def _excitation_report(
    reg: RobotRegressor, ls: BlockLS, fit: FrictionFit, evaluation: Any
) -> dict[str, Any]:
    """The base parameters: how many are rigid-body and armature, how well the training data
    excite each (sqrt(VIF), :meth:`.lsq.BlockLS.excitation`), the fitted and the URDF's
    nominal value, and which ones the data could not identify (kept near nominal)."""
    base = reg.base
    names = base.base_names
    armature = [n.endswith(".armature") for n in names]
    sqrt_vif = ls.excitation("rigid", fit.weights)
    nominal = base.base_values(reg.parameters())
    fitted = evaluation.solution.coef["rigid"]
    rows = [
        {
            "name": name,
            "definition": definition,
            "sqrt_vif": float(v) if np.isfinite(v) else None,
            "fitted": float(b),
            "nominal_urdf": float(b0),
        }
        for name, definition, v, b, b0 in zip(
            names, base.definitions(), sqrt_vif, fitted, nominal, strict=True
        )
    ]
    return {
        "count": base.n_base,
        "rigid_body": int(base.n_base - sum(armature)),
        "armature": int(sum(armature)),
        "computed_from": "pivoted QR of the regressor over random configurations within the "
        "URDF's joint limits (not the recorded data)",
        "not_identified": [
            r["name"]
            for r in rows
            if r["sqrt_vif"] is None or r["sqrt_vif"] > NOT_IDENTIFIED_SQRT_VIF
        ],
        "not_identified_rule": f"sqrt(VIF) > {NOT_IDENTIFIED_SQRT_VIF:g} on the weighted "
        "training data; such directions stay near the URDF's nominal values (ridge "
        f"{RIGID_PRIOR_RIDGE:g} per scaled column)",
        "parameters": rows,
    }


def _floats(x: np.ndarray | None) -> list[float] | None:
    return None if x is None else [float(v) for v in x]


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

    - ``plain_ls``: the joint's own base-regressor row, Coulomb and viscous (:func:`.fit.
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


#: Fewest rows of the test run's leading part on which the guard's second look decides.
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
    tau: np.ndarray,
    chosen: np.ndarray,
    plain: np.ndarray,
    mask: np.ndarray,
    rows: slice,
    chosen_kinds: Sequence[str],
) -> LeadGuard | None:
    """Per joint, what the training guard kept (``chosen`` (T, n) its prediction, of kind
    ``chosen_kinds[j]``) against plain least squares (``plain``) and zero, on the test run's
    ``rows`` (where ``mask`` is 1). The training folds cannot show how a model extrapolates
    to where the test run goes (outside the training envelope, a shared rigid-body fit can
    lose to a joint's own least squares, and an effect nobody declared can grow there); the
    leading test rows can, and no fit has seen them. The lowest error there is kept (the
    training guard's choice on a tie; on a joint with fewer than :data:`TEST_GUARD_MIN_ROWS`
    rows there, that choice). None when no joint has enough."""
    m = mask[rows]
    enough = m.sum(axis=0) >= TEST_GUARD_MIN_ROWS
    if not enough.any():
        return None
    n = tau.shape[1]
    err = {
        "chosen": (((tau - chosen)[rows] ** 2) * m).sum(axis=0),
        PLAIN_LS: (((tau - plain)[rows] ** 2) * m).sum(axis=0),
        ZERO: ((tau[rows] ** 2) * m).sum(axis=0),
    }
    count = np.maximum(m.sum(axis=0), 1.0)
    rms_rows, kept = [], []
    for j in range(n):
        sse = {k: float(v[j]) for k, v in err.items()}
        best = min(sse, key=lambda k: (sse[k], k != "chosen")) if enough[j] else "chosen"
        named = {(chosen_kinds[j] if k == "chosen" else k): v for k, v in sse.items()}
        rms_rows.append({k: float(np.sqrt(v / count[j])) for k, v in named.items()})
        kept.append(chosen_kinds[j] if best == "chosen" else best)
    return LeadGuard((rows.start, rows.stop), rms_rows, kept)


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


@dataclass
class _Run:
    """What the stages of one analysis hand each other."""

    reg: RobotRegressor
    urdf: Path
    meta: dict[str, Any]
    train: Prepared
    test: Prepared
    ctx_train: Context
    ctx_test: Context
    envelope: Envelope
    clock: _Clock
    #: the described cylinders' torque columns (:mod:`.cylinders`), None without pressures
    cyl_train: dict[int, np.ndarray] | None = None
    cyl_test: dict[int, np.ndarray] | None = None
    desc: RobotDescription | None = None
    #: the raw test files the figures are scored on (:mod:`.heldout`)
    test_files: list[TestFile] = field(default_factory=list)


def _load(
    urdf_path: str | Path,
    train_paths: Sequence[str | Path],
    test_paths: Sequence[str | Path],
    options: AnalyzeOptions,
    clock: _Clock,
    skipped: list[str],
) -> tuple[_Run, np.ndarray, AnalyzeOptions]:
    urdf = Path(urdf_path)
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
    options, cutoff = _resolve_cutoffs(options, reg, train_m, test_m, desc, clock)
    train = remove_cylinders(_prepare(train_m, options, clock, skipped), reg, desc)
    test_files: list[TestFile] = []
    test = remove_cylinders(_prepare(test_m, options, clock, skipped, None, test_files), reg, desc)
    if test.p_joints != train.p_joints:
        raise DataFileError(
            f"{test.sources[0]}: pressure columns {list(test.p_joints)} differ from the training "
            f"files' {list(train.p_joints)}"
        )
    clock.say(
        f"preprocessed: {train.n_samples} training and {test.n_samples} test samples at "
        f"{train.rate_hz:.0f} Hz{'; cylinder torque taken out' if has_p else ''}; measured "
        f"noise floor {np.array2string(np.asarray(train.noise_nm), precision=3)} N·m"
    )
    clock.lap("preprocess")

    envelope = Envelope.of(train.q, train.dq)
    ctx_train = make_context(reg, train, clock.say, envelope=envelope)
    ctx_test = make_context(reg, test, clock.say, envelope=envelope)
    clock.say("regressor done")
    clock.lap("regressor")
    meta = {
        "cutoff_choice": None if cutoff is None else cutoff.to_json(),
        "rate_hz": train.rate_hz,
        "analysis_rate_hz": options.rate_hz,
        "position_cutoff_hz": options.position_cutoff_hz,
        "torque_cutoff_hz": options.torque_cutoff_hz,
        "train_files": [str(p) for p in train_paths],
        "test_files": [str(p) for p in test_paths],
        "urdf_xml": urdf_xml,
        "cylinders_removed": has_p,
    }
    run = _Run(
        reg, urdf, meta, train, test, ctx_train, ctx_test, envelope, clock,
        cylinder_columns(train, reg, desc), cylinder_columns(test, reg, desc), desc, test_files,
    )  # fmt: skip
    return run, ratios, options


def _resolve_cutoffs(
    options: AnalyzeOptions,
    reg: RobotRegressor,
    train_m: Sequence[Measurements],
    test_m: Sequence[Measurements],
    desc: RobotDescription | None,
    clock: _Clock,
) -> tuple[AnalyzeOptions, CutoffChoice | None]:
    """``options`` with both cutoffs set: a missing position cutoff chosen on the training
    files (:func:`.cutoff.choose_cutoff`; 20 Hz where they are too short to compare two
    candidates), a missing torque cutoff the highest candidate, never below the position one.

    Only candidates that leave every file something to analyse are compared: a low cutoff
    trims EDGE_PERIODS / cutoff at both ends of each gap-free stretch, and a recording whose
    stretches are short (the CAN driver's holds and coasts cut them) would lose a test file
    whole to a cutoff chosen on the training files. The test files lend only their time
    stamps to that, never their values."""
    choice = None
    if options.position_cutoff_hz is None:

        def prepared(cutoff_hz: float, edge_hz: float, torque_hz: float) -> Prepared:
            trial = replace(
                options,
                position_cutoff_hz=cutoff_hz,
                torque_cutoff_hz=torque_hz,
                skip_short_files=False,
            )
            data = _prepare(train_m, trial, _quiet_clock(), [], edge_hz)
            return remove_cylinders(data, reg, desc)

        sample_hz = min(1.0 / float(np.median(np.diff(m.t))) for m in train_m)
        grid = list(candidates(options.rate_hz, sample_hz))
        files = [m for m in [*train_m, *test_m] if keeps_a_stretch(m, max(grid))]
        usable = [c for c in grid if all(keeps_a_stretch(m, c) for m in files)]
        # without a comparison: the one candidate left, else 20 Hz (or the lowest usable)
        fallback = DEFAULT_POSITION_CUTOFF_HZ
        if len(usable) < len(grid):
            fallback = usable[0] if len(usable) == 1 else max(fallback, usable[0])
            short = next(m for m in files if not keeps_a_stretch(m, grid[0]))
            clock.say(
                f"cutoffs below {usable[0]:g} Hz left out: they would trim all of "
                f"{short.source} (gap-free stretches too short)"
            )
            grid = usable
        while choice is None and len(grid) >= 2:
            try:
                choice = choose_cutoff(
                    reg, prepared, options.rate_hz, sample_hz, options.stick_velocity_rad_s,
                    options.search.folds, clock.say, grid,
                )  # fmt: skip
            except TooShortError:
                # a low cutoff trims EDGE_PERIODS / cutoff at each end: too much for a short
                # file; the lowest candidate goes, the position cutoff falls back when none is left
                grid = grid[1:]
                if len(grid) < 2:
                    clock.say(
                        f"training files too short to compare cutoffs: position cutoff "
                        f"{fallback:g} Hz"
                    )
                    break
        cutoff = choice.cutoff_hz if choice is not None else fallback
        options = replace(options, position_cutoff_hz=cutoff)
    if options.torque_cutoff_hz is None:
        top = max(choice.candidates_hz) if choice is not None else DEFAULT_TORQUE_CUTOFF_HZ
        options = replace(options, torque_cutoff_hz=max(top, options.position_cutoff_hz))
    clock.lap("cutoff")
    return options, choice


def _quiet_clock() -> _Clock:
    return _Clock(lambda _line: None)


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

        state = fx.search_all_along(
            ls, ctx_train, train, base_fit.names, base_fit.weights, options.search, clock.say,
            refit_friction, plain_sse, without_memory,
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
    effects_a = _restricted(accepted_a, set(plain))
    model_a = model_from_solution(
        reg, base_fit, train_eval.solution, effects_a, urdf, meta, run.envelope, plain, chain
    )
    pred_a = model_a.torque_from_context(ctx_test)
    if delay_a:
        pred_a = shift_signal(test.t, test.segment, pred_a, -delay_a)
    plain_ref = plain_least_squares(ctx_train, train.tau, folds, sliding_train)
    pred_plain = _plain_prediction(ctx_test, plain_ref.solution.coef)

    split = round(TEST_FIT_FRACTION * test.n_samples)
    fit_rows = slice(0, split)
    accepted_b: list[fx.Accepted] = []
    pred_after = pred_a
    if options.find_effects:
        gain = fx.training_gain_fn(ls, ctx_train, train, names, base_fit.weights, delay_a)
        done = [a.term for a in accepted_a]
        between = fx.search_between(
            ctx_test, test, pred_a, base_fit.weights, done, options.search, fit_rows,
            clock.say, gain, sliding_test, train_eval.cv_rms,
        )  # fmt: skip
        accepted_b = between.accepted
        pred_after = between.prediction
        refused += between.refused
    accepted = [*accepted_a, *accepted_b]
    # The guard's second look: on the leading test rows, what extrapolates worse than plain
    # least squares or zero is replaced there too (the figures are then those of the rest).
    kinds_now = [MODEL if j not in plain else plain[j].kind for j in range(reg.n)]
    second = guard_on_test(test.tau, pred_after, pred_plain, sliding_test, fit_rows, kinds_now)
    switched = []
    if second is not None:
        pred_after = pred_after.copy()
        for j, (was, now) in enumerate(zip(kinds_now, second.kept, strict=True)):
            if now == was:
                continue
            switched.append(j)
            coef = plain_ref.solution.coef[plain_key(j)]
            plain[j] = PlainJoint.from_coef(j, coef if now == PLAIN_LS else 0.0 * coef, now)
            pred_after[:, j] = pred_plain[:, j] if now == PLAIN_LS else 0.0
            r = second.rms[j]
            clock.say(
                f"joint {j + 1}: on the first {split} test rows {was.replace('_', ' ')} "
                f"({r[was]:.4g} N·m) extrapolates worse than {now.replace('_', ' ')} "
                f"({r[now]:.4g} N·m): {now} kept"
            )
    effects_a = _restricted(accepted_a, set(plain))
    effects_b = _restricted(accepted_b, set(plain))
    model = model_from_solution(
        reg, base_fit, train_eval.solution, [*effects_a, *effects_b], urdf, meta,
        run.envelope, plain, chain,
    )  # fmt: skip
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
    errors = [
        residuals(m, run.test_files, rows, run.desc) for m in (model_before, model, plain_model)
    ]
    (raw_before, raw_after, raw_plain), answered = rms_answered(errors)
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
            "scored": f"{raw_where}: raw measured torque minus each model's prediction "
            "(heldout.py, the arithmetic of `leadthrough predict`), no filter, stuck rows and "
            "reversals included",
        },
        "sliding_share_scored": on.mean(axis=0).tolist(),
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
            "files (fit.plain_columns)",
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
