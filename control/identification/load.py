"""Stages 1-3 of ``leadthrough analyze`` (:mod:`.analyze`): the run it analyses.

1. read the ``--train`` and ``--test`` CSVs (:mod:`.datafile`);
2. preprocess each file (:mod:`.preprocess`: filtering, the position/velocity low-pass chosen
   on the training files by :mod:`.cutoff`, and the measured noise floor); take
   assist-cylinder torque out (:mod:`.fit`);
3. base regressor of the URDF on every sample (:mod:`.rigid`), filtered like the torque.

:func:`_load` runs them and returns the :class:`.stages._Run` the later stages work on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from control.identification.cutoff import CutoffChoice, candidates, choose_cutoff
from control.identification.datafile import Measurements, read_measurements
from control.identification.envelope import Envelope
from control.identification.fit import cylinder_columns, make_context, remove_cylinders
from control.identification.heldout import TestFile
from control.identification.preprocess import (
    DEFAULT_POSITION_CUTOFF_HZ,
    DEFAULT_TORQUE_CUTOFF_HZ,
    Prepared,
    TooShortError,
    concatenate,
    keeps_a_stretch,
    prepare,
)
from control.identification.rigid import RobotRegressor
from control.identification.stages import AnalyzeOptions, _Clock, _Run
from gateway.errors import ConfigError, DataFileError
from gateway.robot.description import RobotDescription, load_description


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

    ctx_train = make_context(reg, train, clock.say)
    nominal = np.einsum("jtb,b->tj", ctx_train.y_base, reg.base.base_values(reg.parameters()))
    room = np.max(np.abs(train.tau), axis=0) + np.max(np.abs(nominal), axis=0)
    envelope = Envelope.of(train.q, train.dq, room)
    ctx_train = replace(ctx_train, envelope=envelope)
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
