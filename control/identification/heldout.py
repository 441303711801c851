"""Held-out figures on the raw test files: measured torque minus :func:`.predict.predict_rows`.

What ``leadthrough analyze`` reports in ``summary["raw"]`` (``rms_before``, ``rms_after``,
``rms_plain_ls``): the same arithmetic anyone can do with ``leadthrough predict`` and the test
file, with no filter on the scored torque, over every row the models answer (a row one of them
declines is left out for all). With effects fitted on the first part of the test run (case B
of :mod:`.effects`), only the rows after that part are scored.

The fit itself works on low-passed, decimated samples (:mod:`.preprocess`), and the summary's
top-level figures are on that analysis target, where each joint slides.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from control.identification.datafile import Measurements
from control.identification.model import IdentifiedModel
from control.identification.predict import predict_rows
from gateway.robot.description import RobotDescription


@dataclass(frozen=True)
class TestFile:
    """One raw test file and how many analysis samples it gave (:mod:`.preprocess`)."""

    measurements: Measurements
    analysis_rows: int


def scored_rows(files: Sequence[TestFile], analysis_t: np.ndarray, split: int) -> list[np.ndarray]:
    """Per file, the raw rows scored: all of them when ``split`` is 0, else those at or after
    analysis sample ``split`` (``analysis_t`` the analysis samples' times, files in order; within
    half a recorded step)."""
    if split <= 0:
        return [np.ones(f.measurements.n_samples, dtype=bool) for f in files]
    out = []
    first = 0
    for f in files:
        m = f.measurements
        last = first + f.analysis_rows
        if split >= last:
            out.append(np.zeros(m.n_samples, dtype=bool))
        elif split <= first:
            out.append(np.ones(m.n_samples, dtype=bool))
        else:
            # the analysis sample is a recorded row (or a grid point among them): the raw rows
            # from half a recorded step before it, so that rounding loses none
            half_step = 0.5 * float(np.median(np.diff(m.t))) if m.n_samples > 1 else 0.0
            out.append(m.t >= analysis_t[split] - half_step)
        first = last
    return out


def residuals(
    model: IdentifiedModel,
    files: Sequence[TestFile],
    rows: Sequence[np.ndarray],
    desc: RobotDescription | None,
) -> np.ndarray:
    """Measured minus predicted torque on the scored rows of every file, stacked, (R, n) [N·m];
    NaN where the model declines a row."""
    parts = []
    for f, keep in zip(files, rows, strict=True):
        m = f.measurements
        parts.append((m.tau - predict_rows(model, m, desc))[keep])
    return np.concatenate(parts)


def rms_answered(errors: Sequence[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray]:
    """Per-joint RMS of each residual array over the rows every one of them answers, and
    those rows (bool, R)."""
    answered = np.logical_and.reduce([np.isfinite(e).all(axis=1) for e in errors])
    if not answered.any():
        return [np.full(e.shape[1], np.nan) for e in errors], answered
    return [np.sqrt(np.mean(e[answered] ** 2, axis=0)) for e in errors], answered


def per_file_rms(
    files: Sequence[TestFile],
    rows: Sequence[np.ndarray],
    errors: dict[str, np.ndarray],
    answered: np.ndarray,
) -> list[dict[str, object]]:
    """Per test file (a multi-sine and a slow, reversing motion are judged apart): its name,
    the rows scored and each model's per-joint RMS (``errors``: name → the stacked residuals
    of :func:`residuals`) over those every model answers; None for a file with none."""
    out: list[dict[str, object]] = []
    first = 0
    for f, keep in zip(files, rows, strict=True):
        part = slice(first, first + int(keep.sum()))
        first = part.stop
        ok = answered[part]
        entry: dict[str, object] = {"file": f.measurements.source, "rows_scored": int(ok.sum())}
        for name, e in errors.items():
            entry[name] = np.sqrt(np.mean(e[part][ok] ** 2, axis=0)).tolist() if ok.any() else None
        out.append(entry)
    return out
