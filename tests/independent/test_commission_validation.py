"""Commissioning's figures on its slow, reversing motion never fitted, redone by the referee.

`leadthrough identify` records a teaching-like motion it never gives the fit (role
``validate``, ``control.identification.on_cell.TEACHING_VALIDATION``) and reports the model's
raw error on it (``summary["validation"]``). The referee asks the product for its prediction
as a user would (``leadthrough predict`` in a child process), reads the raw file and its
sidecar with its own parser, turns the motor currents into torque with the drive gains, and
does the arithmetic itself: the reported figure must be exactly that, and the file must be
the slow, reversing motion it says it is.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sim_bridge.commission import COMMISSION_LIMIT_S, commissioned

from .referee import heldout_figures, read_predictions, run_predict

N = 6
#: It may commission plant 0 (a fresh clone, or changed code): the whole stack as processes,
#: lock-step, so it is of the stack tier (tests/run_suite.py runs it with the tests that need
#: the machine to themselves, never beside one of them).
pytestmark = pytest.mark.stack

#: teaching speeds: what the validation motion must stay within on its strokes [rad/s]
TEACHING_RAD_S = np.radians(2.0)


def _raw(csv: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """t, dq and the torque K i of an exported segment, by the referee's own reading."""
    with open(csv, encoding="ascii") as fh:
        header = fh.readline().strip().split(",")
    data = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
    gains = np.asarray(json.loads(csv.with_suffix(".json").read_text())["drive_gains_nm_per_a"])
    col = {name: k for k, name in enumerate(header)}
    current = data[:, [col[f"i{j}"] for j in range(1, N + 1)]]
    dq = data[:, [col[f"dq{j}"] for j in range(1, N + 1)]]
    return data[:, 0], dq, current * gains


@pytest.mark.timeout(COMMISSION_LIMIT_S)
def test_commissionings_slow_motion_figures_are_the_referees_arithmetic_on_the_raw_file(
    tmp_path,
):
    done = commissioned(0)
    files = done.summary["validation"]["files"]
    assert len(files) == 1 and files[0]["file"].split("_", 1)[1].startswith("teaching")
    reported = files[0]
    csv = done.folder / "segments" / reported["file"]
    t, dq, tau = _raw(csv)
    # the motion is what it claims: slow (the stroke speeds; transfers to the box at 0.1
    # rad/s aside), reversing on every joint, and resting
    speed = np.abs(dq)
    slow = (speed > 2e-3) & (speed < 1.5 * TEACHING_RAD_S)
    assert np.all(slow.mean(axis=0) >= 0.3), slow.mean(axis=0)
    for j in range(N):
        moving = dq[slow[:, j], j]
        assert np.count_nonzero(np.diff(np.sign(moving)) != 0) >= 3, j
    got = run_predict(done.model, csv, tmp_path / "pred.csv", 120.0)
    assert got["error"] is None, got["error"]
    pred = read_predictions(tmp_path / "pred.csv", t, N)
    fig = heldout_figures(tau, np.zeros_like(tau), pred)
    assert reported["rows_scored"] == int(fig["answered"].sum())
    np.testing.assert_allclose(reported["rms_after"], fig["after"], rtol=1e-6)
    # and the friction's measured speeds are reported per joint
    cover = done.summary["friction_measured_over"]
    assert len(cover) == N and all(c["speed_range_rad_s"] is not None for c in cover)
