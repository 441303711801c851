"""The identified model judged on recordings the analysis never saw: commissioning's slow,
reversing motion (the plan's ``teaching`` segments, role ``validate``).

The multi-sine held out by ``analyze`` tests the model on motions like its training; the
operator teaches at 0.5-2 °/s, reverses and rests, where friction is least known. Each
validation file is scored as anyone scores a model (:mod:`.predict`): the raw measured torque
minus the model's prediction on every row it answers, no filter on the scored torque, per
joint overall and split by the rows' measured speed (:func:`.speed_regimes.raw_by_speed`),
beside the RMS of the measured torque itself (what no model at all would leave).
``summary.json`` gets them under ``validation`` (each file by its name: `leadthrough identify`
writes them in ``OUT/segments/``); ``report.md`` shows them.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from control.identification.datafile import read_measurements
from control.identification.model import IdentifiedModel
from control.identification.predict import predict_rows
from control.identification.speed_regimes import measured_velocity, raw_by_speed
from gateway.robot.description import RobotDescription

WHAT = (
    "recordings never given to the fit (the plan's slow, reversing teaching strokes): raw "
    "measured torque minus the model's prediction (the arithmetic of `leadthrough predict`), "
    "every row it answers, no filter; by_speed splits the rows by their measured speed"
)


def _rms(e: np.ndarray) -> list[float | None]:
    if e.shape[0] == 0:
        return [None] * e.shape[1]
    return np.sqrt(np.mean(e**2, axis=0)).tolist()


def score_file(
    model: IdentifiedModel, path: Path, desc: RobotDescription | None, stick_rad_s: float
) -> dict[str, Any]:
    """One validation file's figures (module docstring)."""
    m = read_measurements(path)
    err = m.tau - predict_rows(model, m, desc)  # desc is used only for a cylinder model
    answered = np.isfinite(err).all(axis=1)
    dq = measured_velocity(m)
    return {
        "file": path.name,
        "rows": int(m.n_samples),
        "rows_scored": int(answered.sum()),
        "rms_measured": _rms(m.tau[answered]),
        "rms_after": _rms(err[answered]),
        "by_speed": raw_by_speed({"rms_after": err}, dq, answered, stick_rad_s),
    }


def score_validation(
    model_path: Path,
    files: Sequence[Path],
    desc: RobotDescription | None,
    stick_rad_s: float,
) -> dict[str, Any]:
    """``summary["validation"]``: every validation file scored on the model at
    ``model_path``."""
    model = IdentifiedModel.load(model_path)
    return {
        "what": WHAT,
        "files": [score_file(model, Path(f), desc, stick_rad_s) for f in files],
    }
